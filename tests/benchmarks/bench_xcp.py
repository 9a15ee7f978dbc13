"""Benchmark (not a test): what the XCP slave costs the model step's deadline, in the Python node and in the firmware.

    python tests/benchmarks/bench_xcp.py [--model A] [--rows N] [--repeat N] [--baseline REV]
                                         [--daq-run [--run-rows N] [--mf4 PATH]]

In-process (no bus, so only the node's own work counts): the packaged model's Python node (or --model), connected,
with a DAQ list of the four temperatures (one ODT each, on the model step's event). Figures: the handler time of each
command kind (SHORT_UPLOAD of a float, SET_MTA + DOWNLOAD of a calibration, BUILD_CHECKSUM of the 32 bytes of x
and y, GET_STATUS), --repeat times each; the DAQ sampling time per model step over a lockstep session of
--rows rows; the model step's own time in the same session with and without the DAQ list; and the model step's
period Δt, the deadline each figure is measured against (XCP commands run between frames, DAQ after the step's
replies, so neither enters the step itself).

The firmware node's C slave (bench/firmware/xcp.c), the packaged model's shipped ELF in the emulated Cortex-M4F
(cycles, which the machine's load does not change): the cycles of node_on_frame for each of the same commands
(--repeat // 10 times each), and of a DAQ sample of the same four ODTs (the firmware's DWT reads around it) over
the same session; the IPET WCET bounds (`bench.firmware.timing`'s tool, rows in order) of its timing image, without
an XCP master (`bench.firmware.timing.XCP_MODES`' no_master: no DAQ list, and the globals the C's
`wcet-value(no_master)` facts fix keep their power-on values, so the master's paths are infeasible, as
`bench firmware timing` bounds a drive) and with the DAQ tables full (16 lists, 16 ODTs of 7 bytes): the model step
(fw_step), node_on_frame (a data row with its model step and DAQ sample), node_on_tick (the heartbeat with the time
event's DAQ), node_on_xcp (an XCP command) and xcp_event (a DAQ sample); and the ELF's sections. With
--baseline REV (a git revision; default the last one without the C slave) the same bounds and sections of that
revision's firmware, built from its own sources (`git archive`), beside them: what the slave added.

With --daq-run (pyxcp needed) it also records a whole run by DAQ: a target process on a private udp_multicast bus,
pyxcp as the master with a DAQ list of the four temperatures on the model step's event, and `bench host` replaying
the 40 °C validation run (out/data, generated if missing; --run-rows N: its first N rows) in lockstep with its log;
figures: model steps, DAQ packets per ODT, packets lost (steps minus packets), the largest |DAQ value − the row's CAN
reply| (the replies carry 0.01 °C), and whether `bench host` judged the run clean; with --mf4 PATH the recording is
also written there as an MF4 (`bench.daqrecord`, asammdf) and read back (`mf4_equal_to_daq`). Writes its record
(`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import struct
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from record import Record, add_record_arguments, percentiles  # noqa: E402


def _us(ns_values) -> dict:
    return {k: (None if v is None else round(v / 1000.0, 2)) for k, v in percentiles(ns_values).items()}


def session(node, rows: int, daq: bool) -> list[int]:
    """Drive a lockstep session through `node`; the model step times (ns) it measured."""
    from dbc import FrameCodec
    from host.replay import encode_row

    from helpers import session_drive, session_start

    slave = node.xcp
    slave.command(bytes((0xFF, 0)))
    if daq:
        cells = slave.memory.by_name
        for cto in (bytes((0xD6,)), bytes((0xD5, 0, 1, 0)), bytes((0xD4, 0, 0, 0, 4))):
            assert slave.command(cto) == b"\xff"
        for odt in range(4):
            assert slave.command(bytes((0xD3, 0, 0, 0, odt, 1))) == b"\xff"
            assert slave.command(bytes((0xE2, 0, 0, 0, odt, 0))) == b"\xff"
            entry = bytes((0xE1, 0xFF, 4, 0)) + struct.pack("<I", cells[f"y_est_{odt}"].address)
            assert slave.command(entry) == b"\xff"
        assert slave.command(bytes((0xE0, 0, 0, 0, 0, 0, 1, 0))) == b"\xff"
        assert slave.command(bytes((0xDE, 1, 0, 0)))[0] == 0xFF
    codec = FrameCodec("HOST")
    for frame in session_start(codec):
        node.handle(frame)
    steps: list[int] = []
    for row, values in enumerate(session_drive(rows, 4)):
        before = node.model_steps
        started = time.perf_counter_ns()
        for frame in encode_row(codec, row, values):
            node.handle(frame)
        if node.model_steps > before:
            steps.append(time.perf_counter_ns() - started)
    return steps


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=None, help="model artifact (default: the packaged one)")
    parser.add_argument("--rows", type=int, default=6000, help="rows of the lockstep session (default 6000)")
    parser.add_argument("--repeat", type=int, default=5000, help="calls of each command (default 5000)")
    parser.add_argument("--daq-run", action="store_true", help="also record a whole run by DAQ with pyxcp")
    parser.add_argument("--baseline", default=BASELINE, metavar="REV",
                        help=f"the git revision whose firmware is the baseline (default {BASELINE}: the last "
                             "without the C slave; '' for none)")
    parser.add_argument("--run-rows", type=int, default=None, help="with --daq-run: only the first N rows")
    parser.add_argument("--mf4", type=Path, default=None,
                        help="with --daq-run: also write the recording to this .mf4 (bench.daqrecord; asammdf)")
    add_record_arguments(parser)
    args = parser.parse_args()
    from bench.model.default import default_artifact_path
    from target_sim.artifact import load_artifact
    from target_sim.node import TargetNode

    path = args.model or default_artifact_path()
    artifact = load_artifact(path)
    record = Record("xcp", args, parameters={"model": path.name, "rows": args.rows, "repeat": args.repeat})
    node = TargetNode(artifact)
    slave, cells = node.xcp, node.xcp.memory.by_name
    slave.command(bytes((0xFF, 0)))
    x0, alpha = cells["x_state_0"].address, cells["cal_alpha_cu"].address
    commands = {"SHORT_UPLOAD float": [bytes((0xF4, 4, 0, 0)) + struct.pack("<I", x0)],
                "SET_MTA + DOWNLOAD float": [bytes((0xF6, 0, 0, 0)) + struct.pack("<I", alpha),
                                             bytes((0xF0, 4)) + struct.pack("<f", float(node.model.alpha_cu))],
                "BUILD_CHECKSUM 32 bytes": [bytes((0xF6, 0, 0, 0)) + struct.pack("<I", x0),
                                            bytes((0xF3, 0, 0, 0)) + struct.pack("<I", 32)],
                "GET_STATUS": [bytes((0xFD,))]}
    handlers = {}
    for name, ctos in commands.items():
        slave.handler_ns.clear()
        for _ in range(args.repeat):
            for cto in ctos:
                assert slave.command(cto)[0] == 0xFF, name
        handlers[name] = _us(slave.handler_ns)
    plain = session(TargetNode(artifact), args.rows, daq=False)
    with_daq_node = TargetNode(artifact)
    with_daq = session(with_daq_node, args.rows, daq=True)
    record.figures = {"dt_us": round(artifact.dt * 1e6), "handler_us": handlers,
                      "daq_sample_us": _us(with_daq_node.xcp.sample_ns),
                      "daq_packets": with_daq_node.xcp.daq.packets, "model_steps": with_daq_node.model_steps,
                      "row_with_step_us": {"without_daq": _us(plain), "with_daq": _us(with_daq)}}
    worst = max(v["max"] for v in handlers.values())
    print(f"model step period {artifact.dt * 1e3:g} ms; XCP handler p50/max (µs): "
          + ", ".join(f"{k} {v['p50']}/{v['max']}" for k, v in handlers.items()))
    print(f"DAQ sample (4 ODTs) p50/max {record.figures['daq_sample_us']['p50']}/"
          f"{record.figures['daq_sample_us']['max']} µs, {with_daq_node.xcp.daq.packets} packets for "
          f"{with_daq_node.model_steps} model steps; worst command {worst} µs = "
          f"{100 * worst / (artifact.dt * 1e6):.4f} % of the period")
    if path.resolve() == default_artifact_path().resolve():
        record.figures["firmware"] = firmware_figures(artifact, args.rows, max(1, args.repeat // 10),
                                                      args.baseline or None)
        fw = record.figures["firmware"]
        print(f"firmware: handler cycles p50/max {fw['handler_cycles']}; DAQ sample {fw['daq_sample_cycles']}; "
              f"WCET {fw['wcet_cycles']}; sections {fw['sections']}; baseline {fw.get('baseline')}")
    if args.daq_run:
        record.figures["daq_run"] = daq_run(artifact, path, args.run_rows, args.mf4)
        print(f"DAQ run: {record.figures['daq_run']}")
    record.write()
    return 0


BASELINE = "d7017f8"      # the last revision whose firmware node has no XCP slave
TIMED = ("fw_step", "node_on_frame", "node_on_tick", "node_on_xcp", "xcp_event")


def _bounds_script(timed: tuple[str, ...]) -> str:
    """What a checkout runs to give its packaged model's shipped ELF sections and its timing image's WCET bounds in
    `bench firmware timing`'s XCP modes (`bench.firmware.timing.static_bounds`): without an XCP master (the C's
    `wcet-value(no_master)` facts: the master's paths infeasible, as a drive runs) and with the DAQ tables full. A
    revision older than the modes: its loop facts alone, without a master's DAQ lists, and with them when it has
    the slave."""
    from target_sim.xcp.daq import MAX_DAQ_LISTS, MAX_ODTS

    daq = (MAX_DAQ_LISTS, MAX_ODTS)
    return f"""
