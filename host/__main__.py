"""`python -m host`: replay a dataset to a running target over CAN, log every frame, report what came back.

    python -m host --data FILE [--model FILE] [--mode lockstep|realtime] [--speed X] [--rows N] [--log FILE]
                   [--reply-timeout S] [--connect-timeout S] [--tolerate-gaps] [--json] [--quiet]
                   [--fault KIND=VALUE ...] [--faults K=V,K=V] [--fault-seed N] [--tolerate-faults]
                   [--target-events FILE]
                   [-i INTERFACE] [-c CHANNEL] [-b BITRATE] [--bus-kwargs K=V ...] [--can-config FILE]

The target (`python -m target_sim`) must run on the same bus; its heartbeat must carry the model id of --model
(default: the packaged artifact). Exit status 0 when every row was answered and nothing was lost, 1 when the run
had missing replies, sequence gaps or heartbeat loss (unless --tolerate-gaps), 2 for bad arguments; every error
is one sentence on stderr.

Bus faults (`host.faults`; lockstep) are injected as by `bench run`; kill and freeze need `bench run`, which
owns the target process. To check detection, start the target with `--events FILE` and pass the same file as
`--target-events`; the summary goes into the JSON result ("faults") and next to the log (`<log>.faults.json`).
A run with injected faults exits 1 unless --tolerate-faults (and then only if every fault was detected).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from dbc import HOST_FRAME_IDS
from host.canlog import LogError, check_log_path
from host.faults import FaultSpecError, add_fault_arguments, fault_note, spec_from_args
from host.replay import DataRangeError
from host.run import MODES, run_dataset
from host.session import SessionError
from target_sim.artifact import ArtifactError, load_artifact
from target_sim.transport import BusUnavailable, add_bus_arguments, config_from_args, first_heard, resolve


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        print(f"host: error: {message} (see 'python -m host --help')", file=sys.stderr)
        raise SystemExit(2)


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive number")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="python -m host", description=__doc__.split("\n\n")[0],
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, required=True, help="dataset CSV (bench.drive schema)")
    p.add_argument("--model", type=Path, default=None,
                   help="artifact the target must run (default: the packaged one)")
    p.add_argument("--mode", choices=MODES, default="lockstep")
    p.add_argument("--speed", type=_positive, default=1.0, help="realtime speed factor (default 1)")
    p.add_argument("--rows", type=int, default=None, help="replay only the first N rows")
    p.add_argument("--log", type=Path, default=Path("out/host/host.blf"),
                   help="bus log, format by suffix .blf .asc .log .csv .mf4 (default out/host/host.blf)")
    p.add_argument("--reply-timeout", type=_positive, default=0.05, help="seconds per reply (default 0.05)")
    p.add_argument("--connect-timeout", type=_positive, default=15.0,
                   help="seconds to wait for the target's heartbeat (default 15)")
    p.add_argument("--tolerate-gaps", action="store_true", help="exit 0 despite missing replies (still reported)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    add_fault_arguments(p, process_faults=False)
    p.add_argument("--target-events", type=Path, default=None, metavar="FILE",
                   help="the target's detection journal (its --events file), to check that faults were detected")
    add_bus_arguments(p)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        faults = spec_from_args(args)
    except FaultSpecError as exc:
        parser.error(str(exc))
    if faults is not None and faults.process_faults:
        parser.error("kill and freeze faults need the bench runner, which owns the target process: use 'bench run'")
    if faults is not None and faults.reply_rates():
        parser.error("reply faults are injected by the target: start it with 'python -m target_sim --faults "
                     f"{','.join(faults.reply_rates())}=P' (or use 'bench run')")
    from bench.drive.dataset import DatasetError, load_dataset
    from bench.model.default import default_artifact_path
    from bench.model.runs import drive_matrix, initial_temperatures

    bus = None
    try:
        config = resolve(config_from_args(args))
        if config.interface == "virtual":  # python-can's virtual bus lives in one process: no target could answer
            parser.error("the 'virtual' interface does not cross processes, so no target could answer the host; "
                         "use udp_multicast, socketcan or auto")
        artifact = load_artifact(args.model or default_artifact_path())
        dataset = load_dataset(args.data, sample_period_s=artifact.data_sample_period)
        log_path = check_log_path(args.log)
        bus = config.open()
        if (other := first_heard(bus, HOST_FRAME_IDS)) is not None:  # two hosts would both drive the target
            raise SessionError(f"{config.describe()} already has a host sending (frame id "
                               f"0x{other.arbitration_id:03x}); stop it or pick another channel")
        drive = drive_matrix(dataset)
        if args.rows is not None:
            drive = drive[: max(args.rows, 1)]
        if not (args.quiet or args.json):
            print(f"host: {len(drive)} rows of {dataset.path} ({args.mode}) over {config.describe()}"
                  + (f", injecting {faults.describe()}" if faults else ""), file=sys.stderr)
        started = time.time()
        result = run_dataset(bus, drive, initial_temperatures(dataset), model_id=artifact.model_id,
                             mode=args.mode, speed=args.speed, sample_period_s=dataset.sample_period_s,
                             log_path=log_path, reply_timeout_s=args.reply_timeout,
                             connect_timeout_s=args.connect_timeout, faults=faults,
                             target_events=args.target_events, events_since=started)
    except (ArtifactError, DatasetError, LogError, BusUnavailable, SessionError, DataRangeError,
            FaultSpecError) as exc:
        print(f"host: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("host: interrupted", file=sys.stderr)
        return 130
    finally:
        if bus is not None:
            bus.shutdown()
    problems = result.problems()
    note = fault_note(result.faults)
    if note and not args.tolerate_faults:
        problems.append(note)
    if args.json:
        injected = bool(result.faults and result.faults["injected_total"])
        json.dump({**result.to_dict(), "problems": problems, "clean": not problems and not injected}, sys.stdout,
                  indent=2)
        sys.stdout.write("\n")
    else:
        print(f"{result.rows_sent} rows sent, {result.replies} answered, {result.missing} missing, "
              f"{result.rows_per_s:.0f} rows/s, round trip p50 {result.round_trip_us['p50'] or 0:.0f} µs; "
              f"log {result.log_path}")
        for problem in problems:
            print(f"host: {problem}", file=sys.stderr)
    if problems and (result.faults is not None or not args.tolerate_gaps):  # --tolerate-gaps: not for faults
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
