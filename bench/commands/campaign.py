"""`bench campaign`: sweeps of `bench run` over the axes of a TOML spec, on this machine or a Dask cluster.

    bench campaign run SPEC [--workers N | --cluster ADDRESS] [--out DIR] [--resume] [--timeout S]
                            [--set KEY=VALUE ...] [--json] [--quiet]
    bench campaign plan SPEC [--set KEY=VALUE ...] [--out DIR] [--json]
    bench campaign report DIR [--json]

Every combination of the spec's axes (cartesian product) is one run: `python -m bench run ... --json` in a
subprocess of a Dask worker, with its own target process, its own udp_multicast port, and its log, report, JSON
summary and stderr in OUT/runs/<run-id>.<attempt>/ (the id: a slug of the axis values and a hash of every
option, stable across invocations; the attempt: random, one directory per execution, the table's run_dir).
Default: a local cluster of N worker processes (--workers, default the CPU count); --cluster tcp://HOST:PORT uses
a running scheduler (its workers need the bench installed and OUT and the data at the same paths; while it has no
worker the campaign says so every 15 s, and gives up after 60 s). A run that crashes, times out (--timeout,
default the spec's or 1800 s) or loses its worker is retried once; a verdict that is not clean is a result. One
row per run goes into OUT/campaign.sqlite when it ends, once (a run the cluster executed twice is recorded once,
the later attempt discarded); --resume skips the runs the table holds as done. OUT/report/report.md (verdict
matrix, figures per axis) is rebuilt at the end, and by `bench campaign report DIR` from the table alone. `plan`
lists the runs without running them (with --out, and what the table there says of each). --set KEY=VALUE
overrides a fixed option, or an axis (a list: --set 'model=["hammerstein"]'), e.g. --set rows=2000 to try a spec
small.

Exit status 0 when every run is done and its `bench run` exited 0; 1 otherwise (the report lists why); 2 for a
bad argument or a bad spec, and for an OUT refused before any run (not empty, a campaign without --resume, another
campaign's table); SIGINT/SIGTERM stop the cluster and its runs, leave every row written whole, exit 130/143.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from pathlib import Path

from bench.campaign import spec as spec_module  # stdlib only: the spec format for --help
from bench.commands.args import declare_files, positive_float, positive_int
from bench.commands.common import add_output_flags, check_writable, print_json
from bench.errors import UsageError
from bench.progress import say

DEFAULT_OUT = Path("out/campaigns")


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("campaign", help="sweeps of bench runs over a TOML spec's axes, on a local or Dask "
                                               "cluster (run, plan, report)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    actions = p.add_subparsers(title="actions", dest="action", parser_class=type(p))

    run = actions.add_parser("run", help="run every combination of the spec's axes",
                             description=f"{__doc__}\n{spec_module.__doc__}",
                             formatter_class=argparse.RawDescriptionHelpFormatter)
    run.add_argument("spec", type=Path, metavar="SPEC", help="campaign spec (TOML)")
    run.add_argument("--workers", type=positive_int, default=None, metavar="N",
                     help=f"worker processes of the local cluster (default {os.cpu_count() or 1}, the CPU count)")
    run.add_argument("--cluster", default=None, metavar="ADDRESS",
                     help="a running Dask scheduler, e.g. tcp://10.0.0.5:8786, instead of the local cluster")
    run.add_argument("--timeout", type=positive_float, default=None, metavar="S",
                     help="seconds a run may take before it is stopped (default: the spec's, else 1800)")
    _out_and_set(run, "output directory")
    run.add_argument("--resume", action="store_true", help="skip the runs OUT's table holds as done")
    add_output_flags(run)
    declare_files(run, inputs=('SPEC',), outputs=('--out',))
    run.set_defaults(func=run_command)

    plan = actions.add_parser("plan", help="list the runs a spec makes, without running them")
    plan.add_argument("spec", type=Path, metavar="SPEC", help="campaign spec (TOML)")
    _out_and_set(plan, "a campaign's output directory: show what its table says of each run")
    add_output_flags(plan)
    declare_files(plan, inputs=('SPEC', '--out'))
    plan.set_defaults(func=plan_command)

    report = actions.add_parser("report", help="rebuild DIR/report from DIR/campaign.sqlite alone")
    report.add_argument("dir", type=Path, metavar="DIR", help="a campaign's output directory")
    add_output_flags(report)
    declare_files(report, inputs=('DIR',))
    report.set_defaults(func=report_command)
    p.set_defaults(func=_no_action)


def _out_and_set(p: argparse.ArgumentParser, out_help: str) -> None:
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help=f"{out_help} (default {DEFAULT_OUT}/<spec name>)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a fixed option or an axis of the spec (repeatable), e.g. rows=2000")


def _no_action(_args: argparse.Namespace) -> int:
    raise UsageError("'bench campaign' needs an action, one of run, plan, report (see 'bench campaign --help')")


def _out_dir(args: argparse.Namespace) -> Path:
    return args.out if args.out is not None else DEFAULT_OUT / args.spec.stem


def _check_out(out: Path, resume: bool) -> None:
    """Before anything is written: OUT must be new, empty, or (with --resume) a campaign's."""
    from bench.campaign.store import TABLE_NAME

    check_writable(out, "--out", directory=True)
    if (out / TABLE_NAME).exists():
        if not resume:
            raise UsageError(f"{out} already holds a campaign ({TABLE_NAME}); pass --resume to run only what it does "
                             "not hold as done, or choose another --out")
    elif out.is_dir() and any(out.iterdir()):
        raise UsageError(f"{out} is not empty and holds no campaign table; choose another --out")


