"""Firmware engine benchmark (prints figures; not a test): bit-exactness, cycles, memory, emulation speed, and the
lockstep throughput of the two engines.

    python tests/benchmarks/bench_firmware.py [--rows N] [--repeats R] [--skip-matrix] [--skip-lockstep]

1. `bench firmware check` (in-process: `bench.firmware.check.check_firmware`) over the full 40 °C validation run
   (36 371 rows, 14 548 model steps at Δt 0.5 s) for the three packaged artifacts (their shipped ELFs): mismatches
   against the Python float32 reference, Cortex-M4 cycles per step p50/max, flash, RAM, stack used, emulated
   model steps per second.
2. The same for the balanced, modal and physical realizations at Δt 0.5, 1, 2, 4 s of the LTI LPTN and the
   Hammerstein model, built from the packaged Hammerstein artifact's identified parameters, loss maps and sigmoid
   (the Hammerstein linear block is the LPTN's own at the other Δt: no refit, the point is the firmware, not the
   fit), each compiled with the project's toolchain (needs the `firmware` extra).
3. Lockstep throughput of `bench run` with `--engine firmware` and `--engine python` on the full default run, in
   the same sitting, alternating (R runs each, default 2; log written, no report), rows/s as the host measures
   the replay. Goal: >= 3 000 rows/s with the firmware engine.
Beside each firmware figure, the C28x estimate the target reports (`target_sim.costs`). Writes its record
(`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from record import Record, add_record_arguments  # noqa: E402

from bench.drive.dataset import load_dataset  # noqa: E402
from bench.drive.generate import ensure_default_datasets  # noqa: E402
from bench.firmware.check import check_firmware  # noqa: E402
from bench.firmware.images import PACKAGED_KINDS, firmware_for, packaged_elf_path  # noqa: E402
from bench.model.default import default_artifact_path  # noqa: E402
from bench.model.runs import drive_matrix, initial_temperatures  # noqa: E402
from target_sim.artifact import load_artifact, verify  # noqa: E402
from target_sim.costs import memory_estimate, step_cost  # noqa: E402

REALIZATIONS = ("balanced", "modal", "physical")
DTS = (0.5, 1.0, 2.0, 4.0)


def _row(label: str, r: dict) -> str:
    return (f"{label:34} {r['steps']:6d} {r['mismatches']:5d} {r['cycles']['p50']:6d} {r['cycles']['max']:6d} "
            f"{r['exec_us_at_90MHz']['p50']:7.2f} {r['flash_bytes']:6d} {r['ram_bytes']:5d} "
            f"{r['stack_used_bytes']:5d} {r['emulated_steps_per_s']:9.0f}")


HEADER = (f"{'artifact':34} {'steps':>6} {'mism':>5} {'cyc50':>6} {'cycmax':>6} {'µs@90':>7} {'flash':>6} "
          f"{'RAM':>5} {'stack':>5} {'steps/s':>9}")


def _figures(artifact, result: dict, **extra) -> dict:
    """One firmware check as the record keeps it, with the C28x estimate beside it."""
    cost = step_cost(artifact)
    memory = memory_estimate(artifact, cost)
    keep = ("steps", "mismatches", "cycles", "exec_us_at_90MHz", "flash_bytes", "ram_bytes", "stack_used_bytes",
            "emulated_steps_per_s")
    return {"kind": artifact.kind, "realization": artifact.realization, "dt_s": artifact.dt,
            **{k: result[k] for k in keep}, **extra,
            "c28x_estimate": {"cycles": cost.cycles, "flash_bytes": memory.flash_bytes, "ram_bytes": memory.ram_bytes}}


def packaged_checks(drive, initial) -> list[dict]:
    print("\n1. bench firmware check, packaged artifacts, full 40 °C run")
    print(HEADER)
    out = []
    for kind in PACKAGED_KINDS:
        artifact = load_artifact(default_artifact_path(kind))
        result = check_firmware(artifact, packaged_elf_path(kind), drive, initial)
        print(_row(f"{kind} ({artifact.realization}, {artifact.dt:g} s)", result))
        out.append(_figures(artifact, result))
    return out


def matrix_artifacts():
    """(label, artifact) over kinds x realizations x Δt from the packaged Hammerstein artifact's identification."""
    import numpy as np

    from bench.model.artifact_values import artifact_loss_model, artifact_parameters
    from bench.model.builder import ModelSpec, SigmoidInputs, build_artifact

    reference = load_artifact(default_artifact_path())
    params = artifact_parameters(reference)
    maps, motor = artifact_loss_model(reference)
    sigmoid = SigmoidInputs(*(np.asarray(reference.array("input_nonlinearity", key), dtype=float)
                              for key in ("scale_W", "weight", "bias", "gain", "linear", "offset")))
    for kind in ("lti-lptn", "hammerstein"):
        for realization in REALIZATIONS:
            for dt in DTS:
                spec = ModelSpec(kind, params, dt, "zoh", realization, maps, motor,
                                 sigmoid=sigmoid if kind == "hammerstein" else None)
                yield f"{kind} {realization} {dt:g} s", verify(build_artifact(spec))


