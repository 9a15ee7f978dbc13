"""Orchestration of a bench run: resolve the bus, start the target process, run the host, stop the target.

The target is a separate OS process (`python -m target_sim`) on the same bus options as the host, which runs
in this process. With `auto` the bus is SocketCAN vcan0 where usable, else udp_multicast on a port unique to
this run (handed to the target on its command line). The target's stderr goes to a temporary file, so a
target that fails to start is reported with its own last line.

The target is told this process's id (`--parent-pid`), so it stops by itself when this process dies without
stopping it (SIGKILL, a crash). The host's bus is a `dbc.transport.SenderGuard`: a host frame this process did not
send (another host on the channel, heard before the run or during it) ends the run in one sentence.

Fault injection (`host.faults`): the runner owns the target process, so it lends the host a `ProcessControl`
to kill it (SIGKILL), freeze it (SIGSTOP, and SIGCONT from a timer) and, once the host has noticed the loss,
restart it (same command line). Every target process of the run appends its detection journal (`--events`) to
one temporary file, which the host matches against the injected faults.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np

from bench.errors import BenchError, UsageError
from dbc.database import contract, host_frame_ids
from dbc.transport import (
    IN_USE_LISTEN_S,
    BusConfig,
    BusUnavailable,
    OtherSender,
    SenderGuard,
    config_from_args,
    logger_command,
    resolve,
)
from host.canlog import LogError
from host.faults import FaultSpec, FaultSpecError
from host.replay import DataRangeError, Progress
from host.results import HostResult
from host.run import replay_log, run_dataset
from host.session import DEFAULT_CONNECT_TIMEOUT_S, SessionError
from target_sim.artifact import ArtifactError, ModelArtifact, load_artifact
from target_sim.losses import CURRENT_SIGNALS
from target_sim.node import target_on_channel

TARGET_STOP_TIMEOUT_S = 5.0


def bus_from_args(args) -> BusConfig:
    """The bus the command-line options describe, `auto` resolved: udp_multicast on the bench's own group gets a
    run-unique port, on a channel the user chose python-can's default port unless one is given (`resolve`); the
    CAN contract is read first: a broken DBC is one sentence before anything starts."""
    contract()
    try:
        config = resolve(config_from_args(args), session_unique=True)
    except BusUnavailable as exc:
        raise BenchError(str(exc)) from None
    if config.interface == "virtual":  # python-can's virtual bus lives inside one process; the target is another
        raise UsageError("the 'virtual' interface does not cross processes; use udp_multicast, socketcan or auto")
    return config


def announce_logger(bus: BusConfig, quiet: bool, prefix: str = "bench: ") -> None:
    """On stderr (unless `quiet`), the line that records this bus with python-can's logger, ready to paste."""
    if not quiet:
        print(f"{prefix}to record this bus with python-can: {logger_command(bus)}", file=sys.stderr, flush=True)


NAME_MAX = 255   # bytes in one file name (Linux, macOS)


def check_log_names(log_path: Path, faults: FaultSpec | None) -> None:
    """UsageError, before anything runs, when a file written beside the log would need a name longer than NAME_MAX:
    with faults, the summary `<log>.faults.json`, written through a temporary `.<log>.faults.json.XXXXXXXX`."""
    if faults is None or not faults.active:
        return
    from host.faults import sidecar_path

    sidecar = sidecar_path(log_path).name
    length = len(os.fsencode(sidecar)) + 10
    if length > NAME_MAX:
        raise UsageError(f"--log {log_path}: the fault summary beside it, {sidecar}, would need a file name of "
                         f"{length} bytes (its temporary name), more than the {NAME_MAX} a name may have; shorten the "
                         f"log's name by {length - NAME_MAX} characters")


def load_model(path: str | Path | None) -> tuple[ModelArtifact, Path]:
    from bench.model.default import default_artifact_path

    model_path = Path(path) if path else default_artifact_path()
    try:
        return load_artifact(model_path), model_path
    except ArtifactError as exc:
        raise BenchError(str(exc)) from None


def firmware_for_engine(engine: str, artifact: ModelArtifact, cache_dir: Path, *, quiet: bool = True) -> Path | None:
    """The ELF the target runs with `engine` "firmware" (None for "python"): the packaged one of a packaged
    artifact, else built once into `cache_dir` (BenchError, one sentence, without the compiler, or for a model the
    firmware cannot run)."""
    if engine != "firmware":
        return None
    from target_sim.firmware.node_protocol import firmware_refusal

    refusal = firmware_refusal(artifact)
    if refusal is not None:
        raise BenchError(refusal)
    from bench.firmware.images import firmware_for

    return firmware_for(artifact, cache_dir, quiet=quiet)


