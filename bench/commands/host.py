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
the same model id, say) is never clean, and the JSON carries the same figures as `bench run --json` ("rmse_C",
"max_abs_can_minus_float32_C", "figure_rows": the rows they are over and those a check left out, "metrics").
The `host` package is the node itself (session, replay,
faults, logs) and knows no datasets: this command reads the dataset (through --mapping, as `bench run`) and hands
the host its drive rows, with the d/q currents (DriveCurrents) when the model has an electrical loss model.

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
from pathlib import Path

from bench.acceptance.cli import finish, prepare
from bench.acceptance.junit import CleanCase
from bench.commands.args import announce_logger, declare_files
from bench.commands.common import (
    SHOWN_NODES,
    add_output_flags,
    fmt,
    print_json,
)
from bench.errors import BenchError, UsageError
from bench.run.leftovers import clear_and_say
from bench.run.prepare import prepare_run
from bench.run.request import HOST, RunRequest, add_options
from dbc.database import host_frame_ids
from dbc.transport import (
    SenderGuard,
    add_bus_arguments,
    config_from_args,
    first_heard,
    resolve,
)
from host.faults import FaultSpecError, fault_note, spec_from_args
from host.procedure import run_dataset
from host.session import SessionError


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("host", help="the host node alone, against a target already on the bus",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_options(p, HOST)   # the options of a run that apply to an attached target (`bench.run.request`)
    add_output_flags(p)
    add_bus_arguments(p)
    declare_files(p, inputs=('--data', '--model', '--target-events'), outputs=('--log',))
    p.set_defaults(func=run_host)


def _faults(args: argparse.Namespace):
    faults = spec_from_args(args)
    if faults is not None and faults.process_faults:
        raise UsageError("kill and freeze faults need the bench runner, which owns the target process: use "
                         "'bench run'")
    if faults is not None and faults.reply_rates():
        raise UsageError("reply faults are injected by the target: start it with 'python -m target_sim --faults "
                         f"{','.join(faults.reply_rates())}=P' (or use 'bench run')")
    return faults


def run_host(args: argparse.Namespace) -> int:
    request = RunRequest.from_args(args)   # the run as the command line describes it (`bench.run.request`)
    faults = _faults(args)
    acceptor = prepare(args)   # a bad criteria or baseline file: one sentence, exit status 2, before any work
    config = resolve(config_from_args(args))
    if config.interface == "virtual":  # python-can's virtual bus lives in one process: no target could answer
        raise UsageError("the 'virtual' interface does not cross processes, so no target could answer the host; "
                         "use udp_multicast, socketcan or auto")
    # the arguments' refusals before any work (`bench.run.prepare`); the dataset is read quietly, as always here
    prepared = prepare_run(request, HOST, faults, acceptor.check_data, quiet=True)
    log_path, artifact, dataset = prepared.log_path, prepared.artifact, prepared.dataset
    drive, measurements = prepared.drive, prepared.measurements
    from bench.model.runs import initial_temperatures

    clear_and_say(log_path, args.quiet or args.json)   # what a killed host left beside this log
    bus = None
    try:
        bus = config.open()
        if (other := first_heard(bus, host_frame_ids())) is not None:  # two hosts would both drive the target
            raise SessionError(f"{config.describe()} already has a host sending (frame id "
                               f"0x{other.arbitration_id:03x}); stop it or pick another channel")
        bus = SenderGuard(bus, config, host_frame_ids(), "host")   # and one that starts later stops this run
        if not (args.quiet or args.json):
            print(f"bench: host: {len(drive)} rows of {dataset.path} ({request.mode}) over {config.describe()}"
                  + (f", injecting {faults.describe()}" if faults else ""), file=sys.stderr)
        announce_logger(config, args.quiet, "bench: host: ", wait_s=request.wait_for_listener)
        started = time.time()
        result = run_dataset(bus, drive, initial_temperatures(dataset), model_id=artifact.model_id,
                             mode=request.mode, speed=request.speed, sample_period_s=dataset.sample_period_s,
                             log_path=log_path, reply_timeout_s=request.reply_timeout,
                             connect_timeout_s=request.connect_timeout, faults=faults,
                             target_events=request.target_events, events_since=started, measurements=measurements)
    except FaultSpecError as exc:   # kept for its exit status: a plan the host refuses here (faults in real time at
        raise BenchError(str(exc)) from None   # too short a sample interval) exits 1, a bad --fault option 2
    finally:
        if bus is not None:
            bus.shutdown()
    from bench.analysis.results import SCHEMA_KEY, SCHEMA_VERSION, as_json, verdict_text
    from bench.analysis.verdict import verdict

    metrics, found = _analyze(log_path, artifact, dataset, config.nominal_bitrate, result.problems())
    acceptance = acceptor.judge(metrics, why_none="; ".join(found) or "the log has no figures")
    if metrics is not None:
        metrics.acceptance = acceptance
    outcome = verdict(result.problems() + found, fault_note(result.faults), faulted=result.faults is not None,
                      tolerate_faults=request.tolerate_faults, tolerate_gaps=request.tolerate_gaps)
    problems = outcome.problems
    injected = result.faults["injected_total"] if result.faults else 0
    clean = not problems and not injected
    sentence = verdict_text(clean, problems, injected, result.faults.get("undetected") if result.faults else 0)
    if args.json:
        figures = {} if metrics is None else {
            "max_abs_can_minus_float32_C": as_json(metrics.agreement.max_abs_can_minus_float32_C),
            "rmse_C": as_json(metrics.accuracy.rmse_C), "rmse_reference": as_json(metrics.accuracy.rmse_reference),
            "figure_rows": as_json(metrics.figure_rows), "notes": metrics.notes,
            "metrics": metrics.to_json(windows=False)}
        print_json({SCHEMA_KEY: SCHEMA_VERSION, **result.to_dict(), **figures, "problems": problems, "clean": clean,
                    "verdict": sentence, **({"acceptance": as_json(acceptance)} if acceptance is not None else {})})
    else:
        print(f"{result.rows_sent} rows sent, {result.replies} answered, {result.missing} missing, "
              f"{result.rows_per_s:.0f} rows/s, round trip p50 {result.round_trip_us['p50'] or 0:.0f} µs; "
              f"log {result.log_path}")
        if metrics is not None:
            agreement = metrics.agreement.max_abs_can_minus_float32_C
            print(f"max |CAN - {metrics.agreement.can_reference}| (°C): "
                  + ", ".join(f"{t} {fmt(agreement.get(t), 4)}" for t in SHOWN_NODES)
                  + f"; {metrics.figure_rows.text('RMSE and every figure')}")
        for problem in problems:
            print(f"bench: host: {problem}", file=sys.stderr)
    report = metrics.report if metrics is not None else None
    return finish(acceptor, acceptance, command="bench host", subject="the host's run",
                  status=outcome.status,   # --tolerate-gaps: not for faults (the shared rule)
                  clean=CleanCase(outcome.status == 0, sentence, tuple(problems)),
                  elapsed_s=time.time() - started, quiet=args.quiet or args.json,
                  properties={"model": f"{artifact.model_id:08x}", "engine": result.engine, "bus": config.describe(),
                              "log": result.log_path, "report": report},
                  attachments=[result.log_path])


def _analyze(log_path: Path, artifact, dataset, bitrate: int, host_problems: list[str]):
    """The log's metrics against the offline references (as `bench run` makes them) and its problems; (None, a
    sentence) when the log holds nothing to compare (a run that ended before its first row)."""
    from bench.analysis.report import analyze_log
    from host.canlog import LogError

    try:
        return analyze_log(log_path, artifact, dataset, bitrate=bitrate, extra_problems=host_problems)
    except (LogError, ValueError) as exc:
        return None, [f"the log {log_path} cannot be compared with the offline float32 reference ({exc})"]