def check_same_campaign(meta: dict[str, str], campaign, out: Path) -> None:
    """UsageError (one sentence, exit 2, before any run) when OUT's table holds another campaign than `campaign` (other
    axes or fixed options, from another spec or other --set values): a resume would mix the two campaigns' runs in
    one table and report, and replace the stored spec. A new table (no stored axes) is this campaign's."""
    from bench.campaign.store import holds_another

    if holds_another(meta, {"axes": campaign.axes, "fixed": campaign.fixed}):
        raise UsageError(f"{out} holds the campaign {meta.get('name')!r} of {meta.get('spec_path')} (spec sha256 "
                         f"{meta.get('spec_sha256', '')[:12]}…), whose axes or fixed options differ from "
                         f"{campaign.path}'s; resume it with that spec and the same --set values, or choose "
                         "another --out")


def run_command(args: argparse.Namespace) -> int:
    from bench.campaign.execute import check_reachable, run_campaign
    from bench.campaign.report import write_report
    from bench.campaign.spec import load_spec
    from bench.campaign.store import DONE, TABLE_NAME, Store

    if args.cluster is not None and args.workers is not None:
        raise UsageError("--workers sizes the local cluster; with --cluster the scheduler's own workers run the "
                         "campaign: drop one of them")
    campaign = load_spec(args.spec, args.set)
    out = _out_dir(args)
    _check_out(out, args.resume)
    if args.cluster is not None:
        check_reachable(args.cluster)        # an unreachable scheduler is one sentence, before anything is written
    quiet = args.quiet or args.json
    with Store(out / TABLE_NAME, create=True) as store:
        check_same_campaign(store.meta(), campaign, out)   # --resume into another campaign's table: refused
        store.set_meta({"name": campaign.name, "description": campaign.description,
                        "spec_path": str(campaign.path.resolve()), "spec_text": campaign.text,
                        "spec_sha256": hashlib.sha256(campaign.text.encode()).hexdigest(),
                        "axes": json.dumps(campaign.axes), "fixed": json.dumps(campaign.fixed),
                        "table": str((out / TABLE_NAME).resolve())})

        def note(text: str) -> None:
            if not quiet:
                say(f"bench: {text}")

        outcome = run_campaign(campaign, store, out, workers=args.workers or os.cpu_count() or 1,
                               address=args.cluster, resume=args.resume, timeout_s=args.timeout, quiet=quiet,
                               on_event=note)
        rows = {r["run_id"]: r for r in store.rows()}
    report = write_report(out)
    mine = [rows.get(run.run_id) for run in campaign.runs]
    counts: dict[str, int] = {}
    for row in mine:
        label = "not run" if row is None else (row["verdict"] if row["status"] == DONE else row["status"])
        counts[label] = counts.get(label, 0) + 1
    passed = sum(1 for r in mine if r is not None and r["status"] == DONE and r["exit_code"] == 0)
    summary = {"campaign": campaign.name, "runs": outcome.runs, "ran": outcome.ran, "skipped": outcome.skipped,
               "retried": outcome.retried, "discarded": outcome.discarded, "counts": counts, "passed": passed,
               "cluster": outcome.cluster, "workers": outcome.workers, "wall_s": round(outcome.wall_s, 2),
               "out": str(out), "table": str(out / TABLE_NAME), "report": str(report),
               "run_ids": [run.run_id for run in campaign.runs]}
    if args.json:
        print_json(summary)
    else:
        print(f"campaign {campaign.name}: {outcome.runs} run(s): "
              + ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
              + (f"; {outcome.skipped} done before (--resume)" if outcome.skipped else "")
              + (f"; {outcome.retried} retried" if outcome.retried else "")
              + (f"; {outcome.discarded} duplicate attempt(s) discarded" if outcome.discarded else "")
              + (f"; {outcome.wall_s:.1f} s on {outcome.cluster}" if outcome.cluster else ""))
        print(f"table {out / TABLE_NAME}, report {report}")
    if passed == outcome.runs:
        return 0
    if not args.json:
        print(f"bench: error: campaign {campaign.name}: {outcome.runs - passed} of {outcome.runs} run(s) did not pass "
              f"(" + ", ".join(f"{n} {k}" for k, n in sorted(counts.items()) if k != "clean") + f"); see {report}",
              file=sys.stderr)
    return 1