def load_data(path: str | Path | None, artifact: ModelArtifact | None = None, seed: int | None = None,
              quiet: bool = True, *, mapping=None, sample_period_s: float | None = None):
    """The dataset (default: the generated 40 °C validation run, made in out/data if missing).

    A user's own file is read through `mapping` (a `bench.drive.dataset.ColumnMapping`, from --mapping) at
    `sample_period_s` (--sample-period; None: the mapping's, else the artifact's). The data's sample period must be
    the one the artifact's model runs on (BenchError, one sentence, if not)."""
    from bench.drive.dataset import load_dataset
    from bench.drive.generate import ensure_default_datasets

    if path is None:
        if not quiet and not Path("out/data/cycle_coolant40.csv").is_file():
            print("bench: generating the default datasets in out/data (once)", file=sys.stderr)
        path = ensure_default_datasets(Path("out/data"), seed)[40]
    given = sample_period_s if sample_period_s is not None else getattr(mapping, "sample_period_s", None)
    period = given if given is not None else (artifact.data_sample_period if artifact is not None else None)
    dataset = load_dataset(Path(path), mapping, sample_period_s=period)
    if artifact is not None and not math.isclose(dataset.sample_period_s, artifact.data_sample_period,
                                                  rel_tol=1e-6):
        where = f" ({artifact.path})" if artifact.path is not None else ""
        raise BenchError(f"{dataset.path} is sampled every {dataset.sample_period_s:g} s, but model "
                         f"{artifact.model_id:08x}{where} runs on data sampled every {artifact.data_sample_period:g} "
                         f"s; resample the data or use a model identified on data at {dataset.sample_period_s:g} s")
    return dataset


def check_drive_data(dataset, artifact: ModelArtifact) -> None:
    """BenchError (one sentence) when the model needs the d/q currents (an electrical loss model) and the data has
    none: refused before anything starts (the target would otherwise never see a complete row)."""
    if set(artifact.drive_signals) & set(CURRENT_SIGNALS) and not dataset.has_currents:
        where = f" ({artifact.path})" if artifact.path is not None else ""
        raise BenchError(f"model {artifact.model_id:08x}{where} has an {artifact.loss_model} loss model, which "
                         f"needs the d/q currents, and {dataset.path} has none (columns i_d_A, i_q_A); map them with "
                         "--mapping or use a model with loss maps")


def drive_for(dataset, artifact: ModelArtifact):
    """What the host sends per row: (rows, 4) [torque, speed, coolant, ambient], and [i_d, i_q] after them (rows,
    6) when the model has an electrical loss model (after `check_drive_data`)."""
    from bench.model.runs import drive_matrix

    check_drive_data(dataset, artifact)
    return drive_matrix(dataset, artifact.drive_signals)


