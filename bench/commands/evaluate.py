"""`bench evaluate`: accuracy of model artifacts on data.

- `--data FILE…` (files or globs, read through `--mapping`): each model on each file, nothing refitted and no
  training file needed: MSE, RMSE, NRMSE and max |error| per file and pooled, for winding and PM and every other
  measured node, float64 and float32, beside the baselines the artifact records (coolant; a low-pass of the
  copper loss fitted on the training files); `--plots DIR` draws one figure per file.
- A model with an observer (`bench observer`): on every file with its measurement columns, also open loop against
  the observer per node (float32, the target's own code; a node whose own reference column a measurement reads is
  labelled measured, every other row says when the observer is worse than the open loop) and the time the magnet
  takes to come within 2 K when started 30 K off, each way.
- `--data DIR` (or nothing): the Table 5 analogue on the built-in motor's 40 °C run, LTI LPTN vs Hammerstein at
  Δt 0.5-4 s (the Hammerstein model refitted at every Δt other than the artifact's).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.commands.args import declare_files
from bench.commands.common import (
    add_data_arguments,
    add_output_flags,
    check_writable,
    choice_list,
    float_list,
    print_json,
)
from bench.errors import BenchError, UsageError
from bench.model.deploy import DEPLOYED_NODES
from target_sim.artifact import OUTPUTS
from target_sim.kinds import MODEL_KINDS
from target_sim.kinds import REALIZATIONS as REALIZATION_KINDS

DEFAULT_DTS = [0.5, 1.0, 2.0, 4.0]
BUILT_IN_MOTOR = "virtual-200kw"


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("evaluate", help="accuracy of model artifacts on data files (or the Table 5 analogue)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", type=Path, action="append", default=None,
                   help="model artifact (repeat to compare several on --data files; default: the packaged "
                        "hammerstein one)")
    p.add_argument("--data", nargs="+", default=None, metavar="FILE",
                   help="data files or globs to evaluate on; or one directory with the built-in motor's three "
                        "datasets for the Table 5 analogue (default out/data)")
    add_data_arguments(p)
    p.add_argument("--dt", type=float_list, default=DEFAULT_DTS, help="Table 5: steps in s (default 0.5,1,2,4)")
    realizations = REALIZATION_KINDS.names()
    p.add_argument("--realization", choices=realizations, default=None,
                   help="deployed realization for the float32 rows (default: the artifact's)")
    p.add_argument("--plots", type=Path, default=None,
                   help="directory for the figures: one per data file, or with a directory the Figs. 6/7 analogues "
                        "(original vs balanced realization in float32)")
    p.add_argument("--plot-realizations", type=choice_list(realizations), default=["original", "balanced", "delta"],
                   help="realizations to plot (default original,balanced,delta)")
    add_output_flags(p)
    declare_files(p, inputs=('--model', '--data'), outputs=('--plots',))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.model.default import default_artifact_path

    if args.plots:
        check_writable(args.plots, "--plots", directory=True)
    paths = args.model or [default_artifact_path()]
    if args.data is not None and not _names_a_directory(args.data):
        return run_on_files(args, [_load(p) for p in paths], paths)
    if len(paths) > 1:
        raise UsageError("the Table 5 analogue takes one --model; pass data files with --data to compare several")
    if args.mapping is not None:
        raise UsageError("--mapping applies to --data files, not to the built-in motor's dataset directory")
    return run_table5(args, _load(paths[0]), paths[0], Path(args.data[0]) if args.data else None)


def _names_a_directory(data: list[str]) -> bool:
    """One --data argument that is a directory, or would be one (no such path, no suffix, no glob)."""
    if len(data) != 1:
        return False
    path = Path(data[0])
    return path.is_dir() or (not path.exists() and not path.suffix and not any(c in data[0] for c in "*?["))


def _load(path: Path):
    from target_sim.artifact import load_artifact

    return load_artifact(path)


def run_on_files(args: argparse.Namespace, artifacts: list, paths: list[Path]) -> int:
    from bench.commands.common import data_options
    from bench.drive.files import expand_data_paths, load_datasets
    from bench.model.fileeval import evaluate_files
    from target_sim.observer import has_observer

    if args.dt != DEFAULT_DTS or args.realization is not None:
        raise UsageError("--dt and --realization belong to the Table 5 analogue (a dataset directory); on data "
                         "files each model runs as its artifact says")
    periods = {a.data_sample_period for a in artifacts}
    if len(periods) > 1:
        raise UsageError("the models expect different data sample periods; evaluate them one at a time")
    period = periods.pop()
    mapping, given = data_options(args)
    files = expand_data_paths(args.data, "--data")
    datasets = load_datasets(files, mapping, given)
    for dataset in datasets:
        if abs(dataset.sample_period_s - period) > 1e-6 * period:
            raise BenchError(f"{dataset.path} is sampled every {dataset.sample_period_s:g} s, the model "
                             f"{paths[0]} was identified on data at {period:g} s; resample the file or use a model "
                             "identified at its period")
    say = None if (args.quiet or args.json) else (lambda msg: print(msg, file=sys.stderr))
    models, results = [], []
    for artifact, path in zip(artifacts, paths, strict=True):
        if say:
            say(f"evaluating {path} on {len(datasets)} file(s)")
        per_file, report = evaluate_files(artifact, datasets)
        results.append(per_file)
        models.append({"model": str(path), "sha256": artifact.sha256, "kind": artifact.kind,
                       "loss_model": artifact.loss_model, "dt": artifact.dt,
                       "motor": artifact.content.get("provenance", {}).get("motor", {}).get("name"), **report})
        if has_observer(artifact):
            models[-1]["observer"] = observer_report(artifact, datasets, say, args.plots)
    report = {"models": models}
    if args.plots:
        from bench.analysis.file_plots import file_figure

        labels = [f"{m['kind']} ({Path(m['model']).name})" for m in models]
        report["plots"] = [str(file_figure(d.name, [r[i] for r in results], labels, args.plots / f"{d.name}.png"))
                           for i, d in enumerate(datasets)]
    if args.json:
        print_json(report)
    else:
        print_file_table(report)
    return 0


def print_file_table(report: dict) -> None:
    head = f"{'file':24} {'estimator':28} {'node':8} {'prec':7} {'RMSE °C':>8} {'max|e| °C':>9} {'NRMSE':>7}"
    for m in report["models"]:
        print(f"model {m['model']} ({m['kind']}, {m['loss_model']} losses, Δt {m['dt']:g} s, "
              f"sha256 {m['sha256'][:12]})")
    print(head)
    print("-" * len(head))
    first = report["models"][0]
    for index, file in enumerate([*first["files"], None]):
        name = "pooled" if file is None else Path(file["file"]).name
        for node in first["pooled"]["nodes"]:
            for m in report["models"]:
                block = m["pooled"] if file is None else m["files"][index]
                for prec in ("float64", "float32"):
                    _row(name, f"{m['kind']} ({Path(m['model']).stem})", node, prec, block["nodes"][node][prec])
            block = first["pooled"] if file is None else first["files"][index]
            for baseline, per_node in block["baselines"].items():
                if node in per_node:
                    _row(name, f"baseline: {baseline}", node, "float64", per_node[node])
    worst = max(m["pooled"]["max_abs_f32_minus_f64_C"] for m in report["models"])
    print(f"largest |float32 - float64|: {worst:.4g} °C")
    for m in report["models"]:
        if "observer" in m:
            print_observer_table(m)
    for path in report.get("plots", []):
        print(f"wrote {path}")


def observer_report(artifact, datasets, say, plots: Path | None = None) -> dict:
    """Open loop vs observer per node and the recovery from a wrong initial magnet temperature, on every file that
    has the observer's measurement columns; with `plots`, each file's estimate with its ±2σ band."""
    from bench.observer.measured import lab_measurements, measurement_columns

    section = artifact.content["observer"]
    columns = measurement_columns(artifact)
    usable = [d for d in datasets if all(d.has(c) for c in columns)]
    return {"node": section["node"], "column": section["column"], "form": section["form"],
            "columns": columns, "measurements": [m.describe() for m in lab_measurements(artifact)],
            "states": section.get("states", list(OUTPUTS)),
            "skipped": [str(d.path) for d in datasets if not all(d.has(c) for c in columns)],
            **_observer_files(artifact, usable, say, plots)}


def _observer_files(artifact, datasets, say, plots: Path | None) -> dict:
    from bench.observer.evaluate import evaluate_observer
    from bench.observer.plots import observer_figure

    files, figures = [], []
    for d in datasets:
        result = evaluate_observer(artifact, d, say=say)
        files.append(result.as_dict())
        if plots is not None:
            figures.append(str(observer_figure(result, plots / f"{d.name}-observer.png")))
    return {"files": files, "plots": figures}


def print_observer_table(model: dict) -> None:
    from bench.drive.dataset import MEASURED_NODES

    obs = model["observer"]
    said = "; ".join(f"the {m['node']} node with {m.get('column') or ', '.join(m['columns'])} ({m['kind']})"
                     for m in obs.get("measurements", [{"node": obs["node"], "column": obs["column"],
                                                        "kind": "lagged-sensor"}]))
    print(f"observer of {model['model']}: {obs['form']} form, states {', '.join(obs.get('states', OUTPUTS))}; "
          f"measuring {said} (float32; a measured node is pulled to its measurement, so its error is no "
          "estimate's)")
    # a node is "measured" (its error no estimate's) only where a measurement reads its own reference column: an
    # end-winding NTC mapped onto ntc_C corrects the winding node, whose reference winding_C it does not read, so
    # an observer that worsens the winding there is flagged like on any other node
    read = set(obs.get("columns") or [obs["column"]])
    own = {node for node, column in MEASURED_NODES.items() if column in read}
    head = f"{'file':24} {'node':14} {'open loop RMSE':>14} {'max|e|':>7} {'observer RMSE':>14} {'max|e|':>7}"
    print(head)
    print("-" * len(head))
    for f in obs["files"]:
        for node, m in f["nodes"].items():
            measured = node in own
            label = f"{node} (measured)" if measured else node
            worse = m["observer"]["rmse"] > m["open_loop"]["rmse"] and not measured
            print(f"{Path(f['file']).name[:24]:24} {label:14} {m['open_loop']['rmse']:14.4f} "
                  f"{m['open_loop']['max_abs']:7.3f} {m['observer']['rmse']:14.4f} {m['observer']['max_abs']:7.3f}"
                  + ("  observer WORSE than open loop" if worse else ""))
        for r in f["recovery"]:
            print(f"{'':24} magnet started {r['offset_K']:+g} K off: open loop {_recovered(r['open_loop_s'])}, "
                  f"with the observer {_recovered(r['observer_s'])}")
    for path in obs.get("plots", []):
        print(f"wrote {path}")
    for path in obs["skipped"]:
        print(f"{path}: lacks a column of {', '.join(obs.get('columns', [obs['column']]))}, the observer was not "
              "evaluated")


def _recovered(seconds: float) -> str:
    """"within 2 K after 40 s", or "never within 2 K" (not by the end of the file)."""
    from bench.observer.evaluate import RECOVERY_BAND_K

    band = f"within {RECOVERY_BAND_K:g} K"
    return f"never {band}" if seconds == float("inf") else f"{band} after {seconds:.0f} s"


def _row(name: str, estimator: str, node: str, prec: str, m: dict) -> None:
    print(f"{name[:24]:24} {estimator[:28]:28} {node:8} {prec:7} {m['rmse']:8.4f} {m['max_abs']:9.3f} "
          f"{m['nrmse']:7.4f}")


def run_table5(args: argparse.Namespace, artifact, model_path: Path, data_dir: Path | None) -> int:
    from bench.model.evaluate import hammerstein_models, realization_comparison, table5
    from bench.model.pipeline import load_campaign

    if not MODEL_KINDS[artifact.kind].input_nonlinearity:
        raise BenchError(f"{model_path} is a {artifact.kind} artifact; the comparison needs a hammerstein one "
                         "(pass one with --model)")
    motor = artifact.content.get("provenance", {}).get("motor", {}).get("name")
    if motor not in (None, BUILT_IN_MOTOR):
        raise BenchError(f"{model_path} was identified for motor {motor!r}; the Table 5 analogue runs on the built-in "
                         "motor's datasets, so evaluate it on its own files with --data FILE…")
    datasets = load_campaign(data_dir)
    say = None if (args.quiet or args.json) else (lambda msg: print(msg, file=sys.stderr))
    models = hammerstein_models(artifact, datasets, args.dt, progress=say)
    rows = table5(artifact, datasets, models, args.realization or artifact.realization)
    report = {"model": str(model_path), "sha256": artifact.sha256,
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
    for domain in DEPLOYED_NODES:
        for row in report["rows"]:
            for prec in ("float64", "float32"):
                m = row[prec][domain]
                print(f"{domain:8} {row['model']:12} {row['dt']:4g} {prec:7} {m['mse']:9.4f} {m['rmse']:8.4f} "
                      f"{m['nrmse']:7.4f}")
    worst = max(r["max_abs_f32_minus_f64_C"] for r in report["rows"])
    print(f"largest |float32 - float64| over all rows: {worst:.4g} °C")
    for path in report.get("plots", []):
        print(f"wrote {path}")
