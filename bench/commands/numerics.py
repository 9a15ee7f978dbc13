"""`bench numerics`: the paper's Tables 2-4 analogue for every realization of the linear block; with `--budget`,
the float32 error budget of a model artifact over a whole run (which part of the step costs how much)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

from bench.commands.args import declare_files
from bench.commands.common import add_data_arguments, add_output_flags, choice_list, float_list, print_json
from bench.errors import BenchError, UsageError
from bench.thermal.parameters import PARAMETER_SETS, parameter_set
from dbc.contract import TEMPERATURE_NODES
from target_sim.kinds import MODEL_KINDS
from target_sim.kinds import REALIZATIONS as REALIZATION_KINDS

if TYPE_CHECKING:  # the CLI builds every subcommand's parser at start: the realizations' numerics when one runs
    from bench.thermal.precision import PrecisionRow


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("numerics", help="condition numbers and float32 survival of each realization",
                              description=__doc__)
    p.add_argument("--params", default="table1-refined", help=f"parameter set: {', '.join(PARAMETER_SETS)}")
    p.add_argument("--disc", type=choice_list(("zoh", "tustin", "euler")), default=["zoh", "tustin"],
                   help="discretizations, comma-separated (default zoh,tustin)")
    p.add_argument("--dt", type=float_list, default=[0.5, 1.0, 2.0, 4.0], help="steps in s (default 0.5,1,2,4)")
    realizations = REALIZATION_KINDS.names()
    p.add_argument("--realizations", type=choice_list(realizations), default=list(realizations),
                   help="realizations, comma-separated (default all)")
    p.add_argument("--seed", type=int, default=7, help="seed of the synthetic 7274 s excitation")
    p.add_argument("--budget", action="store_true",
                   help="the float32 error budget of --model on --data: float32 in one part of the step at a time")
    p.add_argument("--observer", action="store_true",
                   help="the float32 covariance forms of --model's observer over a whole run of --data: smallest "
                        "eigenvalue of P, its symmetry error and |float32 - float64| of the estimate per form")
    p.add_argument("--model", type=Path, default=None,
                   help="--budget, --observer: model artifact (default: the packaged one; --observer needs one "
                        "with an observer, see 'bench observer')")
    p.add_argument("--data", type=Path, default=None,
                   help="--budget, --observer: dataset CSV (default: the 40 °C validation run in out/data, "
                        "generated if missing)")
    add_data_arguments(p)
    add_output_flags(p)
    declare_files(p, inputs=('--model', '--data'))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.budget and args.observer:
        raise UsageError("--budget and --observer are two reports; ask for one at a time")
    if args.budget:
        return run_budget(args)
    if args.observer:
        return run_observer(args)
    if args.model is not None or args.data is not None or args.mapping is not None:
        raise UsageError("--model, --data and --mapping belong to --budget or --observer")
    try:
        params = parameter_set(args.params)
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    from bench.thermal.excitation import SAMPLE_PERIOD_S, interval_means, synthetic_lti_inputs
    from bench.thermal.precision import numerics_report, precision_table

    started = time.perf_counter()
    samples = synthetic_lti_inputs(seed=args.seed)
    rows = precision_table(params, args.disc, args.dt, lambda dt: interval_means(samples, SAMPLE_PERIOD_S, dt),
                           args.realizations)
    report = numerics_report(params, args.params, rows)
    if args.json:
        print_json(report)
    else:
        print_tables(report, rows)
        if not args.quiet:
            print(f"\n{len(rows)} rows in {time.perf_counter() - started:.2f} s")
    return 0


def _fmt_list(values, digits=4) -> str:
    return " ".join(f"{v:.{digits}f}" for v in values)


def print_tables(report: dict, rows: list[PrecisionRow]) -> None:
    print(f"parameter set: {report['params']}")
    print(f"continuous eigenvalues (1/s): {_fmt_list(report['eigenvalues_continuous'], 7)}")
    print(f"time constants (s):           {_fmt_list(report['time_constants_s'], 2)}")
    header = (f"{'disc':7} {'dt':>4} {'realization':11} {'cond':>9}  {'eig float64':32}  "
              f"{'|eig| float32':32} {'f32':8} {'max err f32 (°C)':>16}")
    print()
    print(header)
    print("-" * len(header))
    for r in rows:
        stable = "stable" if r.stable_f32 else "UNSTABLE"
        err = f"{r.max_output_error_f32_C:.3e}" + (" (diverged)" if r.diverged_f32 else "")
        print(f"{r.discretization:7} {r.dt:4g} {r.realization:11} {r.cond:9.4f}  {_fmt_list(r.eig_f64):32}  "
              f"{_fmt_list(r.eig_f32_abs):32} {stable:8} {err:>16}")


def run_budget(args: argparse.Namespace) -> int:
    import sys

    from bench.commands.common import data_options
    from bench.model.artifact_eval import artifact_drive
    from bench.model.budget import error_budget
    from bench.model.default import default_artifact_path
    from bench.model.runs import initial_temperatures
    from bench.run.inputs import load_data, load_model

    artifact, model_path = load_model(args.model or default_artifact_path())
    if not MODEL_KINDS[artifact.kind].linear_block:
        raise BenchError(f"{model_path} is a pv-lptn model; the error budget covers the LTI LPTN and Hammerstein "
                         "kinds (a fixed linear block)")
    mapping, period = data_options(args)
    dataset = load_data(args.data, artifact, mapping=mapping, sample_period_s=period)
    say = None if (args.quiet or args.json) else (lambda part: print(f"budget: float32 in {part}", file=sys.stderr))
    started = time.perf_counter()
    rows, info = error_budget(artifact, artifact_drive(artifact, dataset), initial_temperatures(dataset), say)
    report = {"model": str(model_path), "sha256": artifact.sha256, "kind": artifact.kind,
              "realization": artifact.realization, "dt": artifact.dt, "data": str(dataset.path), **info,
              "rows": [{"part": r.part, "max_abs_C": r.max_abs_C, "worst_C": r.worst_C} for r in rows],
              "seconds": round(time.perf_counter() - started, 2)}
    if args.json:
        print_json(report)
    else:
        print(f"float32 error budget of {model_path} ({artifact.kind}, {artifact.realization}, Δt {artifact.dt:g} s) "
              f"on {dataset.path.name}, {info['steps']} steps: largest |y - y_float64| (°C) with float32 in one part")
        print(f"{'part':13} " + " ".join(f"{n:>10}" for n in TEMPERATURE_NODES))
        for r in rows:
            label = {"all": "all parts", "target": "the target"}.get(r.part, r.part)
            print(f"{label:13} " + " ".join(f"{r.max_abs_C[n]:10.2e}" for n in TEMPERATURE_NODES))
        print(f"all parts vs the target's own float32 code: {info['all_vs_target_max_abs_C']:.2e} °C")
    return 0


def run_observer(args: argparse.Namespace) -> int:
    import sys

    from bench.commands.common import data_options
    from bench.model.default import default_artifact_path
    from bench.observer.evaluate import form_comparison
    from bench.observer.measured import measured_nodes_of
    from bench.run.inputs import load_data, load_model
    from target_sim.observer import has_observer

    artifact, model_path = load_model(args.model or default_artifact_path())
    if not has_observer(artifact):
        raise BenchError(f"{model_path} has no observer; add one with 'bench observer --model {model_path}' and "
                         "pass the artifact it writes with --model")
    mapping, period = data_options(args)
    dataset = load_data(args.data, artifact, mapping=mapping, sample_period_s=period)
    say = None if (args.quiet or args.json) else (lambda msg: print(msg, file=sys.stderr))
    started = time.perf_counter()
    rows = form_comparison(artifact, dataset, say=say)
    deployed = artifact.content["observer"]["form"]
    report = {"model": str(model_path), "sha256": artifact.sha256, "kind": artifact.kind,
              "realization": artifact.realization, "dt": artifact.dt, "data": str(dataset.path),
              "measured_node": artifact.content["observer"]["node"], "measured_nodes": measured_nodes_of(artifact),
              "deployed_form": deployed,
              "rows": [r.as_dict() for r in rows], "seconds": round(time.perf_counter() - started, 2)}
    if args.json:
        print_json(report)
        return 0
    print(f"observer of {model_path} ({artifact.kind}, {artifact.realization}, Δt {artifact.dt:g} s) on "
          f"{dataset.path.name}, measuring the {' and '.join(report['measured_nodes'])} "
          f"node{'s' if len(report['measured_nodes']) > 1 else ''}; float32 over the whole run, P's "
          "eigenvalue in the state coordinates, its symmetry in the filter's own (node coordinates)")
    print(f"{'form':13} {'min eig P':>11} {'max |P-Pᵀ|/|P|':>16} {'max|f32-f64| °C':>16} {'worst node':>10}")
    for r in rows:
        mark = " (deployed)" if r.form == deployed else ""
        print(f"{r.form:13} {r.min_eigenvalue:11.3e} {r.max_symmetry_error:16.3e} {r.max_abs_f32_minus_f64_C:16.3e} "
              f"{r.worst_node:>10}{mark}")
    return 0
