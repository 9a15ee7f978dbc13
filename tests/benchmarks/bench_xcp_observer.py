"""Benchmark (not a test): what serving an observer's XCP cells costs the firmware node, in emulated Cortex-M4F
cycles (which the machine's load does not change), against a baseline revision's firmware of the same artifact.

    python tests/benchmarks/bench_xcp_observer.py --model OBSERVER.json [--rows N] [--baseline REV]

The committed record's observer: the packaged Hammerstein model with a lagged winding sensor and the winding
heat-bias state (six filter states, UD form), `bench observer --train SMALL.csv --evaluations 2 --lag 60 --bias`
on the tests' synthetic dataset (tests/conftest.py's small_dataset), as tests/target_sim/test_xcp_firmware.py's
slow case makes it.

For the observer artifact's firmware (built from this checkout's sources, and with --baseline from REV's own
sources, `git archive`): the ELF's sections; a lockstep session of --rows rows (default 300) with a winding sensor
1.5 K warm of the open loop (ABSENT every 7th row) and a DAQ list of three ODTs on the model step (the observer's
1-sigma, innovation, sensor offset and Q where the firmware serves them, else the model's outputs): the model step's
cycles (Timing4) and the DAQ sample's; the cycles of node_on_xcp for SHORT_UPLOAD and DOWNLOAD of the cells the
firmware serves; and the IPET WCET bounds of the timing image (`bench firmware timing`'s tool) of fw_obs_step,
fw_obs_sigma, fw_obs_report, node_on_frame, node_on_tick, node_on_xcp and xcp_event, without an XCP master and with
the DAQ tables full. Writes its record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

TIMED = ("fw_obs_step", "fw_obs_sigma", "fw_obs_report", "node_on_frame", "node_on_tick", "node_on_xcp",
         "xcp_event")
DAQ_FULL = (16, 16)        # the DAQ tables' budget (target_sim.xcp.daq): lists, ODTs


def u32(value: int) -> bytes:
    return struct.pack("<I", value)


def figures(path: Path, rows: int) -> dict:
    """This checkout's figures for the observer artifact at `path` (see the module docstring)."""
    import can
    import numpy as np

    from bench.firmware.images import firmware_for
    from bench.firmware.timing import timing_sources
    from dbc.database import host_frame_ids
    from dbc.xcp import cmd_id
    from target_sim.artifact import load_artifact
    from target_sim.firmware.elf import memory_from_elf, read_elf
    from target_sim.firmware.node_engine import FirmwareNode, cycle_figures
    from target_sim.firmware.wcet import WcetError, loop_facts, wcet
    from target_sim.model import run_offline
    from target_sim.node import TargetNode

    from helpers import SESSION_INITIAL, session_drive, session_frames

    artifact = load_artifact(path)
    with tempfile.TemporaryDirectory() as cache:
        elf = firmware_for(artifact, Path(cache))
        timing_image = read_elf(firmware_for(artifact, Path(cache), isr=True))
        out: dict = {"sections": memory_from_elf(elf)["sections"]}
        node = FirmwareNode(artifact, elf)
        cells = TargetNode(artifact, xcp_elf=elf).xcp.memory.by_name

    def send(cto: bytes) -> bytes:
        replies = node.handle(can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=cto))
        return bytes(replies[0].data) if replies else b""

    send(bytes((0xFF, 0)))
    served = {name for name, cell in cells.items() if cell.symbol is not None}
    commands = {f"SHORT_UPLOAD {name}": ((), bytes((0xF4, 4, 0, 0)) + u32(cells[name].address))
                for name in ("x_state_0", "obs_sigma_3") if name in served}
    for name in ("cal_alpha_cu", "cal_sensor0_offset"):
        if name in served:
            commands[f"DOWNLOAD {name}"] = ((bytes((0xF6, 0, 0, 0)) + u32(cells[name].address),),
                                            bytes((0xF0, 4)) + struct.pack("<f", cells[name].read()))
    handlers = {}
    for name, (before, cto) in commands.items():
        counted: Counter[int] = Counter()
        for _ in range(50):
            for setup in before:
                send(setup)
            seen = node.xcp_cycles.copy()
            assert send(cto)[0] == 0xFF, name
            counted += node.xcp_cycles - seen
        handlers[name] = cycle_figures(counted)
    out["handler_cycles"] = handlers
    observer_odts = [[("obs_sigma_1", 4), ("obs_innov_0", 3)], [("cal_sensor0_offset", 4), ("cal_q_1", 3)],
                     [("obs_sigma_3", 4)]]
    odts = observer_odts if "obs_sigma_1" in served else [[("y_est_0", 4), ("y_est_1", 3)], [("estimate_2", 4)],
                                                          [("x_state_3", 4)]]
    out["daq_entries"] = [[name for name, _ in entries] for entries in odts]
    for cto in (bytes((0xD6,)), bytes((0xD5, 0, 1, 0)), bytes((0xD4, 0, 0, 0, len(odts)))):
        send(cto)
    for k, entries in enumerate(odts):
        send(bytes((0xD3, 0, 0, 0, k, len(entries))))
        send(bytes((0xE2, 0, 0, 0, k, 0)))
        for name, size in entries:
            assert send(bytes((0xE1, 0xFF, size, 0)) + u32(cells[name].address))[0] == 0xFF, name
    send(bytes((0xE0, 0, 0, 0, 0, 0, 1, 0)))
    assert send(bytes((0xDE, 1, 0, 0)))[0] == 0xFF
    drive = session_drive(rows, 8)
    steps, open_loop = run_offline(artifact, drive, SESSION_INITIAL)
    sensor = np.round(np.interp(np.arange(rows), steps, open_loop[:, 1]) + 1.5, 2)
    sensor[::7] = np.nan
    measured = np.column_stack([sensor, np.full(rows, np.nan)])
    for frame in session_frames(artifact, drive, stop=False, measurements=measured):
        if frame.arbitration_id in host_frame_ids():
            node.handle(frame)
    out.update({"model_steps": node.model_steps, "model_step_cycles": cycle_figures(node.m4_cycles),
                "daq_sample_cycles": cycle_figures(node.xcp_sample_cycles)})
    sources = timing_sources(artifact)
    for key, facts in (("wcet_cycles", lambda: loop_facts(sources, 0)),
                       ("wcet_cycles_daq", lambda: loop_facts(sources, 0, daq=DAQ_FULL))):
        out[key] = {}
        for name in TIMED:
            if name in timing_image.symbols:
                try:
                    out[key][name] = wcet(timing_image, name, facts()).cycles
                except WcetError as exc:       # a loop without a stated bound: no bound, said why
                    out[key][name] = f"no bound: {str(exc)[:160]}"
    return out


