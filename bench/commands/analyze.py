"""`bench analyze LOG`: decode a bus log of this bench offline into the same report as `bench run`.

    bench analyze LOG [--model FILE] [--data FILE [--mapping FILE] [--sample-period S|auto]] [--xcp-elf ELF]
                      [--report DIR | --no-report] [--tolerate-faults] [--json] [--quiet]
                      [--criteria FILE] [--baseline FILE] [--junit-xml FILE]

The model defaults to the packaged artifact and must carry the log's model id (Status.ModelId). The measured
reference comes from --data, or else from a dataset in out/data whose rows match the drive values in the log
(so a log of the default `bench run` gets the same report); without one, RMSE is against the float64 model only.
A log of a model with an electrical loss model carries each row's d/q currents (DriveCurrents): the references
run on them, and --data must have them too.

A log with XCP DOWNLOADs (a calibration master changed the target during the run) is judged against the target's
twin, which replays them; a DOWNLOAD names its cell by address, so the twin lays out its cells as the target did:
by --xcp-elf, the firmware ELF of a firmware target (or the ELF a Python target had as --xcp-elf). Without it, a log
that `bench run --engine firmware` or `bench replay` wrote names that ELF in the note beside it (`<log>.elf.json`:
path and sha256), and the twin takes it, refused in one sentence when it is gone or its bytes changed (an
--xcp-elf that is not the noted ELF is refused too); a firmware target's log without a note takes the packaged
model's shipped ELF; for any other model's firmware the ELF is needed.

Exit status as `bench run`'s: 1 when the log is not clean, and a log with injected faults (BenchEvent marks; the
`<log>.faults.json` sidecar beside it says whether each was detected) is not, unless --tolerate-faults; a fault
the sidecar lists as undetected fails even then. Not clean either, whatever the faults: a log that is incomplete
(no Control STOP after the last START, or a .blf never closed: a killed run), values the target clamped or that
were not finite, frames of the target the host's checks reject (unless injected faults explain them) and frames
that pass them but are not of this session (replayed or forged: counted, shown, never used).

Acceptance criteria (--criteria, --baseline, --junit-xml) as `bench run`'s, judged on the log's figures: each
check's figure, limit and verdict in the JSON ("acceptance") and the report, exit status 1 when any fails.

The report directory is written at once (a temporary directory renamed into place); one that holds anything but
an earlier report is refused before the log is read.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from bench.acceptance.cli import add_acceptance_arguments, finish, prepare
from bench.commands.args import declare_files
from bench.commands.common import (
    add_data_arguments,
    add_output_flags,
    check_writable,
    data_options,
    print_json,
    print_summary,
)
from bench.errors import BenchError, UsageError
from bench.run.elfnote import check_given_elf, recorded_layout
from bench.run.inputs import data_mismatch, load_data, load_model, matching_dataset


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("analyze", help="decode a bus log offline into the bench report",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path, help="bus log (.blf .asc .log .csv .mf4)")
    p.add_argument("--model", type=Path, default=None, help="artifact the log was made with (default: packaged)")
    p.add_argument("--data", type=Path, default=None, help="dataset with the measured reference")
    add_data_arguments(p)
    p.add_argument("--xcp-elf", type=Path, default=None, metavar="ELF",
                   help="the firmware ELF whose addresses the target's XCP slave had (a firmware target's own, a "
                        "Python target's --xcp-elf): the twin replays the log's calibrations at them (default: a "
                        "firmware target's packaged ELF, else the Python slave's pages)")
    p.add_argument("--report", type=Path, default=None,
                   help="report directory (default: <log dir>/<log name>-report)")
    p.add_argument("--no-report", action="store_true",
                   help="skip the report (metrics and verdict are still computed), as 'bench run --no-report'")
    p.add_argument("--tolerate-faults", action="store_true",
                   help="exit 0 for a log with injected faults if every one was detected and nothing else went wrong")
    add_output_flags(p)
    add_acceptance_arguments(p)
    declare_files(p, inputs=('LOG', '--model', '--data', '--xcp-elf'), outputs=('--report',), replaced=('--report',),
                  off_with={'--report': '--no-report'})
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.acceptance.junit import CleanCase
    from bench.analysis.canmetrics import compute, data_identity
    from bench.analysis.logdecode import decode_log
    from bench.analysis.report import check_report_dir, write_report
    from bench.analysis.results import LogSummary
    from bench.analysis.verdict import fault_note, problems, verdict

    started = time.perf_counter()
    if args.no_report and args.report is not None:
        raise UsageError("--no-report skips the report that --report names; pass one of them")
    report_dir = None if args.no_report else args.report or args.log.with_name(f"{args.log.stem}-report")
    acceptor = prepare(args)   # a bad criteria or baseline file: one sentence, exit status 2, before the log is read
    if report_dir is not None:   # before the log is read: a report that cannot be written must not cost that
        check_writable(report_dir, "--report", directory=True)
        check_report_dir(report_dir)
    artifact, model_path = load_model(args.model)
    if args.xcp_elf is not None:    # an ELF of another model, no ELF, or not the one the log's note names: one
        check_given_elf(args.xcp_elf, artifact, args.log)  # sentence before the log is read
    dataset = None
    if args.data:  # read before the log: the loader's transient peak then does not add to the decoded log
        mapping, period = data_options(args)
        dataset = load_data(args.data, artifact, mapping=mapping, sample_period_s=period)
    record = decode_log(args.log)
    if record.model_id is not None and record.model_id != artifact.model_id:
        raise BenchError(f"log {args.log} was made with model {record.model_id:08x}, but {model_path} is "
                         f"{artifact.model_id:08x}; pass the log's artifact with --model")
    if record.initial is None:
        raise BenchError(f"log {args.log} has no complete RESET (ResetTemps1, ResetTemps2, Control RESET); "
                         "it cannot be compared with the model")
    if dataset is not None:
        mismatch = data_mismatch(dataset, record.drive)
        if mismatch:
            raise BenchError(f"--data {args.data} {mismatch}, so it is not the dataset log {args.log} was recorded "
                             "from; pass that one, or leave --data out to compare with the model only")
    else:
        dataset = matching_dataset(record.drive, artifact)
    acceptor.check_data(data_identity(dataset, record.rows), f"log {args.log}")   # before the figures are computed
    xcp_elf = args.xcp_elf or recorded_layout(args.log, record, artifact)
    try:
        results, refs = compute(record, artifact, dataset, xcp_elf=xcp_elf)
    except ValueError as exc:     # e.g. an electrical loss model and a log without the d/q currents
        raise BenchError(f"log {args.log} cannot be compared with {model_path}: {exc}") from None
    in_log = problems(results)
    results.acceptance = acceptor.judge(results)
    if report_dir is not None:
        results.report = str(write_report(report_dir, results, in_log, record, refs, dataset,
                                          {"mode": "analyzed from the log"}))  # the report `bench run` writes
    outcome = verdict(in_log, fault_note(results), faulted=results.faults is not None,
                      tolerate_faults=args.tolerate_faults)
    found = outcome.problems
    injected = bool(results.faults and results.faults.injected_total)
    if args.json:
        print_json(LogSummary(results, found, not found and not injected).to_json())
    else:
        print_summary(results, found)
        if dataset is None and not args.quiet:
            print("bench: no dataset matched the log: RMSE is against the float64 model only (pass --data)",
                  file=sys.stderr)
    status = outcome.exit_status(f"the log {args.log}", args.json)
    summary = LogSummary(results, found, not found and not injected)
    return finish(acceptor, results.acceptance, command="bench analyze", subject=f"the log {args.log}",
                  status=status, clean=CleanCase(status == 0, summary.to_json()["verdict"], tuple(found)),
                  elapsed_s=time.perf_counter() - started, quiet=args.quiet or args.json,
                  properties={"model": results.model.id, "engine": results.timing.engine,
                              "log": results.integrity.log, "report": results.report},
                  attachments=[results.integrity.log, results.report])
