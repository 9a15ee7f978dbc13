"""`bench robustness`: how much noise, bias, drift, quantization, dropped samples, parameter error, a wrong start
and Δt jitter move a model's estimate, measured with the target's own float32 code offline.

    bench robustness [--model M]… [--data FILE… [--mapping F]] [--spec FILE] [--seeds N] [--rows N]
                     [--workers N | --cluster ADDRESS] [--out DIR] [--resume] [--json] [--quiet]

Every (perturbation kind, subject, magnitude) of the spec (default: every kind at its defaults, sensible for a
traction drive) is one case per model and data file; the random kinds (noise, dropout, jitter) run --seeds lanes
at once, one per Monte Carlo seed. The cases run on Dask (a local cluster of --workers processes, or the scheduler
at --cluster; the workers need the models and data at the same paths), each outcome a row of OUT/robustness.sqlite
when it ends; a case whose worker died is retried once; --resume skips the cases the table holds as done. At the
end OUT/report/ holds robustness.json, report.md (the sensitivity table per node: Δ RMSE and Δ max |error| vs the
clean run with the Monte Carlo spread, the three perturbations that move each node most, the worst case, the
filtering trade-off), a tornado plot per node and the filtering plot. Default data: the built-in motor's 40 °C
validation run; default model: the packaged hammerstein artifact. A model with an observer (`bench observer`)
runs open loop and observer side by side on the same perturbed inputs, its measurement channels (ntc_C,
winding_C, u_d_V, u_q_V) perturbed like any input (a dropped sample: no reading); see
examples/robustness/observer.toml.

Exit status 0 when every case is done (a diverged model is a result); 1 when a case failed; 2 for a bad argument
or a bad spec, and for an OUT refused before any case (not empty, a study without --resume, another study's table);
SIGINT/SIGTERM leave every row written whole (resume with --resume).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from pathlib import Path

from bench.commands.args import declare_files, positive_int
from bench.commands.common import add_data_arguments, add_output_flags, check_writable, print_json
from bench.errors import BenchError, UsageError
from bench.progress import say

DEFAULT_OUT = Path("out/robustness")


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("robustness", help="sensitivity of a model's estimate to input, parameter, start and "
                                                 "timing errors (Monte Carlo, on a local or Dask cluster)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", type=Path, action="append", default=None,
                   help="model artifact (repeatable; default: the packaged hammerstein one)")
    p.add_argument("--data", nargs="+", default=None, metavar="FILE",
                   help="data files (default: the built-in motor's 40 °C validation run, made in out/data if missing)")
    add_data_arguments(p)
    p.add_argument("--spec", type=Path, default=None, metavar="FILE",
                   help="robustness spec (TOML; see examples/robustness/default.toml); default: every kind at its "
                        "defaults")
    p.add_argument("--seeds", type=positive_int, default=None, metavar="N",
                   help="Monte Carlo seeds of the random kinds (default: the spec's, else 8)")
    p.add_argument("--rows", type=positive_int, default=None, metavar="N",
                   help="only the first N rows of each data file (to try a study small)")
    p.add_argument("--workers", type=positive_int, default=None, metavar="N",
                   help=f"worker processes of the local cluster (default {os.cpu_count() or 1}, the CPU count)")
    p.add_argument("--cluster", default=None, metavar="ADDRESS",
                   help="a running Dask scheduler, e.g. tcp://10.0.0.5:8786, instead of the local cluster")
    p.add_argument("--serial", action="store_true",
                   help="run the cases in a plain loop in this process (no Dask), e.g. to compare wall times")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default {DEFAULT_OUT})")
    p.add_argument("--resume", action="store_true", help="skip the cases OUT's table holds as done")
    add_output_flags(p)
    declare_files(p, inputs=('--model', '--data', '--spec'), outputs=('--out',))
    p.set_defaults(func=run)


def _check_out(out: Path, resume: bool) -> None:
    from bench.robustness.store import TABLE_NAME

    check_writable(out, "--out", directory=True)
    if (out / TABLE_NAME).exists():
        if not resume:
            raise UsageError(f"{out} already holds a robustness study ({TABLE_NAME}); pass --resume to run only "
                             "what it does not hold as done, or choose another --out")
    elif out.is_dir() and any(out.iterdir()):
        raise UsageError(f"{out} is not empty and holds no robustness table; choose another --out")


def check_same_study(meta: dict[str, str], case_ids: list[str], out: Path) -> None:
    """UsageError (one sentence, exit 2, before any case runs) when OUT's table holds another study than these cases
    (a case id names its model, data, rows, perturbation and seed: another spec, --seeds, model or data makes others),
    as `bench campaign` refuses a resume into another campaign (`bench.campaign.store.holds_another`)."""
    from bench.campaign.store import holds_another

    if holds_another(meta, {"case_ids": case_ids}):
        study = json.loads(meta.get("study", "{}"))
        digest = hashlib.sha256(meta.get("spec_text", "").encode()).hexdigest()[:12]
        spec = study.get("spec") or "the built-in spec"
        raise UsageError(f"{out} holds the robustness study {study.get('name')!r} of {spec} (spec sha256 {digest}…), "
                         "whose cases differ from this one's (another spec, --seeds, --rows, model or data); resume "
                         "it with the same spec and options, or choose another --out")


def _inputs(args: argparse.Namespace):
    """[(path, artifact)], [dataset], the mapping path: everything checked before anything is written."""
    from bench.commands.common import data_options
    from bench.drive.files import expand_data_paths, load_datasets
    from bench.model.default import default_artifact_path
    from target_sim.artifact import load_artifact

    paths = [p.resolve() for p in (args.model or [default_artifact_path()])]
    models = [(p, load_artifact(p)) for p in paths]
    if args.data is None:
        if args.mapping is not None:
            raise UsageError("--mapping applies to --data files")
        from bench.drive.generate import ensure_default_datasets

        files = [ensure_default_datasets()[40].resolve()]
        mapping, given = None, None
    else:
        files = [f.resolve() for f in expand_data_paths(args.data, "--data")]
        mapping, given = data_options(args)
    datasets = load_datasets(files, mapping, given)
    for dataset in datasets:
        for path, artifact in models:
            period = artifact.data_sample_period
            if abs(dataset.sample_period_s - period) > 1e-6 * period:
                raise BenchError(f"{dataset.path} is sampled every {dataset.sample_period_s:g} s, the model {path} "
                                 f"was identified on data at {period:g} s; resample the file or use another model")
    return models, datasets, given


def run(args: argparse.Namespace) -> int:
    from bench.robustness.cases import StudyInput, model_cases
    from bench.robustness.channels import observer_description
    from bench.robustness.kinds import PERTURBATIONS
    from bench.robustness.report import write_report
    from bench.robustness.spec import load_spec
    from bench.robustness.store import TABLE_NAME, CaseStore
    from bench.robustness.study import run_study

    if args.cluster is not None and (args.workers is not None or args.serial):
        raise UsageError("--cluster runs the study on the scheduler's workers: drop --workers/--serial")
    models, datasets, given = _inputs(args)
    subjects = {name: tuple(dict.fromkeys(s for _, a in models for s in kind.subjects(a)))
                for name, kind in PERTURBATIONS.items()}
    spec = load_spec(args.spec, subjects)
    seeds = args.seeds or spec.seeds
    if seeds != spec.seeds:
        from dataclasses import replace

        spec = replace(spec, seeds=seeds)
    out = args.out
    _check_out(out, args.resume)
    if args.cluster is not None:
        from bench.campaign.execute import check_reachable

        check_reachable(args.cluster)
    mapping = str(args.mapping.resolve()) if args.mapping else None
    cases = []
    for path, artifact in models:
        for dataset in datasets:
            source = StudyInput(str(path), artifact.sha256, str(Path(dataset.path).resolve()), dataset.sha256,
                                mapping, given, args.rows)
            cases += model_cases(source, artifact, spec, len(cases))
    quiet = args.quiet or args.json

    def note(text: str) -> None:
        if not quiet:
            say(f"bench: {text}")     # not onto the bar's line

    info = {"name": spec.name, "description": spec.description, "seeds": spec.seeds, "seed": spec.seed,
            "spec": str(args.spec) if args.spec else None, "rows": args.rows,
            "models": [str(p) for p, _ in models], "data": [str(Path(d.path).resolve()) for d in datasets],
            "sample_periods": {str(Path(d.path).resolve()): d.sample_period_s for d in datasets},
            "observers": {str(p): observer_description(a) for p, a in models if observer_description(a)}}
    with CaseStore(out / TABLE_NAME, create=True) as store:
        check_same_study(store.meta(), [c.case_id for c in cases], out)   # --resume with another spec: refused
        store.set_meta({"study": json.dumps(info), "spec_text": spec.text,
                        "case_ids": json.dumps([c.case_id for c in cases])})   # the report's cases, in order
        outcome = run_study(cases, store, workers=args.workers or os.cpu_count() or 1, address=args.cluster,
                            resume=args.resume, serial=args.serial, quiet=quiet, on_event=note)
        rows = {r["case_id"]: r for r in store.rows()}
    report = write_report(out)
    mine = [rows.get(c.case_id) for c in cases]
    not_done = [c.case_id for c, r in zip(cases, mine, strict=True) if r is None or r["status"] != "done"]
    diverged = sum(1 for r in mine if r is not None and r["outcome"] == "diverged")
    summary = {"study": spec.name, "cases": outcome.cases, "ran": outcome.ran, "skipped": outcome.skipped,
               "retried": outcome.retried, "discarded": outcome.discarded, "diverged": diverged,
               "not_done": len(not_done),
               "cluster": outcome.cluster, "workers": outcome.workers, "wall_s": round(outcome.wall_s, 2),
               "out": str(out), "table": str(out / TABLE_NAME), "report": str(report),
               "json": str(out / "report" / "robustness.json")}
    if args.json:
        print_json(summary)
    else:
        print(f"robustness {spec.name}: {outcome.cases} case(s), {outcome.ran} run"
              + (f", {outcome.skipped} done before (--resume)" if outcome.skipped else "")
              + (f", {outcome.retried} retried" if outcome.retried else "")
              + (f", {outcome.discarded} duplicate outcome(s) discarded" if outcome.discarded else "")
              + (f", {diverged} diverged" if diverged else "")
              + (f"; {outcome.wall_s:.1f} s on {outcome.cluster}" if outcome.cluster else ""))
        print(f"table {out / TABLE_NAME}, report {report}")
    if not_done:
        if not args.json:
            print(f"bench: error: robustness {spec.name}: {len(not_done)} of {len(cases)} case(s) did not finish; "
                  f"see {report}", file=sys.stderr)
        return 1
    return 0
