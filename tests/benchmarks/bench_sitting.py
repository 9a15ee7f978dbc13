"""Performance sitting (prints figures; not a test): lockstep rows/s against the bus's own one-frame round trip.

    python tests/benchmarks/bench_sitting.py [--rounds N] [--rows N] [--pingpong-seconds S] [--note TEXT]
                                             [-i ... -c ...]

A lockstep run is bounded by the bus's round trip: one row is a request and its reply. This script measures, in
one sitting and alternating so that the machine's state falls on all three alike, per round:

(a) the python-can one-frame ping-pong: two processes on the same bus the bench uses (udp_multicast on its own
    group and a fresh port here, SocketCAN where the bench resolves to it), one sends a frame and waits for the
    other's answer, with python-can's plain blocking `recv`, for `--pingpong-seconds`: round trips per second;
(b) `bench run` in lockstep on the python engine, (c) on the firmware engine, each in a fresh process as a user
    starts it (log written, no report; `--rows` rows of the default 40 °C run, all 36 371 unless given): the run's
    own rows/s (`throughput_steps_per_s`, the replay loop from the first row to the last reply);

each quiet and with two CPU-bound processes beside it (`python -c 'while True: pass'`, started and stopped here,
killed for sure at exit). Figures: rows/s ÷ round trips/s of the same round and condition, and the medians over
the rounds. Goals (issue 40): python engine ≥ 0.7 × the ping-pong quiet, ≥ 0.3 × with the two CPU-bound
processes; firmware ≥ 0.9 × python. A machine shared with other jobs is not quiet: the load average before each
measurement is recorded beside it (`--note` says what else ran). Writes its record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from record import Record, add_record_arguments  # noqa: E402

from dbc.transport import UDP_INTERFACE, BusConfig, add_bus_arguments, config_from_args, free_udp_port, resolve  # noqa: E402

PING_ID, PONG_ID, BYE_ID = 0x101, 0x201, 0x1FF   # the ping-pong's own bus (a port of its own): any ids do
ECHO_IDLE_S = 120.0   # the answering side gives up after this long without a frame (a pinger that never came)
HOG = "while True: pass"
GOALS = {"quiet": 0.7, "loaded": 0.3, "firmware_over_python": 0.9}
ENGINES = ("python", "firmware")


# ---------------------------------------------------------------------------------------------- the ping-pong
def _open_bus(bus_json: str):
    config = json.loads(bus_json)
    return BusConfig(config.pop("interface"), config.pop("channel"), config.pop("bitrate"), config).open()


def echo(bus_json: str, seconds: float) -> int:
    """The answering side: every ping is answered with one pong, until the asking side says bye (or nothing came for
    `seconds`)."""
    import can

    bus = _open_bus(bus_json)
    pong = can.Message(arbitration_id=PONG_ID, data=bytes(8), is_extended_id=False)
    print("ready", flush=True)
    try:
        while (msg := bus.recv(seconds)) is not None and msg.arbitration_id != BYE_ID:
            if msg.arbitration_id == PING_ID:
                bus.send(pong)
    finally:
        bus.shutdown()
    return 0


def ping(bus_json: str, seconds: float) -> int:
    """The asking side: send a ping, wait for its pong (skipping the own copy udp_multicast loops back), again for
    `seconds`; prints {"round_trips", "seconds", "lost"} as JSON."""
    import can

    bus = _open_bus(bus_json)
    frame = can.Message(arbitration_id=PING_ID, data=bytes(8), is_extended_id=False)
    perf = time.perf_counter
    try:
        for _ in range(200):   # warm up: the echo is there and both sides' code paths are hot
            bus.send(frame)
            if not _await_pong(bus, 5.0):
                print(json.dumps({"error": "no answer to the warm-up pings"}), flush=True)
                return 1
        trips = lost = 0
        started = perf()
        end = started + seconds
        while perf() < end:
            bus.send(frame)
            if _await_pong(bus, 1.0):
                trips += 1
            else:
                lost += 1
        elapsed = perf() - started
        bus.send(can.Message(arbitration_id=BYE_ID, data=bytes(8), is_extended_id=False))
    finally:
        bus.shutdown()
    print(json.dumps({"round_trips": trips, "seconds": elapsed, "lost": lost}), flush=True)
    return 0


def _await_pong(bus, timeout: float) -> bool:
    deadline = time.perf_counter() + timeout
    while (remaining := deadline - time.perf_counter()) > 0:
        msg = bus.recv(remaining)
        if msg is not None and msg.arbitration_id == PONG_ID:
            return True
    return False


def run_pingpong(bus: BusConfig, seconds: float) -> dict:
    """Round trips per second of the one-frame ping-pong between two fresh processes on `bus`."""
    bus_json = json.dumps(bus.as_dict())
    me = [sys.executable, str(Path(__file__).resolve())]
    answering = subprocess.Popen([*me, "--role", "echo", "--bus-json", bus_json, "--seconds", str(ECHO_IDLE_S)],
                                 stdout=subprocess.PIPE, text=True)
    try:
        answering.stdout.readline()   # "ready": its socket has joined the group
        asking = subprocess.run([*me, "--role", "ping", "--bus-json", bus_json, "--seconds", str(seconds)],
                                capture_output=True, text=True, timeout=seconds + 1200)
        result = json.loads(asking.stdout.strip().splitlines()[-1])
    finally:
        if answering.poll() is None:
            answering.kill()
        answering.wait()
    if "error" in result:
        raise SystemExit(f"the ping-pong failed: {result['error']}")
    return {"round_trips_per_s": round(result["round_trips"] / result["seconds"]),
            "round_trip_us": round(1e6 * result["seconds"] / max(result["round_trips"], 1), 1),
            "lost": result["lost"], "seconds": round(result["seconds"], 1)}


# ---------------------------------------------------------------------------------------------- bench run
def run_bench(engine: str, bus: BusConfig, rows: int | None, tmp: Path, root: Path = ROOT) -> dict:
    """`bench run` lockstep on `engine` in a fresh process (log written, no report) of the code in `root`: its own
    rows/s and verdict."""
    argv = [sys.executable, "-m", "bench", "run", "--engine", engine, "--log", str(tmp / f"{engine}.blf"),
            "--no-report", "--json", "--quiet", *bus.to_argv()]
    if rows:
        argv += ["--rows", str(rows)]
    started = time.perf_counter()
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(root))
    done = subprocess.run(argv, capture_output=True, text=True, cwd=root, env=env)
    wall = time.perf_counter() - started
    result = json.loads(done.stdout) if done.stdout.strip().startswith("{") else {}
    if done.returncode != 0 or not result:
        last = done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "(no output)"
        print(f"  bench run --engine {engine} exited {done.returncode}: {last}")
    return {"exit": done.returncode, "rows": result.get("steps_sent"),
            "rows_per_s": result.get("throughput_steps_per_s"),
            "missing": result.get("missing"), "verdict": result.get("verdict"), "wall_s": round(wall, 1),
            "step_time_us_p50": (result.get("step_time_us") or {}).get("p50")}


# ---------------------------------------------------------------------------------------------- CPU-bound load
class Hogs:
    """Two CPU-bound processes beside the measurement while in the `with` block; killed for sure at exit."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.processes: list[subprocess.Popen] = []
        atexit.register(self.stop)

    def __enter__(self) -> Hogs:
        self.processes = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(self.count)]
        time.sleep(1.0)   # let the scheduler see them as CPU-bound before the measurement starts
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def stop(self) -> None:
        for process in self.processes:
            if process.poll() is None:
                process.kill()
            process.wait()
        self.processes = []


