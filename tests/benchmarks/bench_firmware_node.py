"""Firmware node benchmark (prints figures; not a test): the CAN node in C against the Python reference node.

    python tests/benchmarks/bench_firmware_node.py [--rows N] [--repeats R] [--skip-lockstep]

1. Byte identity over the full 40 °C run in-process: the host's frames of a whole session (RESET, START, every
   row; 36 371 rows, 14 548 model steps) into the Python node and into the firmware node; every frame each sends
   compared byte for byte (Status, RxErrors, Temperatures, StateCheckpoint: alive counters and CRCs included;
   Timing1-4 carry measured times and TargetInfo the ELF's figures, so they are compared by id only).
2. The same under the fault sweep's frame faults: each frame kind of `dbc.mutations` (drop, duplicate, corrupt,
   stale_counter, wrong_length, unknown_id, out_of_range) at 1 % on the drive frames, seeded; the same faulted
   stream into both nodes; replies and the RxErrors counts compared.
3. Lockstep throughput of `bench run --engine firmware` and `--engine python` over a real cross-process bus,
   alternating (R runs each), rows/s as the host measures; the firmware node's cycles per received frame and per
   reply from its statistics. Goal: >= 2 000 rows/s with the firmware node.
Writes its record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
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
from bench.firmware.images import packaged_elf_path  # noqa: E402
from bench.model.default import default_artifact_path  # noqa: E402
from dbc.codec import FrameCodec  # noqa: E402
from dbc.contract import Command  # noqa: E402
from dbc.database import frame_id  # noqa: E402
from dbc.mutations import FRAME_FAULT_KINDS, mutate, pick, unit  # noqa: E402
from target_sim.artifact import load_artifact  # noqa: E402
from target_sim.firmware.node_engine import FirmwareNode  # noqa: E402
from target_sim.node import TargetNode  # noqa: E402

MEASURED = {frame_id(name) for name in ("Timing1", "Timing2", "Timing3", "Timing4", "TargetInfo")}
TIMING4 = frame_id("Timing4")


def session_frames(drive, rows: int, faults: float = 0.0, seed: int = 1) -> list:
    """The host's frames of a session over `rows` rows, each drive frame faulted at rate `faults` per kind."""
    host = FrameCodec("HOST")
    frames = [host.encode("ResetTemps1", {"Step": 0, "WindingTempInit": 40.0, "MagnetTempInit": 40.5}),
              host.encode("ResetTemps2", {"Step": 0, "YokeTempInit": 39.5, "ToothTempInit": 40.2}),
              host.encode("Control", {"Step": 0, "Command": int(Command.RESET)}),
              host.encode("Control", {"Step": 0, "Command": int(Command.START)})]
    rates = [(kind, faults) for kind in FRAME_FAULT_KINDS] if faults else []
    for row in range(rows):
        torque, speed, coolant, ambient = (float(v) for v in drive[row])
        step = row % 65536
        for index, msg in enumerate((
                host.encode("DriveInputs", {"Step": step, "MotorTorque": torque, "MotorSpeed": speed}),
                host.encode("DriveTemps", {"Step": step, "CoolantTemp": coolant, "AmbientTemp": ambient}))):
            kind = pick(unit(seed, row, index), rates) if rates else None
            frames += mutate(kind, msg, lambda k, r=row, i=index: unit(seed + 1, r, i, k)) if kind else [msg]
    return frames


def compare(artifact, elf, frames) -> dict:
    """Feed `frames` to both nodes; counts of compared and differing replies, and the two nodes' stats."""
    python, firmware = TargetNode(artifact), FirmwareNode(artifact, elf)
    got_p, got_f = python.startup_frames(), firmware.startup_frames()
    calls = mismatches = compared = 0
    first = None
    started = time.perf_counter()
    for msg in frames:
        calls += 1
        a, b = python.handle(msg), firmware.handle(msg)
        ka = [(f.arbitration_id, bytes(f.data) if f.arbitration_id not in MEASURED else b"") for f in a]
        kb = [(f.arbitration_id, bytes(f.data) if f.arbitration_id not in MEASURED else b"") for f in b
              if f.arbitration_id != TIMING4]
        compared += len(ka)
        if ka != kb:
            mismatches += 1
            first = first or (calls, ka, kb)
    for _ in range(3):     # heartbeats: Status and RxErrors after everything
        hp, hf = python.heartbeat_frames(), firmware.heartbeat_frames()
        if [(f.arbitration_id, bytes(f.data)) for f in hp] != [(f.arbitration_id, bytes(f.data)) for f in hf]:
            mismatches += 1
    return {"frames_in": calls, "frames_compared": compared, "mismatching_calls": mismatches, "first": first,
            "seconds": time.perf_counter() - started, "python": python.stats(), "firmware": firmware.stats(),
            "startup_equal_but_target_info": [(f.arbitration_id, bytes(f.data)) for f in got_p[1:]]
            == [(f.arbitration_id, bytes(f.data)) for f in got_f[1:]]}