import json, sys, tempfile
from pathlib import Path
from bench.firmware.images import firmware_for, packaged_elf
from bench.firmware import timing
from bench.model.default import default_artifact_path
from target_sim.artifact import load_artifact
from target_sim.firmware.elf import memory_from_elf, read_elf
from target_sim.firmware.wcet import loop_facts, wcet
artifact = load_artifact(default_artifact_path())
with tempfile.TemporaryDirectory() as cache:
    image = read_elf(firmware_for(artifact, Path(cache), isr=True))
timed = tuple(name for name in {timed!r} if name in image.symbols)
out = {{"sections": memory_from_elf(packaged_elf(artifact))["sections"]}}
if hasattr(timing, "XCP_MODES"):
    for key, mode in (("wcet_cycles", timing.DRIVE_MODE), ("wcet_cycles_daq", timing.DAQ_MODE)):
        out[key] = timing.static_bounds(image, artifact, mode=mode, functions=timed)
else:
    sources = timing.timing_sources(artifact)
    for key, facts in (("wcet_cycles", lambda: loop_facts(sources, 0)),
                       ("wcet_cycles_daq", lambda: loop_facts(sources, 0, daq={daq!r}))):
        try:
            out[key] = {{name: wcet(image, name, facts()).cycles for name in timed}}
        except TypeError:        # a revision without the XCP slave: no DAQ to bound
            pass
