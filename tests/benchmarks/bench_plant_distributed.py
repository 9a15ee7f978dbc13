"""Benchmark: wall time of one 6-hour profile of the distributed virtual plant (run: python
tests/benchmarks/bench_plant_distributed.py [--step S]).

Goal (design notes, "Plants the model cannot be"): under 15 s at a plant step of 0.1-0.5 s on the 2-core build
machine. The profile: examples/suite/ipm-60kw-distributed with its profiles replaced by one of drive cycles,
constant points and steps over 6 h, coolant set points from 25 to 65 °C, the full speed range. Prints the time,
the number of steps and of exact-step grid corners, and writes its record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from record import Record, add_record_arguments  # noqa: E402

from bench.drive.virtual import virtual_plant  # noqa: E402
from bench.motor.description import motor_from_dict  # noqa: E402

MOTOR = Path(__file__).resolve().parents[2] / "examples" / "suite" / "ipm-60kw-distributed" / "motor.json"
GOAL_S = 15.0
SIX_HOURS = [
    {"kind": "constant", "torque_Nm": 100, "speed_rpm": 3000, "duration_s": 2400},
    {"kind": "cycle", "cycle": "wltc3b", "coolant_C": 45},
    {"kind": "constant", "torque_Nm": 40, "speed_rpm": 12000, "duration_s": 1800},
    {"kind": "cycle", "cycle": "ftp75", "coolant_C": 65},
    {"kind": "steps", "points": [[140, 2000, 60], [30, 9000, 120]], "repeat": 10},
    {"kind": "cycle", "cycle": "wltc3b", "speed_scale": 1.2, "coolant_C": 25},
    {"kind": "constant", "torque_Nm": 60, "speed_rpm": 7000, "duration_s": 3600},
    {"kind": "cycle", "cycle": "ftp75"},
    {"kind": "cycle", "cycle": "wltc3b"},
    {"kind": "constant", "torque_Nm": 80, "speed_rpm": 5000, "duration_s": 2436, "coolant_C": 40},
    {"kind": "rest", "duration_s": 300},
]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--step", type=float, default=None, help="plant step in s (default: the motor file's)")
    add_record_arguments(parser)
    args = parser.parse_args()
    content = json.loads(MOTOR.read_text(encoding="utf-8"))
    if args.step is not None:
        content["virtual_plant"]["plant_step_s"] = args.step
    content["virtual_plant"]["profiles"] = [{"name": "six_hours", "role": "train", "coolant_C": 25,
                                             "phases": SIX_HOURS}]
    plant = virtual_plant(motor_from_dict(content, MOTOR))
    profile = plant.profiles[0]
    record = Record("plant_distributed", args, parameters={"step_s": plant.plant_step_s,
                                                           "duration_s": profile.duration_s})
    started = time.perf_counter()
    run = plant.simulate(profile)
    seconds = time.perf_counter() - started
    steps = int(round(profile.duration_s / plant.plant_step_s))
    corners = sum(len(t) for t in plant.thermal._tables.values())
    print(f"{profile.duration_s / 3600:.2f} h at {plant.plant_step_s:g} s ({steps} steps, {plant.thermal.net.size} "
          f"nodes, {corners} grid corners): {seconds:.2f} s (goal: under {GOAL_S:g} s); winding up to "
          f"{run.truth['winding'].max():.1f} °C, magnet up to {run.truth['magnet'].max():.1f} °C")
    record.figures.update(seconds=round(seconds, 2), steps=steps, corners=corners, goal_s=GOAL_S)
    record.write()
    return 0 if seconds < GOAL_S else 1


if __name__ == "__main__":
    sys.exit(main())
