"""CAN bench benchmark (prints figures; not a test): lockstep campaign throughput, round trips, realtime jitter.

    python tests/benchmarks/bench_can.py [--rows N] [--realtime-seconds S] [--fast-rows N] [-i ... -c ...]

1. Lockstep replay of the three-run campaign (coolant 20, 40, 60 °C; 3 × 36 371 rows at 5 Hz), each run with its
   own target process, as `bench run` does it (log written, no report). Goal: ≤ 40 s in all, ≥ 2 700 rows/s.
   `--rows N` replays only the first N rows of each run and says so (the figure is then an extrapolation).
2. Realtime at the data rate (5 Hz) for `--realtime-seconds` (default 60 s) and at --speed 100 (`--fast-rows`,
   default 6 000 rows = 12 s): send-time jitter (actual − planned) p50/p99/max. Goal: p99 ≤ 1 ms.
3. The default run as a user starts it: `bench run --log … --report …` in a fresh process on the datasets already
   made (`--default-runs`, default 2): wall time from start to exit, and the run's own rows/s.
Round trips are measured by the host (send of DriveInputs to the processed Temperatures2, perf_counter). Writes its
record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from record import Record, add_record_arguments  # noqa: E402

from bench.drive.dataset import load_dataset  # noqa: E402
from bench.drive.generate import ensure_default_datasets  # noqa: E402
from bench.model.default import default_artifact_path  # noqa: E402
from bench.model.runs import drive_matrix, initial_temperatures  # noqa: E402
from bench.run.execute import run_with_target  # noqa: E402
from dbc.transport import add_bus_arguments, config_from_args, resolve  # noqa: E402
from target_sim.artifact import load_artifact  # noqa: E402


def _fmt(p: dict, digits: int = 0) -> str:
    return "/".join("–" if p[k] is None else f"{p[k]:.{digits}f}" for k in ("p50", "p99", "max"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=None, help="rows per run (default: all 36 371)")
    parser.add_argument("--realtime-seconds", type=float, default=60.0)
    parser.add_argument("--fast-rows", type=int, default=6000)
    parser.add_argument("--default-runs", type=int, default=2, help="`bench run` invocations timed (default 2)")
    parser.add_argument("--data", type=Path, default=ROOT / "out" / "data")
    add_bus_arguments(parser)
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("can", args, parameters={"rows": args.rows, "realtime_seconds": args.realtime_seconds,
                                             "fast_rows": args.fast_rows, "default_runs": args.default_runs})
    bus = resolve(config_from_args(args), session_unique=True)
    model_path = default_artifact_path()
    artifact = load_artifact(model_path)
    paths = ensure_default_datasets(args.data)
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; bus {bus.describe()}; "
          f"model {artifact.kind} {artifact.model_id:08x}")
    record.parameters.update(bus=bus.describe(), model=f"{artifact.kind} {artifact.model_id:08x}")

    with tempfile.TemporaryDirectory() as tmp:
        total_rows = 0
        total_wall = 0.0
        runs = []
        started = time.perf_counter()
        for setpoint, path in sorted(paths.items()):
            dataset = load_dataset(path)
            drive = drive_matrix(dataset)[: args.rows] if args.rows else drive_matrix(dataset)
            outcome = run_with_target(model_path, artifact, bus, drive, initial_temperatures(dataset),
                                      sample_period_s=dataset.sample_period_s,
                                      log_path=Path(tmp) / f"run{setpoint}.blf")
            r = outcome.result
            total_rows += r.rows_sent
            total_wall += r.wall_time_s
            runs.append({"coolant_C": setpoint, "rows": r.rows_sent, "wall_s": round(r.wall_time_s, 2),
                         "rows_per_s": round(r.rows_per_s), "round_trip_us": r.round_trip_us,
                         "missing": r.missing, "step_time_us_p50": r.step_time_us["p50"]})
            print(f"lockstep {setpoint} °C: {r.rows_sent} rows in {r.wall_time_s:.2f} s = {r.rows_per_s:.0f} rows/s, "
                  f"round trip p50/p99/max {_fmt(r.round_trip_us)} µs, missing {r.missing}, "
                  f"target step p50 {r.step_time_us['p50']:.1f} µs")
        overall = time.perf_counter() - started
        rate = total_rows / total_wall
        print(f"lockstep campaign: {total_rows} rows, replay {total_wall:.1f} s ({rate:.0f} rows/s), "
              f"{overall:.1f} s with process start/stop")
        if args.rows:
            print(f"  (subset of {args.rows} rows per run; the full 3 x 36 371 rows would take about "
                  f"{3 * 36371 / rate:.1f} s at this rate)")
        record.figures["lockstep"] = {"runs": runs, "rows": total_rows, "replay_s": round(total_wall, 1),
                                      "rows_per_s": round(rate), "with_start_stop_s": round(overall, 1)}

        dataset = load_dataset(paths[40])
        for label, speed, rows in (("realtime 5 Hz", 1.0, int(args.realtime_seconds / dataset.sample_period_s)),
                                   ("realtime x100", 100.0, args.fast_rows)):
            drive = drive_matrix(dataset)[:rows]
            outcome = run_with_target(model_path, artifact, bus, drive, initial_temperatures(dataset),
                                      mode="realtime", speed=speed, sample_period_s=dataset.sample_period_s,
                                      log_path=Path(tmp) / f"rt{speed:g}.blf")
            r = outcome.result
            print(f"{label}: {r.rows_sent} rows in {r.wall_time_s:.1f} s, send jitter p50/p99/max "
                  f"{_fmt(r.send_jitter_us, 1)} µs, round trip p50/p99 {_fmt(r.round_trip_us)} µs, missing {r.missing}")
            record.figures.setdefault("realtime", []).append(
                {"speed": speed, "rows": r.rows_sent, "wall_s": round(r.wall_time_s, 1),
                 "send_jitter_us": r.send_jitter_us, "round_trip_us": r.round_trip_us, "missing": r.missing})
        record.figures["default_run"] = [default_run(paths[40], Path(tmp) / f"default{i}")
                                         for i in range(args.default_runs)]
    record.write()
    return 0


def default_run(data: Path, out: Path) -> dict:
    """`bench run` as the quick start runs it (the 40 °C run `data`, report included), in a fresh process: its wall
    time and figures."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "bench", "run", "--data", str(data), "--log", str(out / "run.blf"),
                           "--report", str(out / "report"), "--json", "--quiet"],
                          capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, MPLBACKEND="Agg"))
    wall = time.perf_counter() - started
    result = json.loads(done.stdout) if done.stdout.strip().startswith("{") else {}
    figures = {"exit": done.returncode, "wall_s": round(wall, 1), "rows_per_s": result.get("throughput_steps_per_s"),
               "verdict": result.get("verdict"), "rows": result.get("steps_sent"), "missing": result.get("missing"),
               "elapsed_s": result.get("elapsed_s"),
               "max_abs_can_minus_float32_C": result.get("max_abs_can_minus_float32_C")}
    print(f"default bench run: exit {done.returncode} in {wall:.1f} s, {figures['rows_per_s']} rows/s, "
          f"verdict {figures['verdict']}")
    return figures


if __name__ == "__main__":
    sys.exit(main())
