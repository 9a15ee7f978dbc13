"""`bench identify`: PSO LPTN + Levenberg-Marquardt Hammerstein on the 20 and 60 °C runs -> model artifacts."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.commands.common import add_output_flags, check_writable, print_json
from bench.errors import UsageError
from bench.fileio import write_text_atomically
from bench.model.hammerstein_fit import FIT_PATHS
from bench.thermal.realizations import REALIZATIONS

KINDS = ("hammerstein", "lti-lptn", "pv-lptn")


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("identify", help="identify the LPTN and Hammerstein models and write artifacts",
                              description=__doc__)
    p.add_argument("--data", type=Path, default=None,
                   help="directory with cycle_coolant20/40/60.csv (default out/data, generated if missing)")
    p.add_argument("--dt", type=float, default=0.5, help="model step in s (default 0.5)")
    p.add_argument("--out", type=Path, default=Path("out/model/hammerstein.json"), help="artifact to write")
    p.add_argument("--kind", choices=KINDS, default="hammerstein", help="model kind of --out")
    p.add_argument("--realization", choices=REALIZATIONS, default="balanced",
                   help="realization deployed in the artifact (default balanced)")
    p.add_argument("--fit-path", choices=tuple(FIT_PATHS), default="statespace",
                   help="polynomial (the paper's, companion coordinates) or statespace (balanced coordinates)")
    p.add_argument("--all-kinds", action="store_true",
                   help="also write the other two model kinds beside --out (<stem>-<kind>.json)")
    p.add_argument("--swarm", type=int, default=220, help="PSO swarm size (default 220)")
    p.add_argument("--iterations", type=int, default=100, help="PSO iterations (default 100)")
    p.add_argument("--lm-iterations", type=int, default=100, help="Levenberg-Marquardt iterations (default 100)")
    p.add_argument("--seed", type=int, default=0, help="PSO seed (default 0)")
    add_output_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.model.pipeline import identify_from_directory, validation_metrics

    if not 0 < args.dt < float("inf") or args.swarm < 2 or args.iterations < 1 or args.lm_iterations < 1:
        raise UsageError("--dt must be positive, --swarm at least 2 and the iteration counts at least 1")
    kinds = KINDS if args.all_kinds else (args.kind,)
    outputs = {kind: args.out if kind == args.kind else args.out.with_name(f"{args.out.stem}-{kind}.json")
               for kind in kinds}
    for path in outputs.values():  # before the identification, not after it
        check_writable(path, "--out")
    progress = None if (args.quiet or args.json) else _progress_bar()
    result, datasets = identify_from_directory(args.data, dt=args.dt, swarm_size=args.swarm,
                                               pso_iterations=args.iterations, lm_iterations=args.lm_iterations,
                                               seed=args.seed, fit_path=args.fit_path, progress=progress)
    metrics = validation_metrics(result, datasets, args.realization)
    written = {}
    for kind, path in outputs.items():
        realization = args.realization if kind != "pv-lptn" else "physical"
        write_text_atomically(path, _artifact_text(result.content(kind, realization, metrics)))
        written[kind] = str(path)
    summary = {"artifacts": written, "dt": args.dt, "fit_path": args.fit_path, "realization": args.realization,
               "lptn_parameters": result.lptn.params.as_dict(), "pso_cost": result.lptn.cost,
               "pso_history": result.lptn.history, "lm": {"rms_initial": result.hammerstein.cost_initial,
                                                          "rms_final": result.hammerstein.cost_final,
                                                          "evaluations": result.hammerstein.evaluations},
               "timings_s": result.timings_s, "validation": metrics}
    if args.json:
        print_json(summary)
    else:
        _print_summary(summary)
    return 0


def _artifact_text(content: dict) -> str:
    from target_sim.artifact import dumps

    return dumps(content)


def _progress_bar():
    from tqdm import tqdm

    bars = {}

    def update(stage: str, iteration: int, cost: float) -> None:
        if stage not in bars:
            for bar in bars.values():
                bar.close()
            bars[stage] = tqdm(desc="PSO LPTN" if stage == "pso" else "LM Hammerstein", unit="it", file=sys.stderr,
                               leave=True)
        bars[stage].update(1)
        bars[stage].set_postfix(cost=f"{cost:.4g}")

    return update


def _print_summary(s: dict) -> None:
    print(f"PSO {s['timings_s']['pso']:.1f} s (cost {s['pso_cost']:.4f}), "
          f"LM {s['timings_s']['lm']:.1f} s (RMS {s['lm']['rms_initial']:.3f} -> {s['lm']['rms_final']:.3f} °C)")
    print("validation (40 °C), RMSE °C:")
    for model, m in s["validation"].items():
        for prec in ("float64", "float32"):
            print(f"  {model:12} {prec}  winding {m[prec]['winding']['rmse']:.4f}   PM {m[prec]['pm']['rmse']:.4f}")
        print(f"  {model:12} largest |float32 - float64|: {m['max_abs_f32_minus_f64_C']:.4g} °C")
    for kind, path in s["artifacts"].items():
        print(f"wrote {kind} artifact {path}")
