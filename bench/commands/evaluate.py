"""`bench evaluate`: the Table 5 analogue (MSE, RMSE, NRMSE, LTI LPTN vs Hammerstein, float64 and float32)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.commands.common import add_output_flags, check_writable, choice_list, float_list, print_json
from bench.errors import BenchError
from bench.thermal.realizations import REALIZATIONS


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("evaluate", help="accuracy of a model artifact on the 40 °C validation run",
                              description=__doc__)
    p.add_argument("--model", type=Path, default=None, help="hammerstein artifact (default: the packaged one)")
    p.add_argument("--data", type=Path, default=None, help="directory with the three datasets (default out/data)")
    p.add_argument("--dt", type=float_list, default=[0.5, 1.0, 2.0, 4.0], help="steps in s (default 0.5,1,2,4)")
    p.add_argument("--realization", choices=REALIZATIONS, default=None,
                   help="deployed realization for the float32 rows (default: the artifact's)")
    p.add_argument("--plots", type=Path, default=None,
                   help="directory for the Figs. 6/7 analogues (original vs balanced realization in float32)")
    p.add_argument("--plot-realizations", type=choice_list(REALIZATIONS), default=["original", "balanced"],
                   help="realizations to plot (default original,balanced)")
    add_output_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.model.default import default_artifact_path
    from bench.model.evaluate import hammerstein_models, realization_comparison, table5
    from bench.model.pipeline import load_campaign
    from target_sim.artifact import ArtifactError, load_artifact

    model_path = args.model or default_artifact_path()
    try:
        artifact = load_artifact(model_path)
    except ArtifactError as exc:
        raise BenchError(str(exc)) from None
    if artifact.kind != "hammerstein":
        raise BenchError(f"{model_path} is a {artifact.kind} artifact; the comparison needs a hammerstein one "
                         "(pass one with --model)")
    if args.plots:
        check_writable(args.plots, "--plots", directory=True)
    datasets = load_campaign(args.data)
    say = None if (args.quiet or args.json) else (lambda msg: print(msg, file=sys.stderr))
    models = hammerstein_models(artifact, datasets, args.dt, progress=say)
    rows = table5(artifact, datasets, models, args.realization or artifact.realization)
    report = {"model": str(args.model or default_artifact_path()), "sha256": artifact.sha256,
              "validation": datasets[40].name, "rows": [r.as_dict() for r in rows]}
    if args.plots:
        from bench.analysis.model_plots import realization_figure

        evaluations = realization_comparison(artifact, datasets[40], models, args.plot_realizations)
        report["plots"] = [str(realization_figure(
            evaluations, name, args.plots / f"float32_{name}.png",
            f"Hammerstein model, {name} realization in float32 (40 °C validation)"))
            for name in args.plot_realizations]
    if args.json:
        print_json(report)
    else:
        print_table(report)
    return 0


def print_table(report: dict) -> None:
    print(f"model {report['model']} (sha256 {report['sha256'][:12]}), validation on {report['validation']}")
    head = f"{'domain':8} {'method':12} {'dt':>4} {'prec':7} {'MSE °C²':>9} {'RMSE °C':>8} {'NRMSE':>7}"
    print(head)
    print("-" * len(head))
    for domain in ("winding", "pm"):
        for row in report["rows"]:
            for prec in ("float64", "float32"):
                m = row[prec][domain]
                print(f"{domain:8} {row['model']:12} {row['dt']:4g} {prec:7} {m['mse']:9.4f} {m['rmse']:8.4f} "
                      f"{m['nrmse']:7.4f}")
    worst = max(r["max_abs_f32_minus_f64_C"] for r in report["rows"])
    print(f"largest |float32 - float64| over all rows: {worst:.4g} °C")
    for path in report.get("plots", []):
        print(f"wrote {path}")
