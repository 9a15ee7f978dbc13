"""`bench observer`: tune a Kalman observer on training files and write a model artifact that carries it.

The observer corrects the model's state with a temperature sensor of one node (default: the winding column
winding_C, the winding node; a stator NTC column with --measure ntc_C). Its process noise Q (per node) and
measurement noise R are tuned on the training files (`--criterion magnet`: the magnet's log MSE over every training
file started with the magnet as measured, 30 K too warm and too cold; `nodes`: the same plus the winding's log MSE,
with a steep penalty wherever the filter leaves the magnet worse than the open loop, so a winding sensor (an NTC)
corrects the winding only as far as the magnet it cannot see stays no worse; `likelihood`: the innovations'
likelihood, the magnet reference a second measurement while tuning), and written into a copy of --model as its
`observer` section
(artifact schema version 3; the target runs it in float32, `target_sim.observer`). Without --train, the built-in
motor's training runs (20 and 60 °C in out/data, generated if missing) are used.

A sensor may lag (--lag τ: the filter then carries the lag's state, so a slow NTC is compared with what it can
have seen), read a mix of nodes (--gradient g: node + g·(node - yoke), an end-winding NTC between the hot spot and
the yoke) and have an offset (--offset). Each of the three is a number, or auto: estimated from the training files,
whose winding_C (the node's reference) and yoke_C columns the sensor is fitted to as lag_τ(w + g·(w - yoke)) +
offset by least squares (τ by a bounded search, τ = 0 allowed; without yoke_C the gradient is held at 0), its
residual reported: `--lag auto --gradient auto --offset auto` for a sensor nobody measured. --bias adds a heat-bias
state, a random walk of the watts the loss model misses: --bias winding (or --bias alone) into the winding node,
--bias magnet into the magnet node (for a persistent magnet-side model error: a magnet loss or winding-magnet
coupling the model has wrong); --bias winding-output: a random walk in °C added to the winding's output, which the
sensor sees and the estimate reports, heating nothing: a winding sensor's readings move that bias and no node, so the
model's dynamics (and the magnet) stay the open loop's while the winding follows the sensor (on the motor suite's
validation profiles a corrected winding node drove the magnet through the model's coupling); --bias none: no bias
state. The default (auto) is winding-output when a measurement reads the winding, else none
(`bench.observer.choices.DEFAULT_BIAS`, chosen on the motor suite).
--consider magnet makes the magnet node (and a magnet bias state) consider states (Schmidt-Kalman): a measurement
that does not read the magnet (an end-winding NTC) corrects the winding and the other nodes but never the magnet,
whose estimate then moves only through the model's own coupling; the covariance is that of the gain actually used
(its rows of the magnet zero), so the filter stays consistent. A measurement that reads the magnet (--flux) still
updates it. It is the default (on the suite's validation profiles the only setting that left the magnet no worse
than the open loop on every motor); --consider none: every state is updated (--bias magnet with a winding sensor
alone needs it: a held magnet bias would never move).
--gate SIGMA (default 3, `bench.observer.choices.DEFAULT_GATE`): the innovation gate the target runs: a reading
whose innovation ν is more than SIGMA of its predicted sigma off (ν²/S > SIGMA², S = h P⁻ hᵀ + R; 3: the 99.73 %
quantile of chi-square with 1 degree of freedom) predicts only and is counted; --gate-flag-after N (default 10)
rejections in a row flag the sensor. While a sensor is rejected the covariance grows, so a sensor that truly moved
passes again (the steady-state-gain form, whose S is constant, admits the next reading after the flag). --gate none:
no gate (the section written as before).
--flux adds the flux-linkage magnet temperature from u_d, u_q, i_d, i_q and speed: ψ_0 and α_B (and L_d and
R_s where the data determine them) are calibrated on the training files against the measured magnet, valid at or
above --flux-min-speed; the calibration's residual is reported, a large one is a warning, and one that makes the
readings useless (or a fitted R_s far from the model's stator resistance) is refused (exit 2) unless --flux-force is
given. --measure none with --flux: the flux linkage only.
--resistance adds the winding temperature from the stator resistance, R_s = (u_d + ω_e L_q i_q)/i_d at or below
--resistance-max-speed where |i_d| is at least --resistance-min-current: R_s0 (and L_q where the data determine
it) calibrated on the training files against the measured winding, the residual reported; too few such steps or an
R_s0 the data do not determine is one sentence (exit 2), and its residual and R_s0 are judged as the flux
linkage's (--resistance-force).

A tuning that ends at a limit of its search (a q or R within half a decade of its bound, e.g. R at its upper limit:
the filter barely uses the measurement) or at the --evaluations cap before converging says so: one warning each
(stderr, and `warnings` in --json).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.commands.args import declare_files
from bench.commands.common import add_data_arguments, add_output_flags, check_writable, print_json
from bench.errors import UsageError
from bench.fileio import write_text_atomically
from bench.progress import StageBars


def add_subparser(subparsers) -> None:
    from bench.observer.choices import (
        DEFAULT_BIAS,
        DEFAULT_CONSIDER,
        DEFAULT_CONSIDER_RELEASE_C,
        DEFAULT_GATE,
        DEPLOYED_FORM,
        TUNING_CRITERIA,
    )
    from bench.observer.measures import LAB_MEASUREMENT_KINDS
    from target_sim.artifact import BIAS_KINDS, CONSIDER_KINDS
    from target_sim.observer import OBSERVER_FORMS

    bias_names = [bias_option(kind) for kind in BIAS_KINDS]   # winding-heat: --bias winding

    p = subparsers.add_parser("observer", help="tune a Kalman observer (Q, R) on training files, add it to an artifact",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", type=Path, default=None,
                   help="model artifact to add the observer to (default: the packaged hammerstein one)")
    p.add_argument("--train", nargs="+", default=None, metavar="FILE",
                   help="training data files or globs (default: the built-in motor's 20 and 60 °C runs)")
    add_data_arguments(p)
    for _, kind in LAB_MEASUREMENT_KINDS.items():     # each kind's own options (the sensor, --flux, --resistance)
        kind.add_arguments(p)
    p.add_argument("--bias", nargs="?", const="winding", default=AUTO_BIAS, choices=[AUTO_BIAS, "none", *bias_names],
                   help="add a heat-bias state (W the loss model misses) into the winding (--bias alone: winding) "
                        "or the magnet node, or an output bias of the winding (winding-output: °C added to the "
                        f"winding estimate; its sensor moves the bias, never a node); none: no bias state (default "
                        f"{AUTO_BIAS}: {DEFAULT_BIAS} when a measurement reads the winding, else none)")
    p.add_argument("--consider", choices=["none", *CONSIDER_KINDS], default=DEFAULT_CONSIDER,
                   help="consider states: a measurement that does not read the magnet never updates the magnet "
                        "node (nor a magnet bias), magnet; every node it does not read, unmeasured; or none "
                        f"(default {DEFAULT_CONSIDER})")
    p.add_argument("--consider-release", default=release_text(DEFAULT_CONSIDER_RELEASE_C), metavar="SIGMA",
                   help="key-on release of the consider states: while the magnet's 1-sigma exceeds SIGMA K (a "
                        "magnet nobody measured at key-on), every measurement updates it; below, it is held; none: "
                        f"held always (default {release_text(DEFAULT_CONSIDER_RELEASE_C)})")
    p.add_argument("--gate", default=str(DEFAULT_GATE[0]), metavar="SIGMA",
                   help="innovation gate: a reading more than SIGMA innovation sigmas off predicts only and is "
                        f"counted; none: no gate (default {DEFAULT_GATE[0]:g}, nu^2/S > {DEFAULT_GATE[0] ** 2:g})")
    p.add_argument("--gate-flag-after", type=int, default=DEFAULT_GATE[1], metavar="N",
                   help=f"rejections in a row that flag the sensor (default {DEFAULT_GATE[1]})")
    p.add_argument("--pole-pairs", type=float, default=None,
                   help="pole pairs for --flux and --resistance (default: the artifact's electrical loss model's, "
                        "else 1)")
    p.add_argument("--criterion", choices=TUNING_CRITERIA, default="magnet", help="tuning criterion (default magnet)")
    p.add_argument("--form", choices=OBSERVER_FORMS.names(), default=DEPLOYED_FORM,
                   help=f"covariance form the target deploys (default {DEPLOYED_FORM}, see 'bench numerics "
                        "--observer')")
    p.add_argument("--evaluations", type=int, default=800, help="largest number of filter runs while tuning")
    p.add_argument("--validate", nargs="+", default=None, metavar="FILE",
                   help="files the observer is not tuned on (files or globs, with --train's mapping): its winding "
                        "and magnet MSE against the open loop's there, and a warning where it is worse")
    p.add_argument("--out", type=Path, default=Path("out/model/observer.json"), help="artifact to write")
    add_output_flags(p)
    declare_files(p, inputs=('--model', '--train', '--validate'), outputs=('--out',))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.commands.common import data_options
    from bench.drive.files import expand_data_paths, load_datasets
    from bench.model.default import default_artifact_path
    from bench.model.identify import IDENTIFICATION_COOLANTS
    from bench.model.pipeline import load_campaign
    from bench.observer.evaluate import validation_check
    from bench.observer.measures import LAB_MEASUREMENT_KINDS
    from bench.observer.section import default_bias, observer_section, with_observer
    from bench.observer.tune import consider_problem, tune_observer, tuning_warnings
    from target_sim.artifact import BIAS_KINDS, dumps, load_artifact, verify

    if args.evaluations < 1:
        raise UsageError("--evaluations must be at least 1")
    gate = gate_option(args.gate, args.gate_flag_after)
    release = release_option(args.consider_release, args.consider)
    check_writable(args.out, "--out")
    model_path = args.model or default_artifact_path()
    artifact = load_artifact(model_path)
    if args.train:
        mapping, period = data_options(args)
        datasets = load_datasets(expand_data_paths(args.train, "--train"), mapping, period)
        validation = (load_datasets(expand_data_paths(args.validate, "--validate"), mapping, period)
                      if args.validate else [])
    else:
        if args.mapping is not None:
            raise UsageError("--mapping applies to --train files, not to the built-in motor's datasets")
        campaign = load_campaign(None)
        datasets = [campaign[c] for c in IDENTIFICATION_COOLANTS]
        validation = load_datasets(expand_data_paths(args.validate, "--validate"), None, None) if args.validate \
            else []
    # the filter runs of the search as a bar (a terminal's only): a total, an ETA, the criterion so far
    progress = StageBars(args.quiet or args.json, unit="run")
    # in the kinds' order: the sensor, the flux linkage, the winding resistance
    asked = (kind.from_arguments(args, artifact, datasets) for _, kind in LAB_MEASUREMENT_KINDS.items())
    measurements = [m for m in asked if m is not None]
    if not measurements:
        raise UsageError("--measure none needs --flux or --resistance: the observer needs a measurement")
    bias = ({bias_option(kind): kind for kind in BIAS_KINDS}.get(args.bias) if args.bias != AUTO_BIAS
            else default_bias(measurements))   # a kind of BIAS_KINDS, None: none
    consider = None if args.consider == "none" else args.consider    # a kind of target_sim.artifact.CONSIDER_KINDS
    problem = consider_problem(consider, bias, measurements)
    if problem:
        raise UsageError(problem)
    try:
        fit = tune_observer(artifact, datasets, measurements, args.criterion, args.evaluations,
                            lambda done, most, cost: progress("tuning", done, most, cost), bias, consider,
                            None if release is None else release ** 2)
    finally:
        progress.close()
    warnings = [w for m in measurements for w in m.warnings] + tuning_warnings(fit)
    content = with_observer(artifact, observer_section(artifact, fit, datasets, args.form, gate))
    write_text_atomically(args.out, dumps(content))
    checked = validation_check(verify(content), validation) if validation else None
    if checked is not None and checked.warning():
        warnings.append(checked.warning())
    report = {"model": str(model_path), "out": str(args.out), "sha256": content["sha256"],
              "measurement": measurements[0].describe(), "form": args.form, "bias": fit.bias,
              "consider": fit.consider, "consider_release_sigma_C": release,
              "gate": content["observer"].get("gate"),
              **content["observer"]["tuning"], "warnings": warnings,
              **({"validation": checked.as_dict()} if checked is not None else {})}
    if not args.quiet:
        for warning in warnings:
            print(f"bench: warning: {warning}", file=sys.stderr)
    if args.json:
        print_json(report)
    else:
        tuning = content["observer"]["tuning"]
        q = ", ".join(f"{n} {v:.3g}" for n, v in tuning["q_per_step"].items())
        said = "; ".join(f"the {m.node} node with {', '.join(m.columns)} ({m.kind})" for m in measurements)
        print(f"observer of {model_path} ({artifact.kind}) on {len(datasets)} training file(s), measuring {said}; "
              f"{args.criterion} criterion {fit.cost:.6g} after {fit.evaluations} filter runs")
        for text in filter(None, (m.calibration_text() for m in measurements)):
            print(text)
        print(f"Q per step: {q}; R scale {', '.join(f'{v:.3g}' for v in fit.r_scale)}; deployed form {args.form}; "
              f"consider states: {fit.consider or 'none'}"
              f"{f' (released while the magnet 1-sigma > {release:g} K)' if release is not None else ''}; "
              "innovation gate: "
              f"{f'{gate[0]:g} sigma, flag after {gate[1]}' if gate else 'none'}")
        if checked is not None:
            print("on the validation files, float32 MSE open loop / observer: " + ", ".join(
                f"{'magnet' if n == 'pm' else n} {checked.open_loop_mse[n]:.3g} / {checked.observer_mse[n]:.3g} K²"
                for n in checked.observer_mse))
        print(f"wrote {args.out} (sha256 {content['sha256'][:12]})")
    return 0


AUTO_BIAS = "auto"      # --bias's default: `bench.observer.section.default_bias` of the measurements


def bias_option(kind: str) -> str:
    """The --bias value of a bias kind: a heat bias by its node (winding-heat: winding), an output bias by its name."""
    return kind.removesuffix("-heat")


def release_text(sigma: float | None) -> str:
    return "none" if sigma is None else f"{sigma:g}"


def release_option(value: str, consider: str) -> float | None:
    """--consider-release SIGMA (K, a number > 0, or none) as the magnet's 1-sigma above which it is not held (None:
    held always); without consider states there is nothing to release."""
    if consider == "none":
        return None
    return _positive_or_none(value, f"--consider-release must be a 1-sigma in K above 0 or none, not {value!r}")


def gate_option(value: str, flag_after: int) -> tuple[float, int] | None:
    """--gate SIGMA (a number > 0, or none) and --gate-flag-after N (>= 1) as the section's gate (None: none)."""
    if flag_after < 1:
        raise UsageError(f"--gate-flag-after must be at least 1, not {flag_after}")
    sigma = _positive_or_none(value, f"--gate must be a number of sigmas above 0 or none, not {value!r}")
    return None if sigma is None else (sigma, flag_after)


def _positive_or_none(value: str, sentence: str) -> float | None:
    """A finite number above 0, or None for "none"; `sentence` (a UsageError) for anything else."""
    import math

    if value.strip().lower() == "none":
        return None
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not math.isfinite(number) or number <= 0:
        raise UsageError(sentence)
    return number