class TargetProcess:
    """`python -m target_sim` on a bus, started and stopped cleanly (SIGTERM, then kill after a timeout)."""

    def __init__(self, model_path: str | Path, bus: BusConfig, *, stats_path: str | Path | None = None,
                 events_path: str | Path | None = None, extra_argv: list[str] | None = None,
                 firmware: str | Path | None = None):
        self.model_path = Path(model_path)
        self.bus = bus
        self.firmware = firmware      # the model's ELF: the target runs the firmware engine (else the Python one)
        self.stats_path = stats_path
        self.events_path = events_path
        self.extra_argv = list(extra_argv or [])   # e.g. the reply faults the target injects
        self.process: subprocess.Popen | None = None
        self.restarts = 0
        self.kills = 0
        self.freezes = 0
        self._stderr = tempfile.TemporaryFile(mode="w+b")
        self._thaw: threading.Timer | None = None
        self._frozen = False
        self._lock = threading.Lock()

    @property
    def argv(self) -> list[str]:
        argv = [sys.executable, "-m", "target_sim", "--model", str(self.model_path), *self.bus.to_argv(),
                "--parent-pid", str(os.getpid())]   # it stops by itself if this process dies without stopping it
        if self.firmware is not None:
            argv += ["--engine", "firmware", "--firmware", str(self.firmware)]
        if self.stats_path is not None:
            argv += ["--stats", str(self.stats_path)]
        if self.events_path is not None:
            argv += ["--events", str(self.events_path)]
        return argv + self.extra_argv

    # ------------------------------------------------------------------ process faults
    def kill(self) -> None:
        """SIGKILL the target and reap it (a frozen one too)."""
        self._cancel_thaw()
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self._frozen = False
        self.kills += 1

    def freeze(self, seconds: float) -> None:
        """SIGSTOP the target now and SIGCONT it after `seconds` (from a timer thread)."""
        if self.process is None or self.process.poll() is not None:
            return
        self._cancel_thaw()
        self.process.send_signal(signal.SIGSTOP)
        self._frozen = True
        self.freezes += 1
        self._thaw = threading.Timer(seconds, self.thaw)
        self._thaw.daemon = True
        self._thaw.start()

    def thaw(self) -> None:
        with self._lock:
            if self._frozen and self.process is not None and self.process.poll() is None:
                self.process.send_signal(signal.SIGCONT)
            self._frozen = False

    def _cancel_thaw(self) -> None:
        if self._thaw is not None:
            self._thaw.cancel()
            self._thaw = None

    def ensure_running(self) -> None:
        """Start the target again if it has died (a frozen one is left to its timer)."""
        if self.process is not None and self.process.poll() is not None:
            self.restarts += 1
            self.start()

    def control(self):
        from host.faults import ProcessControl

        return ProcessControl(kill=self.kill, freeze=self.freeze, ensure_running=self.ensure_running,
                              exit_reason=self.exit_reason)

    def start(self) -> TargetProcess:
        env = dict(os.environ)
        env.setdefault("PYTHONUNBUFFERED", "1")
        try:
            self.process = subprocess.Popen(self.argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                            stderr=self._stderr, env=env)
        except OSError as exc:
            raise BenchError(f"cannot start the target process ({exc})") from None
        return self

    def stderr_text(self) -> str:
        self._stderr.flush()
        self._stderr.seek(0)
        return self._stderr.read().decode("utf-8", "replace")

    def last_stderr_line(self) -> str:
        lines = [line.strip() for line in self.stderr_text().splitlines() if line.strip()]
        return lines[-1] if lines else "(no output)"

    def exit_reason(self) -> str | None:
        """None while the process runs; else one sentence with its status and last stderr line."""
        if self.process is None or self.process.poll() is None:
            return None
        return (f"the target process exited with status {self.process.returncode}: "
                f"{self.last_stderr_line().removeprefix('target_sim: error: ').removeprefix('target_sim: ')}")

    def stop(self, timeout: float = TARGET_STOP_TIMEOUT_S) -> int | None:
        """SIGTERM and wait; kill if it does not exit in time. Returns the exit status."""
        if self.process is None:
            return None
        self._cancel_thaw()
        if self._frozen:
            self.thaw()  # a stopped process would not act on SIGTERM
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode

    def close(self) -> None:
        self.stop()
        self._stderr.close()

    def __enter__(self) -> TargetProcess:
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()


@dataclass
class RunOutcome:
    result: HostResult
    target_status: int | None
    target_stderr: str
    target_stats: dict | None = None    # the target's counters at exit (`python -m target_sim --stats`)


def _open(bus: BusConfig) -> SenderGuard:
    """The host's bus, guarded against another host on the channel (`dbc.transport.SenderGuard`)."""
    try:
        return SenderGuard(bus.open(), bus, host_frame_ids(), "host")
    except BusUnavailable as exc:
        raise BenchError(str(exc)) from None


def _host_errors(fn: Callable[[], HostResult], target: TargetProcess) -> HostResult:
    try:
        return fn()
    except SessionError as exc:
        reason = target.exit_reason()
        raise BenchError(reason or str(exc)) from None
    except (LogError, DataRangeError, OtherSender) as exc:
        raise BenchError(str(exc)) from None
    except FaultSpecError as exc:
        raise UsageError(str(exc)) from None


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


def _refuse_others(host_bus: SenderGuard, bus: BusConfig, artifact: ModelArtifact | None) -> None:
    """BenchError (one sentence) if a target, or another host, already sends on the channel (the guard hears a
    host's frames while the runner listens for a target's)."""
    try:
        refuse_foreign_target(host_bus, bus, artifact)
    except OtherSender as exc:
        raise BenchError(str(exc)) from None


# A target process started here reports its death through `alive`, so waiting long for its first heartbeat only
# matters when it starts slowly (a loaded CI runner, the SocketCAN VM where Python takes seconds to import).
OWN_TARGET_CONNECT_TIMEOUT_S = 120.0