def _fresh_port(bus: BusConfig) -> BusConfig:
    """udp_multicast on a port of its own for each measurement (nothing of one hears another); others as given."""
    if bus.interface != UDP_INTERFACE:
        return bus
    return replace(bus, kwargs={**bus.kwargs, "port": free_udp_port()})


def _median(values: list[float | None]) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def _ratio(num: float | None, den: float | None) -> float | None:
    return round(num / den, 3) if num and den else None


def one_round(bus: BusConfig, args: argparse.Namespace, tmp: Path) -> dict:
    """(a), (b), (c) once: the ping-pong, then `bench run` on each engine; the load before each."""
    out: dict = {"load_before": round(os.getloadavg()[0], 2)}
    out["pingpong"] = run_pingpong(_fresh_port(bus), args.pingpong_seconds)
    for label, engine, root in variants(args):
        load = round(os.getloadavg()[0], 2)
        out[label] = {**run_bench(engine, _fresh_port(bus), args.rows, tmp, root), "load_before": load}
    pp = out["pingpong"]["round_trips_per_s"]
    out["ratio"] = {label: _ratio(out[label]["rows_per_s"], pp) for label, _, _ in variants(args)}
    out["ratio"]["firmware_over_python"] = _ratio(out["firmware"]["rows_per_s"], out["python"]["rows_per_s"])
    return out


def variants(args: argparse.Namespace) -> list[tuple[str, str, Path]]:
    """(label, engine, code) of each `bench run` of a round: this checkout's engines, then the --baseline's."""
    out = [(engine, engine, ROOT) for engine in ENGINES]
    if args.baseline is not None:
        out += [(f"{engine}_baseline", engine, args.baseline) for engine in ENGINES]
    return out


