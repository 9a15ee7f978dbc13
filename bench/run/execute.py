"""A run's middle stage, `bench run`'s and `bench host`'s: start the target process (`execute_started`) or attach to
one already on the bus (`execute_attached`), run the host in this process, stop the target.

The target (`bench.run.target.TargetProcess`) is on the same bus options as the host; with `auto` the bus is
SocketCAN vcan0 where usable, else udp_multicast on a port unique to this run (`bench.commands.args.bus_from_args`),
handed to the target on its command line. What a run needs before it starts (model, data, firmware image) is
`bench.run.inputs`.

The host's bus is a `dbc.transport.SenderGuard`: a host frame this process did not send (another host on the
channel, heard before the run or during it) ends the run in one sentence; a target already on the channel is
refused before the run's own starts.

Fault injection (`host.faults`): the host gets the target process's `ProcessControl`, and every target process of
the run appends its detection journal (`--events`) to one temporary file, which the host matches against the
injected faults.
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import can
import numpy as np

from bench.errors import BenchError
from bench.fileio import scratch_dir
from bench.run.elfnote import note_target
from bench.run.target import TargetProcess
from dbc.contract import DEFAULT_REPLY_TIMEOUT_S
from dbc.database import host_frame_ids
from dbc.transport import IN_USE_LISTEN_S, UDP_INTERFACE, BusConfig, SenderGuard, first_heard
from dbc.udp_listeners import ListenerDrops
from host.faults import FaultSpec, FaultSpecError
from host.procedure import replay_log, run_dataset
from host.replay import Progress
from host.results import HostResult
from host.session import DEFAULT_CONNECT_TIMEOUT_S, SessionError
from target_sim.artifact import ModelArtifact
from target_sim.node import target_on_channel

if TYPE_CHECKING:
    from bench.run.prepare import PreparedRun
    from bench.run.request import RunRequest


@dataclass
class RunOutcome:
    """What the execute stage gives the judge: the host's result, and the target's end when the run started it."""

    result: HostResult
    target_status: int | None
    target_stderr: str
    target_stats: dict | None = None    # the target's counters at exit (`python -m target_sim --stats`)
    listener_drops: int | None = None   # frames other listeners on a udp bus lost (`dbc.udp_listeners`)


def listener_drops(bus: BusConfig) -> ListenerDrops | None:
    """The kernel's drop counts of the listeners on `bus` from now on, where it keeps them (udp_multicast)."""
    return ListenerDrops(int(bus.kwargs["port"])) if bus.interface == UDP_INTERFACE and "port" in bus.kwargs else None


def _open(bus: BusConfig) -> SenderGuard:
    """The host's bus, guarded against another host on the channel (`dbc.transport.SenderGuard`)."""
    return SenderGuard(bus.open(), bus, host_frame_ids(), "host")


def _host_session(fn: Callable[[], HostResult], target: TargetProcess | None) -> HostResult:
    """`fn()`, the host's side of the run. A session that could not go on because the target process died ends
    with the process's own sentence (exit status, last line), which says more than the host's; every other error
    (the host's log, data or faults, another host heard by the guard) reaches the CLI as it is."""
    try:
        return fn()
    except SessionError as exc:
        reason = target.exit_reason() if target is not None else None
        if reason is None:
            raise
        if target.killed_by_other() is not None and str(exc) != reason:   # when, in the host's words (the row)
            reason = f"{reason}; the host: {exc}"
        raise BenchError(reason) from None


def refuse_foreign_target(host_bus: can.BusABC, bus: BusConfig, artifact: ModelArtifact | None,
                          listen_s: float = IN_USE_LISTEN_S) -> None:
    """BenchError if a target already sends on the channel: its replies would mix with those of the run's own
    (and a target of the same model would even pass the handshake)."""
    heard = target_on_channel(host_bus, listen_s)
    if heard is None:
        return
    frame, model_id = heard
    channel = f"channel {bus.channel}" + (f" port {bus.kwargs['port']}" if "port" in bus.kwargs else "")
    if model_id is None:
        what = f"sending frames (id 0x{frame:03x})"
    elif artifact is not None and model_id != artifact.model_id:
        what = f"sending heartbeats (it runs model {model_id:08x}, not {artifact.model_id:08x} of the artifact given)"
    else:
        what = f"sending heartbeats (it runs model {model_id:08x}, the same as this run's)"
    raise BenchError(f"{channel} on {bus.interface} already has a target {what}; stop it or pick another channel")


# A target process started here reports its death through `alive`, so waiting long for its first heartbeat only
# matters when it starts slowly (a loaded CI runner, the SocketCAN VM where Python takes seconds to import).
OWN_TARGET_CONNECT_TIMEOUT_S = 120.0


