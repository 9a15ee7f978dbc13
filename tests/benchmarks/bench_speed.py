"""Speed of identification and observer tuning at 100 000 training rows (prints figures; not a test; issue 40).

    python tests/benchmarks/bench_speed.py [--priors designer table1 auto] [--skip-observer] [--work DIR]

The data: the suite's IPM motor (`examples/suite/ipm-60kw-distributed`) with six more training profiles, each a
training profile's phases twice over at 5 °C warmer coolant and other random-step seeds (`speed_motor`): 13 training
files, 98 947 rows at 1 s (the size of a real motor's 81 000 rows in 13 files that issue 40 timed), the suite's own
validation profiles. Then, as a user runs them and as `bench_suite.py` does:

1. Per prior (`designer`: the motor file's own; `table1`: another machine's network, as named; `auto`: read from the
   data), `bench identify --all-kinds --bounds 0.1,10` on the 13 training files with the validation profiles as
   --validate; wall time, CPU time (the child's user + system seconds: on a shared machine the wall time is the
   load's, the CPU time the work's) and the load average before and after.
2. `bench observer` on the designer's Hammerstein artifact with the end-winding NTC (lag, gradient and offset
   estimated), 150 filter runs as `bench_suite.py`; the same figures.

Goal (issue 40): each identification and the observer within 120 s of wall time on 2 cores; the record says
whether each met it and at what load. Writes its record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_accuracy import bench, children_cpu_s  # noqa: E402
from bench_suite import (  # noqa: E402
    BOUNDS,
    OBSERVER_EVALUATIONS,
    PRIORS,
    SENSOR,
    files,
    generate,
    identify,
    run_tag,
)
from record import Record, add_record_arguments  # noqa: E402

from bench.model.choices import FILES_LM_FACTORIZATION, LM_FACTORIZATIONS  # noqa: E402

SUITE_MOTOR = ROOT / "examples" / "suite" / "ipm-60kw-distributed"
GOAL_S = 120.0
LONGER = ("p02", "p03", "p04", "p05", "p06", "p07")   # the training profiles played twice over as extra files
COOLANT_SHIFT_C = 5.0
SEED_SHIFT = 1000


def speed_motor(work: Path) -> Path:
    """The suite IPM motor's directory copied under `work` with the extra training profiles in its motor file."""
    motor_dir = work / "ipm-60kw-speed"
    motor_dir.mkdir(parents=True, exist_ok=True)
    content = json.loads((SUITE_MOTOR / "motor.json").read_text(encoding="utf-8"))
    profiles = content["virtual_plant"]["profiles"]
    extra = []
    for profile in profiles:
        prefix = profile["name"].split("_")[0]
        if profile["role"] != "train" or prefix not in LONGER:
            continue
        longer = copy.deepcopy(profile)
        longer["name"] = f"{prefix}x_long"
        longer["coolant_C"] = profile["coolant_C"] + COOLANT_SHIFT_C
        longer["phases"] = copy.deepcopy(profile["phases"]) + copy.deepcopy(profile["phases"])
        for i, phase in enumerate(longer["phases"]):
            if "seed" in phase:
                phase["seed"] += SEED_SHIFT + i
        extra.append(longer)
    content["virtual_plant"]["profiles"] = profiles + extra
    content["name"] = f"{content['name']}-speed"
    (motor_dir / "motor.json").write_text(json.dumps(content, indent=2) + "\n", encoding="utf-8")
    shutil.copyfile(SUITE_MOTOR / "mapping.json", motor_dir / "mapping.json")
    return motor_dir


def training_rows(index: dict) -> int:
    rows = {p["file"]: p["rows"] for p in index["profiles"]}
    return sum(rows[name] for name in index["roles"]["train"])


def tune_observer(motor: Path, data: Path, index: dict, model: Path) -> dict:
    """`bench observer` as bench_suite.py runs it (the sensor's lag, gradient and offset estimated), timed."""
    cpu, load = children_cpu_s(), os.getloadavg()[0]
    tuned, seconds = bench("observer", "--model", str(model), "--mapping", str(motor / "mapping.json"),
                           "--train", *files(data, index, "train"), "--measure", SENSOR, "--lag", "auto",
                           "--gradient", "auto", "--offset", "auto", "--evaluations", OBSERVER_EVALUATIONS,
                           "--out", str(model.with_name("observer.json")))
    return {"seconds": round(seconds, 1), "cpu_s": round(children_cpu_s() - cpu, 1),
            "load_average": [round(load, 2), round(os.getloadavg()[0], 2)], "evaluations": tuned["evaluations"],
            "criterion_value": tuned["criterion_value"], "goal_met": seconds <= GOAL_S}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--priors", nargs="+", choices=PRIORS, default=list(PRIORS))
    parser.add_argument("--skip-observer", action="store_true")
    parser.add_argument("--work", type=Path, default=None, help="keep the generated files and models here")
    parser.add_argument("--lm-factorization", choices=LM_FACTORIZATIONS, default=FILES_LM_FACTORIZATION,
                        help="identify's --lm-factorization (default: identify's own with --train files)")
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("speed", args, parameters={"motor": SUITE_MOTOR.name, "extra_training_profiles": list(LONGER),
                                               "priors": args.priors, "bounds": BOUNDS, "goal_s": GOAL_S,
                                               "observer_evaluations": int(OBSERVER_EVALUATIONS),
                                               "lm_factorization": args.lm_factorization})
    chosen = () if args.lm_factorization == FILES_LM_FACTORIZATION else ("--lm-factorization", args.lm_factorization)
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench-speed-") as tmp:
        work = args.work or Path(tmp)
        motor = speed_motor(work)
        data, index, data_s = generate(motor, work)
        rows = training_rows(index)
        print(f"data: {len(index['roles']['train'])} training files, {rows} rows ({data_s:.0f} s)", flush=True)
        record.figures.update(training_files=len(index["roles"]["train"]), training_rows=rows, data_s=round(data_s, 1),
                              identify={})
        record.write()     # after each step: an interrupted run keeps what it measured
        designer_model = None
        for prior in args.priors:
            run = identify(motor, work, data, index, prior, extra=chosen, tag=run_tag(chosen))
            timings = {k: round(v, 1) for k, v in run["json"]["timings_s"].items()}
            record.figures["identify"][prior] = {
                "seconds": round(run["seconds"], 1), "cpu_s": round(run["cpu_s"], 1),
                "load_average": run["load_average"], "stages_s": timings,
                "deployed_kind": run["json"]["deployed_kind"], "pso_cost": run["json"]["pso_cost"],
                "goal_met": run["seconds"] <= GOAL_S}
            print(f"identify --all-kinds, {prior} prior: {run['seconds']:.0f} s wall, {run['cpu_s']:.0f} CPU-s "
                  f"(load {run['load_average']}); stages {timings}", flush=True)
            if prior == "designer":
                designer_model = run["artifacts"]["hammerstein"]
            record.write()
        if not args.skip_observer:
            if designer_model is None:
                designer_model = identify(motor, work, data, index, "designer", extra=chosen,
                                          tag=run_tag(chosen))["artifacts"]["hammerstein"]
            tuned = tune_observer(motor, data, index, designer_model)
            record.figures["observer"] = tuned
            print(f"observer ({SENSOR}, lag/gradient/offset auto, {tuned['evaluations']} filter runs): "
                  f"{tuned['seconds']:.0f} s wall, {tuned['cpu_s']:.0f} CPU-s (load {tuned['load_average']})",
                  flush=True)
    record.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
