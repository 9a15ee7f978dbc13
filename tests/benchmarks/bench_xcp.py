"""Benchmark (not a test): what the Python node's XCP slave costs the model step's deadline.

    python tests/benchmarks/bench_xcp.py [--model A] [--rows N] [--repeat N] [--daq-run [--run-rows N] [--mf4 PATH]]

In-process (no bus, so only the node's own work counts): the packaged model's Python node (or --model), connected,
with a DAQ list of the four temperatures (one ODT each, on the model step's event). Figures: the handler time of each
command kind (SHORT_UPLOAD of a float, SET_MTA + DOWNLOAD of a calibration, BUILD_CHECKSUM of the 48 bytes of x,
y and the estimate, GET_STATUS), --repeat times each; the DAQ sampling time per model step over a lockstep session of
--rows rows; the model step's own time in the same session with and without the DAQ list; and the model step's
period Δt, the deadline each figure is measured against (XCP commands run between frames, DAQ after the step's
replies, so neither enters the step itself).

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
                "BUILD_CHECKSUM 48 bytes": [bytes((0xF6, 0, 0, 0)) + struct.pack("<I", x0),
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
    if args.daq_run:
        record.figures["daq_run"] = daq_run(artifact, path, args.run_rows, args.mf4)
        print(f"DAQ run: {record.figures['daq_run']}")
    record.write()
    return 0


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