def matrix_checks(drive, initial) -> list[dict]:
    print("\n2. bench firmware check, realization x Δt (packaged identification), full 40 °C run")
    print(HEADER)
    out = []
    with tempfile.TemporaryDirectory(prefix="bench-fw-matrix-") as cache:
        for label, artifact in matrix_artifacts():
            started = time.perf_counter()
            elf = firmware_for(artifact, Path(cache))
            built = time.perf_counter() - started
            result = check_firmware(artifact, elf, drive, initial)
            print(_row(label, result) + f"   (built in {built:.1f} s)")
            out.append(_figures(artifact, result, build_s=round(built, 2)))
    return out


def lockstep(dataset, rows: int | None, repeats: int) -> dict:
    from bench.run.execute import run_with_target
    from dbc.transport import BusConfig, resolve

    artifact_path = default_artifact_path()
    artifact = load_artifact(artifact_path)
    drive = drive_matrix(dataset)[:rows] if rows else drive_matrix(dataset)
    print(f"\n3. lockstep throughput, {len(drive)} rows of {dataset.path}, {artifact.kind} {artifact.model_id:08x}, "
          f"load average before {os.getloadavg()[0]:.2f}")
    rates: dict[str, list[float]] = {"python": [], "firmware": []}
    with tempfile.TemporaryDirectory(prefix="bench-fw-lockstep-") as tmp:
        for repeat in range(repeats):
            order = ("firmware", "python") if repeat % 2 == 0 else ("python", "firmware")
            for engine in order:
                bus = resolve(BusConfig("auto"), session_unique=True)
                firmware = packaged_elf_path("hammerstein") if engine == "firmware" else None
                outcome = run_with_target(artifact_path, artifact, bus, drive, initial_temperatures(dataset),
                                          sample_period_s=dataset.sample_period_s,
                                          log_path=Path(tmp) / f"{engine}{repeat}.blf", firmware=firmware)
                r = outcome.result
                rates[engine].append(r.rows_per_s)
                m4 = f", M4 cycles p50 {r.m4_cycles['p50']:.0f}" if r.m4_cycles else ""
                print(f"  {engine:8} run {repeat + 1}: {r.rows_sent} rows in {r.wall_time_s:.2f} s = "
                      f"{r.rows_per_s:.0f} rows/s, missing {r.missing}, round trip p50/p99 "
                      f"{r.round_trip_us['p50']:.0f}/{r.round_trip_us['p99']:.0f} µs, target step p50 "
                      f"{r.step_time_us['p50']:.1f} µs{m4} (load {os.getloadavg()[0]:.2f})")
    for engine, values in rates.items():
        print(f"  {engine:8} median {statistics.median(values):.0f} rows/s (runs: "
              f"{', '.join(f'{v:.0f}' for v in values)})")
    return {"rows": len(drive), "rows_per_s": {engine: [round(v) for v in values] for engine, values in rates.items()},
            "median_rows_per_s": {engine: round(statistics.median(v)) for engine, v in rates.items()}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=None, help="rows of the lockstep runs (default: all)")
    parser.add_argument("--repeats", type=int, default=2, help="lockstep runs per engine (default 2)")
    parser.add_argument("--skip-matrix", action="store_true")
    parser.add_argument("--skip-lockstep", action="store_true")
    parser.add_argument("--data", type=Path, default=ROOT / "out" / "data")
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("firmware", args, parameters={"rows": args.rows, "repeats": args.repeats,
                                                  "matrix": not args.skip_matrix, "lockstep": not args.skip_lockstep})
    dataset = load_dataset(ensure_default_datasets(args.data)[40])
    drive, initial = drive_matrix(dataset), initial_temperatures(dataset)
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; {len(drive)} rows of "
          f"{dataset.path}")
    record.parameters["data_rows"] = len(drive)
    record.figures["packaged"] = packaged_checks(drive, initial)
    if not args.skip_matrix:
        record.figures["matrix"] = matrix_checks(drive, initial)
    if not args.skip_lockstep:
        record.figures["lockstep"] = lockstep(dataset, args.rows, args.repeats)
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