def run_with_target(model_path: Path, artifact: ModelArtifact, bus: BusConfig, drive: np.ndarray, initial,
                    *, mode: str = "lockstep", speed: float = 1.0, sample_period_s: float = 0.2,
                    log_path: str | Path | None = None, reply_timeout_s: float = 0.05,
                    progress: Progress | None = None, faults: FaultSpec | None = None,
                    firmware: Path | None = None) -> RunOutcome:
    """Start the target on `bus`, replay `drive` from this process, stop the target.

    With `faults` (active), the target writes its detection journal to a temporary file and the host may kill,
    freeze and restart it; the result carries the fault summary (`result.faults`). With `firmware` (an ELF,
    `firmware_for_engine`) the target runs the firmware engine."""
    injecting = faults is not None and faults.active
    target_files = tempfile.TemporaryDirectory(prefix="bench-target-")   # its stats; its journal when injecting
    events = Path(target_files.name) / "target-events.jsonl" if injecting else None
    stats_path = Path(target_files.name) / "target-stats.json"
    target_stats = None
    host_bus = _open(bus)
    try:
        _refuse_others(host_bus, bus, artifact)
        with TargetProcess(model_path, bus, events_path=events, firmware=firmware, stats_path=stats_path,
                           extra_argv=faults.reply_argv() if injecting else None) as target:
            result = _host_errors(lambda: run_dataset(
                host_bus, drive, initial, model_id=artifact.model_id, mode=mode, speed=speed,
                sample_period_s=sample_period_s, log_path=log_path, reply_timeout_s=reply_timeout_s,
                alive=target.exit_reason, connect_timeout_s=OWN_TARGET_CONNECT_TIMEOUT_S, progress=progress,
                faults=faults if injecting else None,
                control=target.control() if injecting else None, target_events=events), target)
            status = target.stop()
            stderr = target.stderr_text()
            _name_the_fault(result, stderr)
        target_stats = _read_stats(stats_path)
    finally:
        host_bus.shutdown()
        target_files.cleanup()
    if status not in (0, None):
        raise BenchError(f"the target process ended with status {status} after the run: "
                         f"{stderr.strip().splitlines()[-1] if stderr.strip() else '(no output)'}")
    return RunOutcome(result, status, stderr, target_stats)


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
                       reply_timeout_s: float = 0.05, progress: Progress | None = None,
                       firmware: Path | None = None) -> RunOutcome:
    """Re-send a log's host frames to a target started here (or, with model_path None, one already running),
    which runs the firmware engine on the ELF `firmware` if one is given."""
    host_bus = _open(bus)
    target = None
    try:
        if model_path is not None:  # a target of our own: none may be on the channel already
            _refuse_others(host_bus, bus, artifact)
            target = TargetProcess(model_path, bus, firmware=firmware).start()
        alive = target.exit_reason if target is not None else None
        try:
            result = replay_log(host_bus, messages, model_id=artifact.model_id if artifact else None, timed=timed,
                                speed=speed, log_path=log_path, reply_timeout_s=reply_timeout_s, alive=alive,
                                connect_timeout_s=OWN_TARGET_CONNECT_TIMEOUT_S if target else DEFAULT_CONNECT_TIMEOUT_S,
                                progress=progress)
        except SessionError as exc:
            reason = target.exit_reason() if target is not None else None
            raise BenchError(reason or str(exc)) from None
        except (LogError, OtherSender) as exc:
            raise BenchError(str(exc)) from None
        status = target.stop() if target is not None else None
        stderr = target.stderr_text() if target is not None else ""
    finally:
        if target is not None:
            target.close()
        host_bus.shutdown()
    return RunOutcome(result, status, stderr)


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{text!r} is not a number") from None
    if not value > 0 or value != value or value == float("inf"):
        raise UsageError(f"{text!r} must be a positive number")
    return value


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise UsageError(f"{text!r} is not a whole number") from None
    if value <= 0:
        raise UsageError(f"{text!r} must be a positive whole number")
    return value


class ProgressBar:
    """tqdm on stderr for a long replay; silent when `quiet`."""

    def __init__(self, total: int, description: str, quiet: bool):
        self._bar = None
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc=description, unit="row", file=sys.stderr, leave=False,
                             mininterval=0.5, smoothing=0.1)

    def __call__(self, done: int, total: int) -> None:
        if self._bar is not None:
            self._bar.n = done
            self._bar.refresh()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