json.dump(out, sys.stdout)
"""


def _checkout_figures(tree: Path) -> dict:
    import json
    import subprocess

    done = subprocess.run([sys.executable, "-c", _bounds_script(TIMED)], cwd=tree, capture_output=True, text=True,
                          timeout=1800, env={**__import__("os").environ, "PYTHONPATH": str(tree)})
    if done.returncode != 0:
        raise RuntimeError(f"the bounds of {tree} failed: {done.stderr.strip()[-400:]}")
    return json.loads(done.stdout)


def baseline_figures(rev: str) -> dict:
    """The sections and WCET bounds of revision `rev`'s firmware, from its own sources (git archive)."""
    import subprocess
    import tarfile
    import tempfile

    with tempfile.TemporaryDirectory() as work:
        archive = Path(work) / "rev.tar"
        with archive.open("wb") as out:
            subprocess.run(["git", "archive", rev], cwd=ROOT, stdout=out, check=True, timeout=300)
        tree = Path(work) / "tree"
        with tarfile.open(archive) as tar:
            tar.extractall(tree, filter="data")
        return {"revision": rev, **_checkout_figures(tree)}


def firmware_figures(artifact, rows: int, repeat: int, baseline: str | None) -> dict:
    """The C slave's cycles, bounds and memory (see the module docstring)."""
    from collections import Counter

    import can

    from bench.firmware.images import packaged_elf
    from dbc.xcp import cmd_id
    from target_sim.firmware.node_engine import FirmwareNode, cycle_figures
    from target_sim.node import TargetNode

    elf = packaged_elf(artifact)
    node = FirmwareNode(artifact, elf)
    cells = TargetNode(artifact, xcp_elf=elf).xcp.memory.by_name       # the A2L's addresses of this ELF
    x0, alpha = cells["x_state_0"].address, cells["cal_alpha_cu"].address

    def send(cto: bytes) -> list:
        return node.handle(can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=cto))

    send(bytes((0xFF, 0)))
    set_mta = {name: bytes((0xF6, 0, 0, 0)) + struct.pack("<I", address) for name, address in (("x", x0),
                                                                                                 ("alpha", alpha))}
    # per kind: the commands sent before it (not counted), then the command counted
    commands = {"SHORT_UPLOAD float": ((), bytes((0xF4, 4, 0, 0)) + struct.pack("<I", x0)),
                "SET_MTA": ((), set_mta["alpha"]),
                "DOWNLOAD float": ((set_mta["alpha"],), bytes((0xF0, 4)) + struct.pack("<f", artifact_alpha(artifact))),
                "BUILD_CHECKSUM 32 bytes": ((set_mta["x"],), bytes((0xF3, 0, 0, 0)) + struct.pack("<I", 32)),
                "GET_STATUS": ((), bytes((0xFD,)))}
    handlers = {}
    for name, (before, cto) in commands.items():
        counted: Counter[int] = Counter()
        for _ in range(repeat):
            for setup in before:
                send(setup)
            seen = node.xcp_cycles.copy()
            assert bytes(send(cto)[0].data)[0] == 0xFF, name
            counted += node.xcp_cycles - seen
        handlers[name] = cycle_figures(counted)
    session(_FirmwareAsPython(node, cells), rows, daq=True)
    figures = {"elf": elf.name, "handler_cycles": handlers, "daq_sample_cycles": cycle_figures(node.xcp_sample_cycles),
               "daq_packets": node.xcp_stats()["daq_packets"], "model_steps": node.model_steps,
               "model_step_cycles": cycle_figures(node.m4_cycles)}
    figures.update(_checkout_figures(ROOT))
    if baseline:
        base = baseline_figures(baseline)
        figures["baseline"] = base
        figures["added"] = {
            "sections": {k: figures["sections"].get(k, 0) - base["sections"].get(k, 0)
                         for k in sorted(set(figures["sections"]) | set(base["sections"]))},
            "wcet_cycles": {k: figures["wcet_cycles"][k] - base["wcet_cycles"][k]
                            for k in figures["wcet_cycles"] if k in base["wcet_cycles"]},
            "wcet_cycles_daq": {k: figures["wcet_cycles_daq"][k] - base["wcet_cycles"][k]
                                for k in figures["wcet_cycles_daq"] if k in base["wcet_cycles"]}}
    return figures