def baseline_figures(rev: str, model: Path, rows: int) -> dict:
    """The same figures of revision `rev`'s firmware, from its own sources (git archive), by this script."""
    with tempfile.TemporaryDirectory() as work:
        archive = Path(work) / "rev.tar"
        with archive.open("wb") as out:
            subprocess.run(["git", "archive", rev], cwd=ROOT, stdout=out, check=True, timeout=300)
        tree = Path(work) / "tree"
        tree.mkdir()
        subprocess.run(["tar", "-xf", str(archive), "-C", str(tree)], check=True, timeout=300)
        script = tree / "tests" / "benchmarks" / Path(__file__).name
        script.write_text(Path(__file__).read_text(encoding="utf-8"), encoding="utf-8")
        done = subprocess.run([sys.executable, str(script), "--model", str(model.resolve()), "--rows", str(rows),
                               "--inner"], cwd=tree, capture_output=True, text=True, timeout=3600,
                              env={**os.environ, "PYTHONPATH": str(tree)})
        if done.returncode != 0:
            raise RuntimeError(f"the figures of {rev} failed: {done.stderr.strip()[-400:]}")
        return {"revision": rev, **json.loads(done.stdout)}


def main() -> int:
    from record import Record, add_record_arguments

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, required=True, help="an observer model artifact (bench observer)")
    parser.add_argument("--rows", type=int, default=300, help="rows of the lockstep session (default 300)")
    parser.add_argument("--baseline", default=None, metavar="REV", help="a git revision to compare with")
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)   # a baseline tree's figures, JSON
    add_record_arguments(parser)
    args = parser.parse_args()
    if not args.model.is_file():
        print(f"error: {args.model} is not a file", file=sys.stderr)
        return 2
    if args.inner:
        json.dump(figures(args.model, args.rows), sys.stdout)
        return 0
    record = Record("xcp_observer", args, parameters={"model": args.model.name, "rows": args.rows})
    record.figures = figures(args.model, args.rows)
    if args.baseline:
        base = baseline_figures(args.baseline, args.model, args.rows)
        record.figures["baseline"] = base
        record.figures["added_sections"] = {k: record.figures["sections"].get(k, 0) - base["sections"].get(k, 0)
                                            for k in sorted(set(record.figures["sections"]) | set(base["sections"]))}
    print(json.dumps(record.figures, indent=1))
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