def plan_command(args: argparse.Namespace) -> int:
    from bench.campaign.spec import load_spec
    from bench.campaign.store import TABLE_NAME, Store

    campaign = load_spec(args.spec, args.set)
    rows: dict[str, dict] = {}
    if args.out is not None and (args.out / TABLE_NAME).is_file():
        with Store(args.out / TABLE_NAME) as store:
            rows = {r["run_id"]: r for r in store.rows()}
    listed = [{"run_id": run.run_id, "axes": run.axes, "options": run.options,
               "status": rows[run.run_id]["status"] if run.run_id in rows else None} for run in campaign.runs]
    if args.json:
        print_json({"campaign": campaign.name, "axes": campaign.axes, "fixed": campaign.fixed,
                    "timeout_s": campaign.timeout_s, "runs": listed})
        return 0
    print(f"campaign {campaign.name}: {len(listed)} run(s) over "
          + (" x ".join(f"{k} ({len(v)})" for k, v in campaign.axes.items()) or "no axis")
          + (f"; fixed {json.dumps(campaign.fixed)}" if campaign.fixed else ""))
    for item in listed:
        status = f"  [{item['status']}]" if item["status"] else ""
        print(f"{item['run_id']}  " + (", ".join(f"{k}={v}" for k, v in item["axes"].items()) or "-") + status)
    return 0


def report_command(args: argparse.Namespace) -> int:
    from bench.campaign.report import write_report
    from bench.campaign.store import TABLE_NAME, Store

    with Store(args.dir / TABLE_NAME) as store:
        runs = len(store.rows())
    report = write_report(args.dir)
    if args.json:
        print_json({"report": str(report), "runs": runs})
    else:
        print(f"wrote {report} ({runs} run(s))")
    return 0
