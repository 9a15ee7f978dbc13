"""`python -m target_sim`: the simulated C2000 target process.

    python -m target_sim --model MODEL.json [--engine python|firmware] [--firmware ELF] [--isr-rate HZ]
                         [-i INTERFACE] [-c CHANNEL] [-b BITRATE] [--bus-kwargs K=V ...]
                         [--can-config FILE] [--stats FILE] [--events FILE] [--faults K=P,...] [--fault-seed N]
                         [--parent-pid PID] [--quiet]

Loads and verifies the artifact (a bad one: one sentence on stderr, exit 1) and, with `--engine firmware`, the
model's firmware ELF (`bench firmware build`): the whole node (bench/firmware/node.c and the model) runs in the
emulated Cortex-M4F and this process only moves frames between the bus and its mailbox (`target_sim.engines`). An
ELF for another core, or of another model than the artifact's (its `fw_model_id`), is refused in one sentence,
exit 1 (`--firmware` implies the firmware engine; `--engine firmware` needs it). A model whose observer the CAN
frames cannot carry (the flux linkage from its raw channels, more than one measurement) is refused in one sentence,
exit 2. Then it opens the bus (`auto`:
socketcan vcan0 if usable, else udp_multicast), announces itself (TargetInfo, then Status/RxErrors every 100 ms)
and serves until SIGTERM, SIGINT or SIGHUP, then shuts the bus down and exits 0. `--parent-pid PID` (what `bench`
passes to the targets it starts) ties it to that process, its parent: it stops the same way when PID dies (Linux:
the parent-death signal, prctl PR_SET_PDEATHSIG; elsewhere too: it checks its parent id in its loop), so a bench
killed without stopping it leaves no target sending heartbeats behind. A target started by hand has no
`--parent-pid` and runs until it is stopped. `--stats FILE` writes the node's counters
(JSON) at exit. `--events FILE` appends one JSON line per rejected frame or sequence error (the node's detection
journal), plus a "start" line with the process id and a "stop" line with the counters; each line is one
write(2) to a file opened O_APPEND, so what was written survives a SIGKILL and a restarted target appends to the
same file. `--faults reply_drop=0.01,...` alters the temperature replies on their way out (`target_sim.faults`)
and journals each injection in the same file. See `target_sim.node` for the protocol.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import time
from pathlib import Path

from dbc.database import DbcError, contract
from dbc.files import same_file, write_atomically
from dbc.lifeline import tie_to_parent
from dbc.transport import BusUnavailable, add_bus_arguments, config_from_args, resolve
from target_sim.artifact import load_artifact
from target_sim.engines import ENGINES, make_node
from target_sim.errors import TargetError
from target_sim.faults import ReplyFaults, parse_reply_faults
from target_sim.node import log_error, serve, target_on_channel
from target_sim.observer.node import can_refusal


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        print(f"target_sim: error: {message} (see 'python -m target_sim --help')", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m target_sim", description=__doc__.split("\n\n")[0],
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", required=True, help="model artifact (JSON) to run")
    parser.add_argument("--engine", choices=ENGINES, default=None,
                        help="python: the reference node in Python (default); firmware: the node and model compiled "
                             "for a Cortex-M4F (--firmware ELF) in the emulated core, with measured cycles (Timing4)")
    parser.add_argument("--firmware", default=None, metavar="ELF",
                        help="the model's firmware ELF ('bench firmware build'), for --engine firmware")
    parser.add_argument("--isr-rate", type=float, default=0.0, metavar="HZ",
                        help="with --engine firmware and a timing image (bench/firmware/foc_isr.c linked in): the "
                             "field-oriented current loop's interrupt preempts the node at this rate, and each model "
                             "step's response time goes out in Timing5 (default 0: no interrupt)")
    parser.add_argument("--xcp-elf", default=None, metavar="ELF",
                        help="the Python engine's XCP slave places its measurements at this firmware ELF's symbol "
                             "addresses, so the A2L of 'bench firmware a2l --elf ELF' fits (default: the slave's own "
                             "pages; see docs/tutorials/xcp.md)")
    parser.add_argument("--stats", default=None, help="write the node's counters to this JSON file at exit")
    parser.add_argument("--events", default=None,
                        help="append the detection journal (one JSON line per rejected frame) to this file")
    parser.add_argument("--faults", default=None, metavar="K=P,K=P",
                        help="inject faults into the temperature replies, e.g. reply_drop=0.01,reply_corrupt=0.001 "
                             "(each injection is journaled in --events)")
    parser.add_argument("--fault-seed", type=int, default=0, metavar="N", help="seed of the reply faults")
    parser.add_argument("--parent-pid", type=int, default=None, metavar="PID",
                        help="stop when this process, the parent that started the target (bench does), dies")
    parser.add_argument("--quiet", action="store_true", help="no start/stop lines on stderr")
    add_bus_arguments(parser)
    return parser


PARENT_CHECK_S = 0.25     # how often the loop checks that the parent still lives


def _write_stats(path: str, stats: dict) -> None:
    text = json.dumps(stats, indent=1)
    write_atomically(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


class JournalError(TargetError):
    """The --events file cannot be written; one sentence."""


class EventJournal:
    """Appends JSON lines to a file, one os.write per line on an O_APPEND descriptor (nothing buffered)."""

    def __init__(self, path: str):
        target = Path(path)
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            self.fd = os.open(target, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        except OSError as exc:
            raise JournalError(f"cannot write the events file {target} ({exc.strerror or exc}); choose a writable "
                               "path for --events") from None

    def __call__(self, record: dict) -> None:
        os.write(self.fd, (json.dumps({"t": round(time.time(), 6), **record}, separators=(",", ":")) + "\n")
                 .encode())

    def close(self) -> None:
        os.close(self.fd)


def _tie_to_parent(parent: int) -> bool:
    """Stop (SIGTERM) when the parent `parent` dies: the kernel's parent-death signal where there is one (Linux,
    `dbc.lifeline`); the serve loop checks the parent id itself (no watcher thread). False when `parent` is not (or no
    longer) this process's parent."""
    return tie_to_parent(parent, signal.SIGTERM, watch=False)


