"""`bench observer`: tune a Kalman observer on training files and write a model artifact that carries it.

The observer corrects the model's state with a temperature sensor of one node (default: the winding column
winding_C, the winding node; a stator NTC column with --measure ntc_C). Its process noise Q (per node) and
measurement noise R are tuned on the training files (`--criterion magnet`: the magnet's log MSE over every training
file started with the magnet as measured, 30 K too warm and too cold; `likelihood`: the innovations' likelihood, the
magnet reference a second measurement while tuning), and written into a copy of --model as its `observer` section
(artifact schema version 3; the target runs it in float32, `target_sim.observer`). Without --train, the built-in
motor's training runs (20 and 60 °C in out/data, generated if missing) are used.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.commands.common import add_data_arguments, add_output_flags, check_writable, print_json
from bench.errors import UsageError
from bench.fileio import write_text_atomically


def add_subparser(subparsers) -> None:
    from bench.model.observer import DEPLOYED_FORM, TUNING_CRITERIA
    from target_sim.artifact import OUTPUTS
    from target_sim.observer import OBSERVER_FORMS

    p = subparsers.add_parser("observer", help="tune a Kalman observer (Q, R) on training files, add it to an artifact",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", type=Path, default=None,
                   help="model artifact to add the observer to (default: the packaged hammerstein one)")
    p.add_argument("--train", nargs="+", default=None, metavar="FILE",
                   help="training data files or globs (default: the built-in motor's 20 and 60 °C runs)")
    add_data_arguments(p)
    p.add_argument("--measure", default="winding_C", metavar="COLUMN",
                   help="the sensor's dataset column (default winding_C)")
    p.add_argument("--node", choices=OUTPUTS, default="winding", help="the model node the sensor sees (default "
                   "winding)")
    p.add_argument("--offset", type=float, default=0.0, help="the sensor's offset in K, subtracted from each reading")
    p.add_argument("--lag", type=float, default=0.0, help="the sensor's time constant in s (recorded; this version "
                   "of the filter ignores it)")
    p.add_argument("--criterion", choices=TUNING_CRITERIA, default="magnet", help="tuning criterion (default magnet)")
    p.add_argument("--form", choices=OBSERVER_FORMS.names(), default=DEPLOYED_FORM,
                   help=f"covariance form the target deploys (default {DEPLOYED_FORM}, see 'bench numerics "
                        "--observer')")
    p.add_argument("--evaluations", type=int, default=800, help="largest number of filter runs while tuning")
    p.add_argument("--out", type=Path, default=Path("out/model/observer.json"), help="artifact to write")
    add_output_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.commands.common import data_options
    from bench.drive.files import expand_data_paths, load_datasets
    from bench.model.default import default_artifact_path
    from bench.model.identify import IDENTIFICATION_COOLANTS
    from bench.model.observer import Measurement, observer_section, tune_observer, with_observer
    from bench.model.pipeline import load_campaign
    from target_sim.artifact import dumps, load_artifact

    if args.evaluations < 1:
        raise UsageError("--evaluations must be at least 1")
    if not 0 <= args.lag < 1e5:
        raise UsageError("--lag must be a non-negative number of seconds")
    check_writable(args.out, "--out")
    model_path = args.model or default_artifact_path()
    artifact = load_artifact(model_path)
    if args.train:
        mapping, period = data_options(args)
        datasets = load_datasets(expand_data_paths(args.train, "--train"), mapping, period)
    else:
        if args.mapping is not None:
            raise UsageError("--mapping applies to --train files, not to the built-in motor's datasets")
        campaign = load_campaign(None)
        datasets = [campaign[c] for c in IDENTIFICATION_COOLANTS]
    say = None if (args.quiet or args.json) else (lambda msg: print(msg, file=sys.stderr))
    progress = None
    if say:
        def progress(calls: int, cost: float) -> None:
            if calls % 50 == 0:
                say(f"tuning: {calls} filter runs, {args.criterion} criterion {cost:.6g}")
    measurement = Measurement(args.node, args.measure, args.offset, args.lag)
    fit = tune_observer(artifact, datasets, measurement, args.criterion, args.evaluations, progress)
    content = with_observer(artifact, observer_section(artifact, fit, datasets, args.form))
    write_text_atomically(args.out, dumps(content))
    report = {"model": str(model_path), "out": str(args.out), "sha256": content["sha256"],
              "measurement": {"node": args.node, "column": args.measure, "offset_C": args.offset, "lag_s": args.lag},
              "form": args.form, **content["observer"]["tuning"]}
    if args.json:
        print_json(report)
    else:
        tuning = content["observer"]["tuning"]
        q = ", ".join(f"{n} {v:.3g}" for n, v in tuning["q_C2_per_step"].items())
        print(f"observer of {model_path} ({artifact.kind}) on {len(datasets)} training file(s), measuring the "
              f"{args.node} node with {args.measure}; {args.criterion} criterion {fit.cost:.6g} after "
              f"{fit.evaluations} filter runs")
        print(f"Q per step (°C²): {q}; R {fit.r_C2:.3g} °C²; deployed form {args.form}")
        print(f"wrote {args.out} (sha256 {content['sha256'][:12]})")
    return 0