def summary(rounds: list[dict]) -> dict:
    """Medians over the rounds of one condition."""
    labels = [label for label in rounds[0] if label in ENGINES or label.endswith("_baseline")]
    return {"pingpong_round_trips_per_s": _median([r["pingpong"]["round_trips_per_s"] for r in rounds]),
            **{f"{e}_rows_per_s": _median([r[e]["rows_per_s"] for r in rounds]) for e in labels},
            **{f"ratio_{k}": _median([r["ratio"][k] for r in rounds]) for k in (*labels, "firmware_over_python")},
            "load_before": _median([r["load_before"] for r in rounds])}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3, help="rounds per condition (default 3)")
    parser.add_argument("--rows", type=int, default=None, help="rows of each `bench run` (default: all 36 371)")
    parser.add_argument("--pingpong-seconds", type=float, default=5.0, help="length of each ping-pong (default 5)")
    parser.add_argument("--hogs", type=int, default=2, help="CPU-bound processes beside the loaded rounds (default 2)")
    parser.add_argument("--note", default="", help="what else ran on the machine (goes into the record)")
    parser.add_argument("--baseline", type=Path, default=None, metavar="DIR",
                        help="a checkout of other code (e.g. `git worktree add DIR main`) whose `bench run` is "
                             "measured too, alternating: before and after in one sitting")
    parser.add_argument("--role", choices=("echo", "ping"), help=argparse.SUPPRESS)   # the ping-pong's processes
    parser.add_argument("--bus-json", help=argparse.SUPPRESS)
    parser.add_argument("--seconds", type=float, help=argparse.SUPPRESS)
    add_bus_arguments(parser)
    add_record_arguments(parser)
    args = parser.parse_args()
    if args.role:
        return (echo if args.role == "echo" else ping)(args.bus_json, args.seconds)
    if args.baseline is not None and not (args.baseline / "bench" / "__main__.py").is_file():
        parser.error(f"--baseline {args.baseline} is no checkout of the bench (no bench/__main__.py there)")
    if args.rounds < 1 or args.pingpong_seconds <= 0 or args.hogs < 0 or (args.rows is not None and args.rows < 1):
        parser.error("--rounds, --pingpong-seconds and --rows must be positive, --hogs not negative")
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))   # atexit kills the hogs
    bus = resolve(config_from_args(args), session_unique=True)
    record = Record("sitting", args, parameters={
        "rounds": args.rounds, "rows": args.rows, "pingpong_seconds": args.pingpong_seconds, "hogs": args.hogs,
        "bus": bus.describe().rsplit(" port ", 1)[0] + " (a fresh port per measurement)", "note": args.note,
        "baseline": None if args.baseline is None else _commit_of(args.baseline),
        "goals": GOALS})
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; bus {bus.describe()}")
    hogs = Hogs(args.hogs)
    rounds: dict[str, list[dict]] = {"quiet": [], "loaded": []}
    with tempfile.TemporaryDirectory() as tmp:
        for n in range(args.rounds):
            for condition in rounds:
                if condition == "loaded" and args.hogs:
                    with hogs:
                        result = one_round(bus, args, Path(tmp))
                else:
                    result = one_round(bus, args, Path(tmp))
                rounds[condition].append(result)
                r = result["ratio"]
                print(f"round {n + 1} {condition:6s} (load {result['load_before']:.1f}): ping-pong "
                      f"{result['pingpong']['round_trips_per_s']} round trips/s; bench run python "
                      f"{_n(result['python']['rows_per_s'])}, firmware {_n(result['firmware']['rows_per_s'])} rows/s; "
                      f"ratio {r['python']} / {r['firmware']}, firmware/python {r['firmware_over_python']}"
                      + (f"; baseline ratio {r['python_baseline']} / {r['firmware_baseline']}"
                         if args.baseline is not None else ""))
    medians = {condition: summary(results) for condition, results in rounds.items()}
    met = {"quiet": (medians["quiet"]["ratio_python"] or 0) >= GOALS["quiet"],
           "loaded": (medians["loaded"]["ratio_python"] or 0) >= GOALS["loaded"],
           "firmware_over_python": all((m["ratio_firmware_over_python"] or 0) >= GOALS["firmware_over_python"]
                                       for m in medians.values())}
    for condition, m in medians.items():
        print(f"median {condition}: ping-pong {_n(m['pingpong_round_trips_per_s'])} round trips/s, python "
              f"{_n(m['python_rows_per_s'])} rows/s (ratio {m['ratio_python']}), firmware "
              f"{_n(m['firmware_rows_per_s'])} (ratio {m['ratio_firmware']}, firmware/python "
              f"{m['ratio_firmware_over_python']})")
    if args.baseline is not None:
        for condition, m in medians.items():
            print(f"median {condition}, baseline: python {_n(m['python_baseline_rows_per_s'])} rows/s (ratio "
                  f"{m['ratio_python_baseline']}), firmware {_n(m['firmware_baseline_rows_per_s'])} (ratio "
                  f"{m['ratio_firmware_baseline']})")
    print("goals met: " + ", ".join(f"{k} {'yes' if v else 'no'}" for k, v in met.items()))
    record.figures.update(rounds=rounds, medians=medians, goals_met=met)
    record.write()
    return 0


def _commit_of(root: Path) -> str:
    """The baseline's commit (a checkout), or its path when it is no git checkout."""
    done = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=root, capture_output=True, text=True)
    return done.stdout.strip() if done.returncode == 0 else str(root)


def _n(value: float | None) -> str:
    return "–" if value is None else f"{value:.0f}"


if __name__ == "__main__":
    sys.exit(main())
