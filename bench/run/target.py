"""Supervision of the target process: `python -m target_sim` on a bus, started, faulted and stopped.

The target's stderr goes to a temporary file, so a target that fails to start is reported with its own last line.
It is told this process's id (`--parent-pid`), so it stops by itself when this process dies without stopping it
(SIGKILL, a crash).

Fault injection (`host.faults`): the runner owns the target process, so it lends the host a `ProcessControl`
(`TargetProcess.control`) to kill it (SIGKILL), freeze it (SIGSTOP, and SIGCONT from a timer) and, once the host
has noticed the loss, restart it (same command line).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from bench.errors import BenchError
from dbc.transport import BusConfig

TARGET_STOP_TIMEOUT_S = 5.0


class TargetProcess:
    """`python -m target_sim` on a bus, started and stopped cleanly (SIGTERM, then kill after a timeout)."""

    def __init__(self, model_path: str | Path, bus: BusConfig, *, stats_path: str | Path | None = None,
                 events_path: str | Path | None = None, extra_argv: list[str] | None = None,
                 firmware: str | Path | None = None, isr_rate_hz: int = 0):
        self.model_path = Path(model_path)
        self.isr_rate_hz = isr_rate_hz   # the firmware's motor-control interrupt (a timing image's), 0: none
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
        self._signalled = False    # the bench itself sent the current process a stopping signal (stop, kill)
        self._lock = threading.Lock()

    @property
    def argv(self) -> list[str]:
        argv = [sys.executable, "-m", "target_sim", "--model", str(self.model_path), *self.bus.to_argv(),
                "--parent-pid", str(os.getpid())]   # it stops by itself if this process dies without stopping it
        if self.firmware is not None:
            argv += ["--engine", "firmware", "--firmware", str(self.firmware)]
        if self.isr_rate_hz:
            argv += ["--isr-rate", str(self.isr_rate_hz)]
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
            self._signalled = True
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
        self._signalled = False
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

    def killed_by_other(self) -> signal.Signals | None:
        """The signal that ended the target when another process (or the system: the OOM killer) sent it, not
        this bench; else None (running, exited by itself, or stopped by the bench)."""
        code = None if self.process is None else self.process.poll()
        if code is None or code >= 0 or self._signalled:
            return None
        try:
            return signal.Signals(-code)
        except ValueError:
            return None

    def exit_reason(self) -> str | None:
        """None while the process runs; else one sentence with its status and last stderr line."""
        if self.process is None or self.process.poll() is None:
            return None
        killer = self.killed_by_other()
        if killer is not None:
            return f"the target process was killed by signal {killer.value} ({killer.name}), not by the bench"
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
            self._signalled = True
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