def run_with_target(model_path: Path, artifact: ModelArtifact, bus: BusConfig, drive: np.ndarray, initial,
                    *, mode: str = "lockstep", speed: float = 1.0, sample_period_s: float = 0.2,
                    log_path: str | Path | None = None, reply_timeout_s: float = DEFAULT_REPLY_TIMEOUT_S,
                    progress: Progress | None = None, faults: FaultSpec | None = None,
                    firmware: Path | None = None, isr_rate_hz: int = 0,
                    measurements: np.ndarray | None = None) -> RunOutcome:
    """Start the target on `bus`, replay `drive` from this process, stop the target.

    With `faults` (active), the target writes its detection journal to a temporary file and the host may kill,
    freeze and restart it; the result carries the fault summary (`result.faults`). With `firmware` (an ELF,
    `firmware_for_engine`) the target runs the firmware engine, with `isr_rate_hz` its motor-control interrupt;
    `measurements` (a model with an observer, `bench.run.inputs.measurements_for`) go out in each row's Measurements
    frame."""
    injecting = faults is not None and faults.active
    target_files = scratch_dir("target")   # its stats; its journal when injecting
    events = Path(target_files.name) / "target-events.jsonl" if injecting else None
    stats_path = Path(target_files.name) / "target-stats.json"
    target_stats = None
    host_bus = _open(bus)
    listeners = listener_drops(bus)
    dropped = None
    try:
        refuse_foreign_target(host_bus, bus, artifact)   # (the guard raises OtherSender if it hears another host)
        with TargetProcess(model_path, bus, events_path=events, firmware=firmware, stats_path=stats_path,
                           isr_rate_hz=isr_rate_hz, extra_argv=faults.reply_argv() if injecting else None) as target:
            result = _host_session(lambda: run_dataset(
                host_bus, drive, initial, model_id=artifact.model_id, mode=mode, speed=speed,
                sample_period_s=sample_period_s, log_path=log_path, reply_timeout_s=reply_timeout_s,
                alive=target.exit_reason, connect_timeout_s=OWN_TARGET_CONNECT_TIMEOUT_S, progress=progress,
                faults=faults if injecting else None,
                control=target.control() if injecting else None, target_events=events,
                measurements=measurements), target)
            if listeners is not None:   # while the target's socket is open: its filtered own copies are not a loss
                dropped = listeners.count([target.process.pid] if target.process is not None else [])
            killed = target.killed_by_other()   # before stop(): it ended while the host still ran
            status = target.stop()
            stderr = target.stderr_text()
            _name_the_fault(result, stderr)
        target_stats = _read_stats(stats_path)
    finally:
        host_bus.shutdown()
        target_files.cleanup()
    if result.log_path:    # which ELF ran, for `bench analyze` (an earlier run's note of this name goes)
        note_target(result.log_path, firmware)
    if killed is not None:
        raise BenchError(killed_sentence(killed, result))
    if status not in (0, None):
        raise BenchError(f"the target process ended with status {status} after the run: "
                         f"{stderr.strip().splitlines()[-1] if stderr.strip() else '(no output)'}")
    return RunOutcome(result, status, stderr, target_stats, dropped)


def execute_started(prepared: PreparedRun, request: RunRequest, bus: BusConfig, faults: FaultSpec | None, *,
                    firmware: Path | None = None, progress: Progress | None = None) -> RunOutcome:
    """A run's middle stage for `bench run`: the target started here (`run_with_target`, on the ELF `firmware` for
    the firmware engine), the prepared rows replayed and logged."""
    from bench.model.runs import initial_temperatures

    return run_with_target(prepared.model_path, prepared.artifact, bus, prepared.drive,
                           initial_temperatures(prepared.dataset), mode=request.mode, speed=request.speed,
                           sample_period_s=prepared.dataset.sample_period_s, log_path=prepared.log_path,
                           reply_timeout_s=request.reply_timeout, progress=progress, faults=faults,
                           firmware=firmware, isr_rate_hz=request.isr_rate, measurements=prepared.measurements)