def artifact_alpha(artifact) -> float:
    from target_sim.model import Float32Estimator

    return float(Float32Estimator(artifact).alpha_cu)


class _FirmwareAsPython:
    """The firmware node behind `session`'s interface (an `xcp.command` and `xcp.memory.by_name` like the Python
    slave's), so the DAQ session drives both engines alike."""

    def __init__(self, node, cells):
        from dbc.xcp import cmd_id

        self._node, self._cmd = node, cmd_id()
        self.xcp = self
        self.memory = self
        self.by_name = cells

    def command(self, cto: bytes) -> bytes | None:
        import can

        replies = self._node.handle(can.Message(arbitration_id=self._cmd, is_extended_id=False, data=cto))
        return bytes(replies[0].data) if replies else None

    def handle(self, frame):
        return self._node.handle(frame)

    @property
    def model_steps(self) -> int:
        return self._node.model_steps


def daq_run(artifact, model_path: Path, rows: int | None, mf4: Path | None = None) -> dict:
    """A whole run recorded by DAQ (see the module docstring)."""
    import subprocess
    import tempfile

    import can
    import numpy as np
    from pyxcp.config import create_application_from_config
    from pyxcp.master import Master

    from bench.analysis.logdecode import decode_log
    from bench.daqrecord import DaqRecorder, configure_daq, daq_channels, write_daq_mf4
    from bench.drive.generate import ensure_default_datasets
    from dbc.transport import BusConfig, resolve
    from dbc.xcp import cmd_id, res_id
    from target_sim.model import InputAccumulator

    from helpers import start_target

    data = ensure_default_datasets()[40]
    config = resolve(BusConfig("udp_multicast"), session_unique=True)
    channels = daq_channels(artifact, [f"y_est_{odt}" for odt in range(4)])
    with start_target("--model", model_path, "--quiet", *config.to_argv()):   # stopped when the block ends
        bus = config.open()
        try:
            deadline = time.monotonic() + 60
            while True:
                msg = bus.recv(0.5)
                if msg is not None and msg.arbitration_id == 0x230:
                    break
                assert time.monotonic() < deadline, "no heartbeat from the target"
            app = create_application_from_config({"Transport": {"CAN": {
                "interface": "udp_multicast", "channel": config.channel, "can_id_master": cmd_id(),
                "can_id_slave": res_id()}}})
            app.transport.layer = "CAN"
            app.transport.can.udp_multicast.port = config.kwargs["port"]
            app.general.disable_error_handling = True
            with tempfile.TemporaryDirectory() as work, Master("can", config=app) as xcp:
                xcp.connect()
                recorder = DaqRecorder(configure_daq(xcp, channels), len(channels))
                notifier = can.Notifier(bus, [recorder])
                xcp.startStopSynch(0x01)
                log = Path(work) / "run.blf"
                host = subprocess.run([sys.executable, "-m", "bench", "host", "--data", str(data), "--model",
                                       str(model_path), "--log", str(log), "--quiet",
                                       *(["--rows", str(rows)] if rows else []), *config.to_argv()],
                                      cwd=ROOT, capture_output=True, text=True, timeout=7200)
                time.sleep(1.0)
                xcp.startStopSynch(0x00)
                xcp.disconnect()
                time.sleep(0.5)
                notifier.stop()
                record = decode_log(log)
                samples = recorder.samples()
                if mf4 is not None:
                    write_daq_mf4(mf4, channels, samples)
        finally:
            bus.shutdown()
    accumulator = InputAccumulator(artifact.data_sample_period, artifact.dt)
    step_rows = [row for row in range(record.rows) if accumulator.ends_interval(row)]
    # y_est: yoke, winding, tooth, magnet; record.temps has the same order
    values = samples.values
    worst = (float(np.max(np.abs(values - record.temps[step_rows, :4]))) if len(values) == len(step_rows)
             else float("nan"))
    figures = {"rows": int(record.rows), "model_steps": len(step_rows), "daq_samples": len(values),
               "daq_packets_per_odt": [int(n) for n in np.sum(~np.isnan(values), axis=0)],
               "lost": len(step_rows) * len(channels) - int(np.sum(~np.isnan(values))),
               "max_abs_daq_minus_can_C": round(worst, 6),
               "host_exit": host.returncode, "host_stderr": host.stderr.strip()[-300:]}
    if mf4 is not None:
        from asammdf import MDF

        mdf = MDF(str(mf4))
        try:
            figures["mf4_equal_to_daq"] = all(np.array_equal(mdf.get(c.name).samples, values[:, i], equal_nan=True)
                                              for i, c in enumerate(channels))
        finally:
            mdf.close()
        figures["mf4"] = str(mf4)
    return figures


if __name__ == "__main__":
    sys.exit(main())
