"""Benchmark: wall time of generating the three default datasets (run: python tests/benchmarks/bench_data.py).

Goal (issue): well under 30 s for all three. Prints one line per dataset and the total, and writes its record
(`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from record import Record, add_record_arguments  # noqa: E402

from bench.drive.dataset import dataset_filename  # noqa: E402
from bench.drive.generate import COOLANT_SETPOINTS_C, DEFAULT_SEED, generate_and_write  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_record_arguments(parser)
    record = Record("data", parser.parse_args(), parameters={"seed": DEFAULT_SEED})
    per_dataset = {}
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        for setpoint in COOLANT_SETPOINTS_C:
            t0 = time.perf_counter()
            _, sha = generate_and_write(Path(tmp) / dataset_filename(setpoint), setpoint, DEFAULT_SEED)
            seconds = time.perf_counter() - t0
            per_dataset[f"{setpoint:g}"] = {"seconds": round(seconds, 2), "sha256": sha}
            print(f"coolant {setpoint:4g} °C: {seconds:6.2f} s  sha256 {sha[:16]}…")
        total = time.perf_counter() - started
    print(f"all three datasets: {total:.2f} s (goal: well under 30 s)")
    record.figures.update(datasets=per_dataset, total_s=round(total, 2), goal_s=30)
    record.write()
    return 0 if total < 30 else 1


if __name__ == "__main__":
    sys.exit(main())