def lockstep(engine: str, data: Path, out: Path) -> dict:
    env = dict(os.environ, MPLBACKEND="Agg")
    done = subprocess.run([sys.executable, "-m", "bench", "run", "--engine", engine, "--data", str(data),
                           "--log", str(out / f"{engine}.blf"), "--no-report", "--json", "--quiet"],
                          capture_output=True, text=True, env=env, cwd=ROOT)
    result = json.loads(done.stdout) if done.stdout.strip().startswith("{") else {}
    return {"rc": done.returncode, "rows_per_s": result.get("throughput_steps_per_s"), "clean": result.get("clean"),
            "m4_cycles": result.get("m4_cycles"), "flash": result.get("flash_bytes"), "ram": result.get("ram_bytes")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=None)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--skip-lockstep", action="store_true")
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("firmware_node", args, parameters={"rows": args.rows, "repeats": args.repeats,
                                                       "lockstep": not args.skip_lockstep})
    data = ensure_default_datasets(ROOT / "out" / "data")[40]
    dataset = load_dataset(data)
    drive = dataset.drive_inputs()
    rows = args.rows or len(drive)
    artifact = load_artifact(default_artifact_path("hammerstein"))
    elf = packaged_elf_path("hammerstein")
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; {rows} rows of {data}")

    print("\n1. byte identity, clean session, in-process")
    result = compare(artifact, elf, session_frames(drive, rows))
    fw = result["firmware"]
    print(f"  {result['frames_in']} frames in, {result['frames_compared']} reply frames compared, "
          f"{result['mismatching_calls']} calls with differing replies; model steps {fw['model_steps']}; "
          f"startup frames equal but TargetInfo: {result['startup_equal_but_target_info']}; "
          f"{result['seconds']:.1f} s for both nodes")
    print(f"  firmware node: M4 cycles per model step p50/max {fw['m4_cycles']['p50']}/{fw['m4_cycles']['max']}, "
          f"per received frame (model steps excluded) p50/max {fw['frame_cycles']['p50']}/"
          f"{fw['frame_cycles']['max']}, per reply frame p50/max {fw['reply_cycles']['p50']}/"
          f"{fw['reply_cycles']['max']}; flash {fw['flash_bytes']} B, RAM {fw['ram_bytes']} B, "
          f"stack used {fw['stack_used_bytes']} B; tx dropped {fw['tx_dropped']}")
    if result["first"]:
        print("  first difference:", result["first"])
    record.parameters["session_rows"] = rows
    record.figures["identity"] = {
        "frames_in": result["frames_in"], "frames_compared": result["frames_compared"],
        "mismatching_calls": result["mismatching_calls"], "model_steps": fw["model_steps"],
        "startup_equal_but_target_info": result["startup_equal_but_target_info"],
        "m4_cycles": fw["m4_cycles"], "frame_cycles": fw["frame_cycles"], "reply_cycles": fw["reply_cycles"],
        "flash_bytes": fw["flash_bytes"], "ram_bytes": fw["ram_bytes"], "stack_used_bytes": fw["stack_used_bytes"],
        "tx_dropped": fw["tx_dropped"]}
    record.figures["faults"] = []

    print("\n2. byte identity under frame faults (each kind at 1 % of the drive frames), in-process")
    for seed in (1, 2, 3):
        result = compare(artifact, elf, session_frames(drive, min(rows, 12000), faults=0.01, seed=seed))
        errors_p, errors_f = result["python"]["errors"], result["firmware"]["errors"]
        print(f"  seed {seed}: {result['frames_in']} frames, {result['frames_compared']} replies compared, "
              f"{result['mismatching_calls']} differing; rx errors equal {errors_p == errors_f}: {errors_f}")
        record.figures["faults"].append({"seed": seed, "rate": 0.01, "frames_in": result["frames_in"],
                                         "frames_compared": result["frames_compared"],
                                         "mismatching_calls": result["mismatching_calls"],
                                         "rx_errors_equal": errors_p == errors_f})

    if args.skip_lockstep:
        record.write()
        return 0
    print("\n3. lockstep throughput over the bus, alternating")
    figures: dict[str, list[float]] = {"firmware": [], "python": []}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for engine in ("firmware", "python") if repeat % 2 == 0 else ("python", "firmware"):
                run = lockstep(engine, data, Path(tmp))
                figures[engine].append(run["rows_per_s"] or 0.0)
                print(f"  {engine:8s} run {repeat + 1}: {run['rows_per_s'] or 0:.0f} rows/s, clean {run['clean']}, "
                      f"exit {run['rc']}, M4 cycles {run['m4_cycles']}, flash/RAM {run['flash']}/{run['ram']} B")
    for engine, values in figures.items():
        print(f"  {engine:8s} median {statistics.median(values):.0f} rows/s (runs: "
              f"{', '.join(f'{v:.0f}' for v in values)})")
    record.figures["lockstep"] = {
        "rows_per_s": {engine: [round(v) for v in values] for engine, values in figures.items()},
        "median_rows_per_s": {engine: round(statistics.median(v)) for engine, v in figures.items()}}
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
