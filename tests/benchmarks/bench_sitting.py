"""Performance sitting (prints figures; not a test): lockstep rows/s against the bus's own one-frame round trip.

    python tests/benchmarks/bench_sitting.py [--rounds N] [--rows N] [--pingpong-seconds S] [--hogs N]
                                             [--budget-rows N] [--baseline DIR] [--note TEXT] [-i ... -c ...]

A lockstep run is bounded by the bus's round trip: one row is a request and its reply. This script measures, in
one sitting and alternating so that the machine's state falls on all three alike, per round:

(a) the python-can one-frame ping-pong: two processes on the same bus the bench uses (udp_multicast on its own
    group and a fresh port here, SocketCAN where the bench resolves to it), one sends a frame and waits for the
    other's answer, with python-can's own bus (`can.Bus`, not the bench's leaner udp_multicast receive) and its
    plain blocking `recv`, for `--pingpong-seconds`: round trips per second;
(b) `bench run` in lockstep on the python engine, (c) on the firmware engine, each in a fresh process as a user
    starts it (log written, no report; `--rows` rows of the default 40 °C run, all 36 371 unless given): the run's
    own rows/s (`throughput_steps_per_s`, the replay loop from the first row to the last reply);

each quiet and with two CPU-bound processes beside it (`python -c 'while True: pass'`, started and stopped here,
killed for sure at exit). Figures: rows/s ÷ round trips/s of the same round and condition, and the medians over
the rounds. Goals (issue 40): python engine ≥ 0.7 × the ping-pong quiet, ≥ 0.3 × with the two CPU-bound
processes; firmware ≥ 0.9 × python. A machine shared with other jobs is not quiet: the load average before each
measurement is recorded beside it (`--note` says what else ran). `--baseline DIR` measures the `bench run` of
another checkout too, in the same rounds (before and after a change, in one sitting).

First, per engine, where a row's µs go: host and target of a lockstep run in this one thread, one after the other
(no wake-up, no scheduler), each part of the row timed in the thread's CPU time, so the figure holds on a loaded
machine (`--budget-rows`), beside the ping-pong's round trip timed the same way. Writes its record
(`tests/benchmarks/record.py`).
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
    return python_can_bus(BusConfig(config.pop("interface"), config.pop("channel"), config.pop("bitrate"), config))


def python_can_bus(bus: BusConfig):
    """python-can's own bus of `bus` (`can.Bus`), for the ping-pong: the floor is python-can's round trip, not the
    bench's (`BusConfig.open` gives udp_multicast a leaner receive, `dbc.udp_bus`)."""
    return bus.open(lean=False)


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


# ---------------------------------------------------------------------------------------------- the CPU budget
BUDGET_PARTS = ("host: encode the next row", "host: send the row", "target: receive and handle the row",
                "target: send the replies", "target: read back its own copies",
                "host: read its own copies and the replies", "host: write the log")


def cpu_budget(engine: str, rows: int, bus: BusConfig, data: Path) -> dict:
    """Where a row's µs go: host and target of one lockstep run, both in this one thread (each step in turn, so no
    wake-up and no scheduler), each part timed in CPU time of the thread (`time.thread_time_ns`: a preempted moment
    is not counted, so the figure holds on a loaded machine); then the one-frame ping-pong timed the same way."""
    import can

    from bench.drive.dataset import load_dataset
    from bench.drive.generate import ensure_default_datasets
    from bench.model.default import default_artifact_path
    from bench.model.runs import drive_matrix, initial_temperatures
    from bench.run.inputs import firmware_for_engine
    from dbc.contract import RESET_SIGNALS, Command, split_temperatures
    from dbc.database import host_frame_ids, target_frame_ids
    from dbc.loopback_filter import drop_own_frames
    from dbc.transport import OwnFrameFilter, SenderGuard
    from dbc.xcp import res_id
    from host.canlog import FrameLog
    from host.session import HostSession
    from target_sim.artifact import load_artifact
    from target_sim.engines import make_node

    artifact = load_artifact(default_artifact_path())
    dataset = load_dataset(ensure_default_datasets(data)[40])
    drive = drive_matrix(dataset)[:rows]
    with tempfile.TemporaryDirectory() as tmp:
        firmware = firmware_for_engine(engine, artifact, Path(tmp))
        node = make_node(artifact, engine=engine, firmware=firmware)
        host_bus, target_bus = SenderGuard(bus.open(), bus, host_frame_ids()), bus.open()
        drop_own_frames(target_bus, target_frame_ids() | {res_id()})   # as `target_sim.node.serve` does
        session = HostSession(host_bus, log=FrameLog(Path(tmp) / "budget.blf"), expected_model_id=artifact.model_id)
        try:
            initial = [round(float(v), 2) for v in initial_temperatures(dataset)]   # the handshake, straight in
            for name, signals in split_temperatures(initial, RESET_SIGNALS).items():
                node.handle(session.codec.encode(name, {"Step": 0, **signals}))
            node.handle(session.control(Command.RESET))
            node.handle(session.control(Command.START))
            parts, frames_out = _budget_rows(session, node, target_bus, OwnFrameFilter(target_frame_ids()), drive)
        finally:
            session.log.close(commit=False)
            host_bus.shutdown()
            target_bus.shutdown()
    ping_bus, echo_bus = python_can_bus(bus), python_can_bus(bus)
    try:
        ping_us = _budget_pingpong(can, ping_bus, echo_bus, 5000)
    finally:
        ping_bus.shutdown()
        echo_bus.shutdown()
    per_row = {part: round(ns / 1000 / rows, 1) for part, ns in zip(BUDGET_PARTS, parts, strict=True)}
    return {"rows": rows, "per_row_us": per_row, "row_us": round(sum(per_row.values()), 1),
            "target_frames_out_per_row": round(frames_out / rows, 2), "pingpong_round_trip_us": round(ping_us, 1)}


