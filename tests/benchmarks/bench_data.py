"""Benchmark: wall time of generating the three default datasets (run: python tests/benchmarks/bench_data.py).

Goal (issue): well under 30 s for all three. Prints one line per dataset and the total.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from bench.drive.dataset import dataset_filename
from bench.drive.generate import COOLANT_SETPOINTS_C, DEFAULT_SEED, generate_and_write


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        for setpoint in COOLANT_SETPOINTS_C:
            t0 = time.perf_counter()
            _, sha = generate_and_write(Path(tmp) / dataset_filename(setpoint), setpoint, DEFAULT_SEED)
            print(f"coolant {setpoint:4g} °C: {time.perf_counter() - t0:6.2f} s  sha256 {sha[:16]}…")
        total = time.perf_counter() - started
    print(f"all three datasets: {total:.2f} s (goal: well under 30 s)")
    return 0 if total < 30 else 1


if __name__ == "__main__":
    sys.exit(main())
