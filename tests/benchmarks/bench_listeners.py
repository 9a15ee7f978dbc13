"""Which CAN tools keep up with a run (prints figures; not a test): python-can's logger and viewer and cantools'
monitor attached to `bench run`, in lockstep and paced with `--mode realtime --speed S`.

    python tests/benchmarks/bench_listeners.py [--rows N] [--speeds S ...] [--repeats K]

Per pacing and repeat: three listeners are started on one bus group and port (the udp_multicast bus; SocketCAN
where the kernel has it is `-i socketcan -c vcan0`, not measured here), then `bench run --rows N` with that bus:
- `python -m can.logger -f copy.asc`: frames in its file;
- `python -m can.viewer`: on a pseudo-terminal read by a terminal emulator (pyte; `pip install pyte`), the sum of
  its per-id Count column once the run has ended;
- `cantools monitor dbc/thermal_bench.dbc`: likewise, its "Received: N" line.
Each is compared with the frames of the run's own log (`--log run.blf`): the share each listener saw. A listener
started before the run also sees the target's heartbeats before and after it, so a share may exceed 100 % by a few
frames. The figures go to the CAN tools page (docs/tutorials/can-tools.md). Writes its record
(`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import json
import os
import pty
import re
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from record import Record, add_record_arguments  # noqa: E402

DBC = ROOT / "dbc" / "thermal_bench.dbc"
GROUP = "239.74.163.9"           # a group of its own: other runs on the machine are not counted
SCREEN = (160, 60)               # columns, lines of the listeners' terminals: room for every frame id
SETTLE_S = 3.0                   # after the run: the listeners drain their sockets and redraw
RUN_TIMEOUT_S = 900


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        return s.getsockname()[1]


class TerminalListener:
    """A curses tool on a pseudo-terminal of SCREEN size, its output fed into a pyte screen as it comes."""

    def __init__(self, argv: list[str]):
        import pyte

        self.screen = pyte.Screen(*SCREEN)
        self._stream = pyte.ByteStream(self.screen)
        self._lock = threading.Lock()
        master, slave = pty.openpty()
        import fcntl
        import struct
        import termios

        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", SCREEN[1], SCREEN[0], 0, 0))
        env = dict(os.environ, TERM="xterm", COLUMNS=str(SCREEN[0]), LINES=str(SCREEN[1]))
        self.process = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, env=env, cwd=ROOT,
                                        start_new_session=True)
        os.close(slave)
        self._master = master
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while True:
            try:
                data = os.read(self._master, 65536)
            except OSError:
                return
            if not data:
                return
            with self._lock:
                self._stream.feed(data)

    def text(self) -> str:
        with self._lock:
            return "\n".join(self.screen.display)

    def stop(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGINT)
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        self._reader.join(5)
        os.close(self._master)


def viewer_count(screen: str) -> int | None:
    """The sum of can.viewer's Count column (a row: count, time, dt, id, dlc, data)."""
    rows = [int(m.group(1)) for m in re.finditer(r"^\s*(\d+)\s+\d+\.\d+\s+\d+\.\d+\s+0x[0-9A-Fa-f]+", screen, re.M)]
    return sum(rows) if rows else None


def monitor_count(screen: str) -> int | None:
    found = re.findall(r"Received: (\d+)", screen)
    return int(found[-1]) if found else None


def log_frames(path: Path) -> int:
    import can

    with can.LogReader(str(path)) as reader:
        return sum(1 for _ in reader)