def _budget_rows(session, node, target_bus, own, drive) -> tuple[list[int], int]:
    """The lockstep loop with both nodes in turn in this thread: CPU ns per part (BUDGET_PARTS) and frames sent."""
    from host.replay import RowValues
    from host.session import RowBook

    rows = len(drive)
    book = session.book = RowBook(rows)
    values = RowValues(drive)
    clock = time.thread_time_ns
    parts = [0] * len(BUDGET_PARTS)
    frames_out = 0
    upcoming = values.frames(session.codec, 0)
    for n in range(rows):
        marks = [clock()]
        frames, session.last_sent_row = upcoming, n
        book.sent_ns[n] = time.perf_counter_ns()
        session.send(frames)
        marks.append(clock())
        if n + 1 < rows:
            upcoming = values.frames(session.codec, n + 1)
        marks.append(clock())
        replies, heard = [], 0
        while heard < len(frames):
            msg = target_bus.recv(1.0)
            if msg is None:
                raise SystemExit(f"the budget's row {n} did not reach the target")
            if not own.is_own(msg):
                heard += 1
                replies += node.handle(msg)
        marks.append(clock())
        for frame in replies:
            target_bus.send(frame)
        frames_out += len(replies)
        marks.append(clock())
        while target_bus.recv(0.0) is not None:
            pass
        marks.append(clock())
        while not book.is_answered(n):
            if session.receive(1.0) is None:
                raise SystemExit(f"the budget's row {n} got no reply")
        session.drain()
        marks.append(clock())
        session.flush_log()
        marks.append(clock())
        # marks: send, encode, target handle, target send, own copies, host receive, log (in BUDGET_PARTS order)
        order = (1, 0, 2, 3, 4, 5, 6)
        for part, index in zip(order, range(len(marks) - 1), strict=True):
            parts[part] += marks[index + 1] - marks[index]
    return parts, frames_out


def _budget_pingpong(can, ping_bus, echo_bus, trips: int) -> float:
    """CPU µs of one ping-pong round trip (two sends, four receives with the loopback copies), in this thread."""
    ping = can.Message(arbitration_id=PING_ID, data=bytes(8), is_extended_id=False)
    pong = can.Message(arbitration_id=PONG_ID, data=bytes(8), is_extended_id=False)
    started = time.thread_time_ns()
    for _ in range(trips):
        ping_bus.send(ping)
        while (msg := echo_bus.recv(1.0)) is not None and msg.arbitration_id != PING_ID:
            pass
        echo_bus.send(pong)
        while (msg := ping_bus.recv(1.0)) is not None and msg.arbitration_id != PONG_ID:
            pass
        while echo_bus.recv(0.0) is not None:
            pass
    return (time.thread_time_ns() - started) / trips / 1000


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
    parser.add_argument("--budget-rows", type=int, default=3000,
                        help="rows of the CPU budget per engine, both nodes in this thread (default 3000; 0: none)")
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
    record.parameters["budget_rows"] = args.budget_rows
    if args.budget_rows:
        record.figures["budget"] = {}
        for engine in ENGINES:
            budget = record.figures["budget"][engine] = cpu_budget(engine, args.budget_rows, _fresh_port(bus),
                                                                   ROOT / "out" / "data")
            print(f"CPU budget, {engine} engine: {budget['row_us']} µs a row (" + ", ".join(
                f"{part} {us}" for part, us in budget["per_row_us"].items()) + f"); the ping-pong "
                f"{budget['pingpong_round_trip_us']} µs a round trip")
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
