"""`bench run`: the main job. Start the simulated target, replay a dataset over CAN, log, report.

    bench run [--data FILE [--mapping FILE] [--sample-period S|auto]] [--model FILE] [--engine python|firmware]
              [--mode lockstep|realtime] [--speed X] [--rows N] [--log FILE]
              [--report DIR | --no-report] [--reply-timeout S] [--tolerate-gaps] [--seed N] [--json] [--quiet]
              [--fault KIND=VALUE ...] [--faults K=V,K=V] [--fault-seed N] [--tolerate-faults]
              [--wait-for-listener SECONDS] [--criteria FILE] [--baseline FILE] [--junit-xml FILE]
              [-i INTERFACE] [-c CHANNEL] [-b BITRATE] [--bus-kwargs K=V ...] [--can-config FILE]

Defaults: the generated 40 °C validation run (out/data, made if missing), the packaged model artifact, lockstep,
log out/run/bench.blf (format by suffix: .blf .asc .log .csv .mf4), report out/run/report/report.md with PNGs.
A user's own data file is read through --mapping (column names, units, derived columns, time column, separator)
at --sample-period (default auto: the mapping's, else the model's); its sample period must be the model's. A model
with an electrical loss model needs the d/q currents: the host then sends each row's DriveCurrents after its
DriveInputs and DriveTemps, and data without them is refused in one sentence before anything starts. A model with an
observer (`bench observer`) needs its measured column: the host sends each row's Measurements frame before its
DriveInputs, the target corrects its estimate with it and reports each node's 1-sigma (the report draws a ±2σ band);
the firmware engine runs it in its generated C (the `ud` and `steady` forms, every measurement kind, the flux linkage
from DriveVoltages and the row's currents; another form is refused before any work), and every engine refuses an
observer whose readings the frames cannot carry (the flux linkage on a loss-map model, two measurements in one
slot; exit 2).
Exit status 0 only when every step was answered, CAN temperatures equal the offline float32 reference within
±0.005 °C, and no heartbeat was lost (`--tolerate-gaps` reports gaps but exits 0). In the JSON summary (--json)
"clean" (true/false) comes with "verdict": "clean", or "not clean: " and the reasons ("; "-separated problems, or
the faults injected), and "rmse_C" with "rmse_reference": per node what its RMSE is against ("measured": the
data's temperature, "float64 model": the offline model, for nodes the data does not measure). It names the bus
it used ("bus": interface, channel, and the port of udp_multicast), `auto` resolved; at the start (with --json
too, not with --quiet) stderr has the `python -m can.logger ...` line that records the run's bus. udp_multicast
on a channel you chose (-c, CAN_CHANNEL, a config file) uses python-can's port 43113 unless --bus-kwargs port=N;
with no channel chosen the bench's own group and a port unique to the run, which exists only once the run has
started: `--wait-for-listener SECONDS` prints the logger line first and waits before the target starts, so a
logger started from it records the whole run. Frames other listeners on a udp bus lost at their full receive
buffers (a logger starved of CPU) are counted from the kernel's figures: a warning and "listener_drops" in the
JSON's "bus". A target already sending on
the channel is refused before the run starts its own, and so is a host; a host frame this run did not send stops
it at any time (`dbc.transport.SenderGuard`). A --log that cannot be written (a directory) is refused before the
run, and so is a --report directory holding other files. SIGINT, SIGTERM and SIGHUP stop the target, discard the
partial log and exit 128 + the signal (one inherited as ignored, as under nohup, stays ignored); what a killed run
left (a partial log of this --log, temporary directories) is removed by the next run once its process is gone.

Acceptance criteria (`bench.acceptance`, docs/ci.md): `--criteria FILE` (TOML, [criteria.NAME] tables) judges the
run's figures against limits: per-node RMSE and max error against the measurement or the float64 model, cycles per
step (counted on the firmware engine, estimated otherwise), deadline misses, missing replies, heartbeat losses, bus
load, and a regression gate against a stored summary (`--baseline FILE`: alone, "no node's RMSE more than 5 %
worse"). Each check's figure, limit and verdict go into the JSON ("acceptance") and the report; when any fails the
exit status is 1 and one sentence on stderr names each failed check; a bad criteria or baseline file is one
sentence, exit status 2, before anything runs. `--junit-xml FILE` writes a JUnit XML report: a testcase "clean"
and one per criterion, figure and limit in properties and the failure message, the log and report attached.

Fault injection (`host.faults`): e.g. `--faults drop=0.01,corrupt=0.001,kill=1 --fault-seed 7`. Bus faults
(drop, delay, duplicate, reorder, corrupt, stale_counter, wrong_length, unknown_id, out_of_range) hit the host's
drive frames; reply faults (reply_drop, reply_corrupt, ...) the target's temperature replies (the target injects
them); kill and freeze hit the target process, which the runner restarts. In lockstep the host retransmits rows
that got no reply and restores a lost target from its last StateCheckpoint, so the estimates stay the clean
run's; in real time (bus and reply faults only) nothing is sent again, a faulted row stays lost, and the report
shows what that cost the estimate. Every fault and gap is marked in the log (BenchEvent frames) and in
`<log>.faults.json`; the JSON summary's "faults" holds injected and detected counts per kind. A run with
injected faults exits 1 unless `--tolerate-faults`, and even then when a fault went undetected or anything the
faults do not explain went wrong.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from bench.commands.args import announce_logger, bus_from_args, declare_files, warn_listener_drops
from bench.commands.common import add_output_flags, print_json, print_summary
from bench.errors import UsageError
from bench.run.request import RUN, RunRequest, add_options
from dbc.transport import add_bus_arguments


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("run", help="run the CAN bench: target process + host replay + log + report",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_options(p, RUN)   # every option of a run (`bench.run.request`)
    add_output_flags(p)
    add_bus_arguments(p)
    declare_files(p, inputs=('--data', '--model'), outputs=('--log', '--report'), replaced=('--report',),
                  off_with={'--report': '--no-report'})
    p.set_defaults(func=run)


def fault_spec(args: argparse.Namespace):
    """The fault options as a FaultSpec (None without faults); FaultSpecError or UsageError (exit status 2) for a
    bad one."""
    from host.faults import spec_from_args

    spec = spec_from_args(args)
    if spec is not None and spec.process_faults and getattr(args, "mode", "lockstep") != "lockstep":
        raise UsageError("kill and freeze faults need lockstep mode (a lost target's rows cannot be sent again on a "
                         "real-time clock); drop them from --faults/--fault or use --mode lockstep")
    return spec


def run(args: argparse.Namespace) -> int:
    """The adapter of the run pipeline (`bench.run`: request -> prepare -> execute -> judge) to the command line."""
    from bench.acceptance.cli import finish_run, prepare
    from bench.progress import ProgressBar
    from bench.run.execute import execute_started
    from bench.run.inputs import firmware_for_engine
    from bench.run.judge import judge, node_cycles
    from bench.run.leftovers import clear_and_say
    from bench.run.prepare import prepare_run

    request = RunRequest.from_args(args)   # the run as the command line describes it (`bench.run.request`)
    faults = fault_spec(args)
    acceptor = prepare(args)   # a bad criteria or baseline file: one sentence, exit status 2, before any work
    quiet = args.quiet or args.json
    # what the arguments alone refuse comes first, before any work (the default data is generated by load_data)
    prepared = prepare_run(request, RUN, faults, acceptor.check_data, quiet=quiet)
    artifact, dataset, drive = prepared.artifact, prepared.dataset, prepared.drive
    bus = bus_from_args(args)
    # the firmware engine's ELF: packaged, or built once beside the log (before the run: no compiler, no run)
    firmware = firmware_for_engine(request.engine, artifact, Path(prepared.log_path).parent / "firmware-cache",
                                   quiet=quiet, isr=bool(request.isr_rate))
    if not quiet:
        injecting = f", injecting {faults.describe()}" if faults else ""
        print(f"bench: {artifact.kind} model {artifact.model_id:08x} ({request.engine} engine) on {len(drive)} rows of "
              f"{dataset.path} ({request.mode}) over {bus.describe()}{injecting}", file=sys.stderr)
    # with --json too: a script's user attaches a logger the same way (--wait-for-listener: before the target starts)
    clear_and_say(prepared.log_path, quiet)   # what a killed run left beside this log and in the temporary directory
    announce_logger(bus, args.quiet, wait_s=request.wait_for_listener)
    bar = ProgressBar(len(drive), request.mode, quiet)
    started = time.perf_counter()
    try:
        outcome = execute_started(prepared, request, bus, faults, firmware=firmware, progress=bar)
    finally:
        bar.close()
    warn_listener_drops(outcome.listener_drops, args.quiet)
    cycles = node_cycles(outcome.target_stats)
    run_info = {"mode": f"{request.mode}" + (f" x{request.speed:g}" if request.mode == "realtime" else ""),
                "bus": bus.describe(), "engine": _engine_label(request.engine, firmware, request.isr_rate),
                "node_cycles": cycles.text() if cycles else None}
    judged = judge(prepared, outcome, request, acceptor.gate, bus, engine=request.engine, firmware=firmware,
                   started=started, run_info=run_info)
    summary = judged.summary
    if args.json:
        print_json(summary.to_json())
    else:
        print_summary(summary.metrics, summary.problems, summary.faults)
    return finish_run(acceptor, summary, command="bench run", subject="the run", bus=bus.describe(),
                      status=judged.verdict.exit_status("the run", args.json),
                      model_id=f"{artifact.model_id:08x}", quiet=quiet)


def _engine_label(engine: str, firmware: Path | None, isr_rate_hz: int = 0) -> str:
    if firmware is None:
        return f"{engine} (float32 model)"
    isr = f", current loop interrupt at {isr_rate_hz} Hz" if isr_rate_hz else ""
    return f"firmware ({firmware.name}, emulated Cortex-M4F{isr})"
