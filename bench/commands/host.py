"""`bench host`: the host node on its own: replay a dataset to a target already on the bus, log every frame,
report what came back.

    bench host --data FILE [--mapping FILE] [--sample-period S|auto] [--model FILE] [--mode lockstep|realtime]
               [--speed X] [--rows N] [--log FILE]
               [--reply-timeout S] [--connect-timeout S] [--tolerate-gaps] [--json] [--quiet]
               [--fault KIND=VALUE ...] [--faults K=V,K=V] [--fault-seed N] [--tolerate-faults]
               [--target-events FILE] [--wait-for-listener SECONDS]
               [--criteria FILE] [--baseline FILE] [--junit-xml FILE]
               [-i INTERFACE] [-c CHANNEL] [-b BITRATE] [--bus-kwargs K=V ...] [--can-config FILE]

The target (`python -m target_sim`, or a real ECU) must run on the same bus; its heartbeat must carry the model
id of --model (default: the packaged artifact). A host frame this host did not send (another host on the channel,
e.g. a `bench run` started there while this one waited for its heartbeat) stops it in one sentence naming the
channel. Exit status 0 when every row was answered and nothing was lost,
1 when the run had missing replies, sequence gaps or heartbeat loss (unless --tolerate-gaps), or when the replies
differ from the offline float32 reference, 2 for bad arguments; every error is one sentence on stderr. The log is
analyzed as `bench run` analyzes its own (`bench.analysis.report.analyze_log`, no report): every reply is compared
with the model's offline float32 reference, so a target that computes something else (another loss table under
the same model id, say) is never clean, and --json prints the summary `bench run --json` prints ("rmse_C",
"max_abs_can_minus_float32_C", "figure_rows": the rows they are over and those a check left out, "metrics"; the
host's own figures, "rows_sent", "sequence_gaps", "target_state", ..., at the top and under "host"); a run whose
log holds no figures has no "metrics" and none of the keys made of them. The `host` package is the node itself
(session, replay, faults, logs) and knows no datasets: this command reads the dataset (through --mapping, as
`bench run`) and hands the host its drive rows, with the d/q currents (DriveCurrents) when the model has an
electrical loss model.

Acceptance criteria (--criteria, --baseline, --junit-xml) as `bench run`'s, judged on the log's figures: each
check's figure, limit and verdict in the JSON ("acceptance"), exit status 1 when any fails. With a target of your
own (a real ECU) "cycles" are the C28x estimate unless it sends the firmware engine's Timing4 frames.

Bus faults (`host.faults`; lockstep) are injected as by `bench run`; kill and freeze need `bench run`, which
owns the target process. To check detection, start the target with `--events FILE` and pass the same file as
`--target-events`; the summary goes into the JSON result ("faults") and next to the log (`<log>.faults.json`).
A run with injected faults exits 1 unless --tolerate-faults (and then only if every fault was detected).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING

from bench.commands.args import announce_logger, declare_files, warn_listener_drops
from bench.commands.common import SHOWN_NODES, add_output_flags, fmt, print_json
from bench.errors import UsageError
from bench.run.request import HOST, RunRequest, add_options
from dbc.transport import add_bus_arguments, config_from_args, resolve

if TYPE_CHECKING:  # the CLI builds every subcommand's parser at start: the run pipeline when this one runs
    from bench.run.judge import JudgedRun
    from host.results import HostResult


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("host", help="the host node alone, against a target already on the bus",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_options(p, HOST)   # the options of a run that apply to an attached target (`bench.run.request`)
    add_output_flags(p)
    add_bus_arguments(p)
    declare_files(p, inputs=('--data', '--model', '--target-events'), outputs=('--log',))
    p.set_defaults(func=run_host)


def _faults(args: argparse.Namespace):
    from host.faults import spec_from_args

    faults = spec_from_args(args)
    if faults is not None and faults.process_faults:
        raise UsageError("kill and freeze faults need the bench runner, which owns the target process: use "
                         "'bench run'")
    if faults is not None and faults.reply_rates():
        raise UsageError("reply faults are injected by the target: start it with 'python -m target_sim --faults "
                         f"{','.join(faults.reply_rates())}=P' (or use 'bench run')")
    return faults


def run_host(args: argparse.Namespace) -> int:
    """The adapter of the run pipeline (`bench.run`: request -> prepare -> execute -> judge, attached to a target
    already on the bus) to the command line."""
    from bench.acceptance.cli import finish_run, prepare
    from bench.run.execute import execute_attached
    from bench.run.judge import judge
    from bench.run.leftovers import clear_and_say
    from bench.run.prepare import prepare_run

    request = RunRequest.from_args(args)   # the run as the command line describes it (`bench.run.request`)
    faults = _faults(args)
    acceptor = prepare(args)   # a bad criteria or baseline file: one sentence, exit status 2, before any work
    config = resolve(config_from_args(args))
    if config.interface == "virtual":  # python-can's virtual bus lives in one process: no target could answer
        raise UsageError("the 'virtual' interface does not cross processes, so no target could answer the host; "
                         "use udp_multicast, socketcan or auto")
    quiet = args.quiet or args.json
    # the arguments' refusals before any work (`bench.run.prepare`); the dataset is read quietly, as always here
    prepared = prepare_run(request, HOST, faults, acceptor.check_data, quiet=True)
    clear_and_say(prepared.log_path, quiet)   # what a killed host left beside this log

    def announce() -> None:   # once the bus is this host's alone
        if not quiet:
            print(f"bench: host: {len(prepared.drive)} rows of {prepared.dataset.path} ({request.mode}) over "
                  f"{config.describe()}" + (f", injecting {faults.describe()}" if faults else ""), file=sys.stderr)
        announce_logger(config, args.quiet, "bench: host: ", wait_s=request.wait_for_listener)

    started = time.perf_counter()
    outcome = execute_attached(prepared, request, config, faults, announce=announce)
    warn_listener_drops(outcome.listener_drops, args.quiet, "bench: host: ")
    judged = judge(prepared, outcome, request, acceptor.gate, config, engine=outcome.result.engine, firmware=None,
                   started=started, need_figures=False)
    if args.json:
        print_json(judged.summary.to_json())
    else:
        _print_lines(outcome.result, judged)
    return finish_run(acceptor, judged.summary, command="bench host", subject="the host's run",
                      bus=config.describe(), status=judged.verdict.status,   # --tolerate-gaps: not for faults
                      model_id=f"{prepared.artifact.model_id:08x}", quiet=quiet)


def _print_lines(result: HostResult, judged: JudgedRun) -> None:
    """Without --json: the host's figures, the log's agreement with the reference, each problem on stderr."""
    metrics = judged.summary.metrics
    print(f"{result.rows_sent} rows sent, {result.replies} answered, {result.missing} missing, "
          f"{result.rows_per_s:.0f} rows/s, round trip p50 {result.round_trip_us['p50'] or 0:.0f} µs; "
          f"log {result.log_path}")
    if metrics is not None:
        agreement = metrics.agreement.max_abs_can_minus_float32_C
        print(f"max |CAN - {metrics.agreement.can_reference}| (°C): "
              + ", ".join(f"{t} {fmt(agreement.get(t), 4)}" for t in SHOWN_NODES)
              + f"; {metrics.figure_rows.text('RMSE and every figure')}")
    for problem in judged.summary.problems:
        print(f"bench: host: {problem}", file=sys.stderr)