OUTPUTS = ("stats", "events")
INPUTS = ("model", "firmware", "xcp_elf", "can_config")


def _output_collision(args: argparse.Namespace) -> str | None:
    """The sentence for an output (--stats, --events) that names an input or the other output (`dbc.files.same_file`:
    symlinks and hard links too); None when every one is its own file."""
    named = [(dest, getattr(args, dest, None)) for dest in (*INPUTS, *OUTPUTS)]
    named = [(dest, path) for dest, path in named if path]
    for i, (dest, path) in enumerate(named):
        for other, other_path in named[:i]:
            if dest in OUTPUTS and same_file(path, other_path):
                option, other_option = (f"--{d.replace('_', '-')}" for d in (dest, other))
                return f"{option} {path} is the same file as {other_option} {other_path}; choose another {option}"
    return None


def main(argv: list[str] | None = None) -> int:
    # python-can repeats a half-constructed bus's failure from __del__ ("not properly shut down") after our sentence.
    logging.getLogger("can").addHandler(logging.NullHandler())
    parser = build_parser()
    args = parser.parse_args(argv)
    collision = _output_collision(args)
    if collision:
        parser.error(collision)
    if args.parent_pid is not None and not _tie_to_parent(args.parent_pid):   # first: a dying bench stops it now
        print(f"target_sim: error: process {args.parent_pid} (--parent-pid) is not the parent of this target (it has "
              "exited?); the target does not start", file=sys.stderr)
        return 1
    try:
        contract()  # the DBC, read before anything else: a broken one is one sentence here
    except DbcError as exc:
        print(f"target_sim: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    reply_rates = {}
    if args.faults:
        try:
            reply_rates = parse_reply_faults(args.faults)
        except ValueError as exc:
            parser.error(f"--faults: {exc}")
    engine = args.engine or ("firmware" if args.firmware else "python")
    if engine == "firmware" and not args.firmware:
        parser.error("--engine firmware needs the model's firmware: --firmware ELF (see 'bench firmware build')")
    if engine == "python" and args.firmware:
        parser.error("--firmware is the firmware engine's ELF; drop it or use --engine firmware")
    if args.xcp_elf and engine != "python":
        parser.error("--xcp-elf lays out the Python engine's XCP slave; the firmware engine's slave has its ELF's "
                     "own addresses: drop it")
    if args.isr_rate and engine != "firmware":
        parser.error("--isr-rate runs the motor-control interrupt in the firmware engine; add --engine firmware "
                     "--firmware ELF or drop it")
    if args.isr_rate:   # 0, no interrupt, needs no check (nor the firmware package, unicorn, in a Python target)
        from target_sim.firmware.motor_control import isr_rate_problem

        problem = isr_rate_problem(args.isr_rate)
        if problem:
            parser.error(problem)
    journal = None
    try:
        config = resolve(config_from_args(args))
        if config.interface == "virtual":  # python-can's virtual bus lives in one process: no host could reach us
            parser.error("the 'virtual' interface does not cross processes, so no host could reach the target; "
                         "use udp_multicast, socketcan or auto")
        artifact = load_artifact(args.model)
        refusal = can_refusal(artifact)
        if refusal is not None:   # an observer whose readings no frame carries: refused, not run wrongly
            print(f"target_sim: error: {refusal}", file=sys.stderr)
            return 2
        node = make_node(artifact, engine=engine, firmware=args.firmware,   # the ELF checked before the bus opens
                         isr_rate_hz=args.isr_rate, xcp_elf=args.xcp_elf)
        bus = config.open()
    except (TargetError, BusUnavailable) as exc:   # the artifact, the firmware image, the bus
        print(f"target_sim: error: {exc}", file=sys.stderr)
        return 1
    other = target_on_channel(bus)
    if other is not None:  # two targets would both answer every row
        bus.shutdown()
        frame, model_id = other
        what = f"frames with id 0x{frame:03x}" if model_id is None else f"heartbeats of model {model_id:08x}"
        print(f"target_sim: error: {config.describe()} already has a target sending ({what}); stop it or pick "
              "another channel", file=sys.stderr)
        return 1
    try:
        if args.events:
            journal = EventJournal(args.events)
    except JournalError as exc:
        bus.shutdown()
        print(f"target_sim: error: {exc}", file=sys.stderr)
        return 1
    node.journal = journal
    if journal is not None:
        journal({"event": "start", "pid": os.getpid(), "model_id": artifact.model_id})
    stop = {"requested": False}

    def request_stop(signum, frame) -> None:  # noqa: ARG001 - signal API
        stop["requested"] = True

    signal.signal(signal.SIGTERM, request_stop)   # how the bench stops it, always heard
    for signum in (signal.SIGINT, signal.SIGHUP):   # one inherited as ignored (nohup, a background job) stays so
        if signal.getsignal(signum) != signal.SIG_IGN:
            signal.signal(signum, request_stop)
    parent = {"next_check": 0.0, "gone": False}

    def should_stop() -> bool:
        if stop["requested"]:
            return True
        if args.parent_pid is not None and (now := time.monotonic()) >= parent["next_check"]:
            parent["next_check"] = now + PARENT_CHECK_S
            parent["gone"] = os.getppid() != args.parent_pid
        return parent["gone"]

    if not args.quiet:
        engine_note = f"firmware node {node.name}" if engine == "firmware" else "python engine"
        log_error(f"model {artifact.model_id:08x} ({artifact.kind}, {artifact.realization}, dt {artifact.dt:g} s, "
                  f"{node.cost.cycles} est. C28x cycles, {engine_note}) on {config.describe()}; serving")
    try:
        serve(node, bus, should_stop, on_error=log_error,
              reply_faults=ReplyFaults(reply_rates, args.fault_seed, journal) if reply_rates else None)
    finally:
        bus.shutdown()
        if args.stats:
            _write_stats(args.stats, node.stats())
        if journal is not None:
            journal({"event": "stop", "pid": os.getpid(), "errors": dict(node.errors)})
            journal.close()
    if not args.quiet:
        s = node.stats()
        why = f" (its parent, process {args.parent_pid}, is gone)" if parent["gone"] else ""
        log_error(f"stopped{why}: {s['rows_used']} rows, {s['model_steps']} model steps, frame errors {s['errors']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