def execute_attached(prepared: PreparedRun, request: RunRequest, bus: BusConfig, faults: FaultSpec | None, *,
                     announce: Callable[[], None] = lambda: None) -> RunOutcome:
    """A run's middle stage for `bench host`: the prepared rows replayed to a target already on `bus`, and logged.
    A second host on the channel, heard before the run or during it, ends it in one sentence (`dbc.transport.
    SenderGuard`); `announce` runs once the bus is this host's alone, before anything is sent (the command's lines,
    --wait-for-listener)."""
    from bench.model.runs import initial_temperatures

    host_bus = None
    listeners = listener_drops(bus)
    try:
        host_bus = bus.open()
        if (other := first_heard(host_bus, host_frame_ids())) is not None:  # two hosts would both drive the target
            raise SessionError(f"{bus.describe()} already has a host sending (frame id "
                               f"0x{other.arbitration_id:03x}); stop it or pick another channel")
        host_bus = SenderGuard(host_bus, bus, host_frame_ids(), "host")   # and one that starts later stops this run
        announce()
        result = run_dataset(host_bus, prepared.drive, initial_temperatures(prepared.dataset),
                             model_id=prepared.artifact.model_id, mode=request.mode, speed=request.speed,
                             sample_period_s=prepared.dataset.sample_period_s, log_path=prepared.log_path,
                             reply_timeout_s=request.reply_timeout, connect_timeout_s=request.connect_timeout,
                             faults=faults, target_events=request.target_events, events_since=time.time(),
                             measurements=prepared.measurements)
        dropped = listeners.count() if listeners is not None else None
    except FaultSpecError as exc:   # kept for its exit status: a plan the host refuses here (faults in real time at
        raise BenchError(str(exc)) from None   # too short a sample interval) exits 1, a bad --fault option 2
    finally:
        if host_bus is not None:
            host_bus.shutdown()
    if result.log_path:    # a target not started here: its ELF is unknown (an earlier run's note of this name goes)
        note_target(result.log_path, None)
    return RunOutcome(result, None, "", listener_drops=dropped)


def killed_sentence(killed: signal.Signals, result: HostResult) -> str:
    """A target another process killed while the host ran: by which signal, at which row (the first one it left
    unanswered for good), and what became of the run's log."""
    answered = np.asarray(result.arrays.get("answered", ()), dtype=bool)
    row = int(np.flatnonzero(answered)[-1]) + 1 if answered.any() else 0
    log = f"; its log {result.log_path} holds the run up to there" if result.log_path else ""
    return (f"the target process was killed by signal {killed.value} ({killed.name}) during the run, at row {row} of "
            f"{result.rows}, by another process or the system (the bench did not stop it){log}; the run is not "
            "complete, run it again")


def _read_stats(path: Path) -> dict | None:
    """The target's counters at exit, or None when it wrote none (killed, or an older target)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _name_the_fault(result: HostResult, stderr: str) -> None:
    """A run the host aborted because the target faulted: the target's own sentence (e.g. the emulated core's
    FirmwareFault) goes into the reason, so the user reads the cause, not only the effect."""
    if not result.aborted:
        return
    faults = [line.removeprefix("target_sim: ") for line in stderr.splitlines() if "internal fault" in line]
    if faults:
        result.aborted = f"{result.aborted}: {faults[-1]}"


def replay_with_target(model_path: Path | None, artifact: ModelArtifact | None, bus: BusConfig, messages, *,
                       timed: bool, speed: float = 1.0, log_path: str | Path | None = None,
                       reply_timeout_s: float = DEFAULT_REPLY_TIMEOUT_S, progress: Progress | None = None,
                       firmware: Path | None = None, xcp_elf: Path | None = None) -> RunOutcome:
    """Re-send a log's host frames (and a master's XCP commands) to a target started here (or, with model_path
    None, one already running), which runs the firmware engine on the ELF `firmware` if one is given, else the
    Python engine, its XCP cells at the addresses of the ELF `xcp_elf` if one is given."""
    host_bus = _open(bus)
    target = None
    try:
        if model_path is not None:  # a target of our own: none may be on the channel already
            refuse_foreign_target(host_bus, bus, artifact)
            target = TargetProcess(model_path, bus, firmware=firmware,
                                   extra_argv=["--xcp-elf", str(xcp_elf)] if xcp_elf is not None else None).start()
        alive = target.exit_reason if target is not None else None
        result = _host_session(lambda: replay_log(
            host_bus, messages, model_id=artifact.model_id if artifact else None, timed=timed, speed=speed,
            log_path=log_path, reply_timeout_s=reply_timeout_s, alive=alive,
            connect_timeout_s=OWN_TARGET_CONNECT_TIMEOUT_S if target else DEFAULT_CONNECT_TIMEOUT_S,
            progress=progress), target)
        status = target.stop() if target is not None else None
        stderr = target.stderr_text() if target is not None else ""
    finally:
        if target is not None:
            target.close()
        host_bus.shutdown()
    if result.log_path:    # whose addresses its XCP cells had (none known for a target not started here)
        note_target(result.log_path, (firmware or xcp_elf) if target is not None else None)
    return RunOutcome(result, status, stderr)