def one_run(work: Path, rows: int, speed: float | None) -> dict:
    """The listeners and one `bench run` (lockstep when `speed` is None): each listener's count and the run's."""
    port = free_udp_port()
    bus = ["-i", "udp_multicast", "-c", GROUP, "--bus-kwargs", f"port={port}"]
    work.mkdir(parents=True)
    logger = subprocess.Popen([sys.executable, "-m", "can.logger", *bus, "-f", str(work / "copy.asc")],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    viewer = TerminalListener([sys.executable, "-m", "can.viewer", *bus])
    monitor = TerminalListener(["cantools", "monitor", str(DBC), *bus])
    try:
        time.sleep(3.0)      # the three joined the group (python start-up, curses)
        pacing = ["--mode", "realtime", "--speed", f"{speed:g}"] if speed else ["--mode", "lockstep"]
        started = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "bench", "run", "--rows", str(rows), *pacing, *bus,
                               "--log", str(work / "run.blf"), "--no-report", "--json", "--quiet"],
                              capture_output=True, text=True, cwd=ROOT, timeout=RUN_TIMEOUT_S,
                              env=dict(os.environ, MPLBACKEND="Agg"))
        wall = time.perf_counter() - started
        time.sleep(SETTLE_S)
        seen = {"viewer": viewer_count(viewer.text()), "monitor": monitor_count(monitor.text())}
    finally:
        for listener in (viewer, monitor):
            listener.stop()
        logger.send_signal(signal.SIGINT)     # can.logger closes its file on Ctrl-C
        try:
            logger.wait(20)
        except subprocess.TimeoutExpired:
            logger.kill()
            logger.wait()
    result = json.loads(done.stdout) if done.stdout.strip().startswith("{") else {}
    frames = log_frames(work / "run.blf") if (work / "run.blf").exists() else None
    seen["logger"] = log_frames(work / "copy.asc") if (work / "copy.asc").exists() else None
    rate = result.get("throughput_steps_per_s")
    rate = round(rate) if rate else None
    return {"exit": done.returncode, "rows_per_s": rate, "wall_s": round(wall, 1), "run_frames": frames,
            "frames_per_s": round(frames / result["elapsed_s"]) if frames and result.get("elapsed_s") else None,
            "seen": seen,
            "share": {k: (None if v is None or not frames else round(v / frames, 4)) for k, v in seen.items()},
            "stderr": done.stderr.strip().splitlines()[-1:] if done.returncode else []}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=2000, help="rows of the default data per run (default 2000)")
    parser.add_argument("--speeds", type=float, nargs="*", default=[50.0, 100.0, 200.0],
                        help="realtime speed factors to try beside lockstep (default 50 100 200)")
    parser.add_argument("--repeats", type=int, default=2, help="runs per pacing (default 2)")
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("listeners", args, parameters={"rows": args.rows, "speeds": args.speeds,
                                                   "repeats": args.repeats, "group": GROUP})
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    pacings: list[float | None] = [None, *args.speeds]
    results: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):          # alternating: each pacing once per round
            for speed in pacings:
                label = "lockstep" if speed is None else f"realtime x{speed:g}"
                figures = one_run(Path(tmp) / f"{label.replace(' ', '-')}-{repeat}", args.rows, speed)
                results.setdefault(label, []).append(figures)
                share = ", ".join(f"{k} {'–' if v is None else f'{100 * v:.1f} %'}"
                                  for k, v in figures["share"].items())
                print(f"{label} #{repeat + 1}: exit {figures['exit']}, {figures['rows_per_s']} rows/s, "
                      f"{figures['frames_per_s']} frames/s, {figures['run_frames']} frames; seen: {share}")
    summary = {}
    for label, runs in results.items():
        summary[label] = {
            "rows_per_s": statistics.median(r["rows_per_s"] for r in runs if r["rows_per_s"]) if any(
                r["rows_per_s"] for r in runs) else None,
            "frames_per_s": statistics.median(r["frames_per_s"] for r in runs if r["frames_per_s"]) if any(
                r["frames_per_s"] for r in runs) else None,
            "share_min": {k: min((r["share"][k] for r in runs if r["share"][k] is not None), default=None)
                          for k in ("logger", "viewer", "monitor")}}
    record.figures = {"runs": results, "summary": summary, "load_end": round(os.getloadavg()[0], 2)}
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
