"""`bench replay` of a log made with bus faults: the faulty frames go out again byte for byte, the new target
rejects the same frames, and every data row's final reply comes back identical (rows retransmitted when the log
was made are compared once, by Step, not by DriveInputs frame)."""

from __future__ import annotations

import json

import can
import pytest

from bench.analysis.logdecode import decode_log
from host.procedure import injected_ids

from .test_cli import load_only
from helpers import run_cli

ROWS = 500
# every bus fault; rates high enough that each kind occurs in 500 rows with this seed
BUS_FAULTS = ("drop=0.02,delay=0.01,duplicate=0.01,reorder=0.01,corrupt=0.01,stale_counter=0.01,wrong_length=0.01,"
              "unknown_id=0.01,out_of_range=0.01")


@pytest.fixture(scope="module")
def bus_fault_log(tmp_path_factory, fault_dataset):
    out = tmp_path_factory.mktemp("busfaults")
    log = out / "bench.blf"
    proc = run_cli("-m", "bench", "run", "--data", str(fault_dataset), "--rows", str(ROWS), "--log", str(log),
                   "--no-report", "--faults", BUS_FAULTS, "--fault-seed", "3", "--json", "--tolerate-faults")
    s = json.loads(proc.stdout)
    assert proc.returncode == 0 or load_only(s["problems"]), proc.stderr
    assert all(n > 0 for n in s["faults"]["injected"].values()), s["faults"]["injected"]
    return log


def _sent(log) -> list[tuple[int, bytes]]:
    """The frames the host put on the bus, in order: (id, bytes)."""
    from dbc import host_frame_ids

    return [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(log))
            if m.arbitration_id in host_frame_ids() | injected_ids()]


@pytest.mark.slow
@pytest.mark.parametrize("timing", ["--as-fast-as-possible", "recorded"])
def test_a_bus_fault_log_replays_faithfully(bus_fault_log, tmp_path, timing):
    new_log = tmp_path / "replay.blf"
    proc = run_cli("-m", "bench", "replay", str(bus_fault_log), "--log", str(new_log), "--json",
                   *([timing] if timing.startswith("--") else []))
    assert proc.returncode == 0, proc.stderr + proc.stdout
    s = json.loads(proc.stdout)
    assert s["reproduced"] and s["identical"] == s["recorded_answered"] == ROWS and s["different"] == 0
    assert s["rows_recorded"] == s["rows_replayed"] == ROWS and s["problems"] == []
    rejections = s["target_rejections"]
    assert rejections["replayed"] == rejections["recorded"]
    assert all(rejections["recorded"][k] > 0 for k in ("unknown_id", "wrong_length", "crc", "counter",
                                                       "out_of_range", "sequence")), rejections
    assert set(s["faults_in_log"]) >= {"drop", "duplicate", "corrupt", "unknown_id", "reorder"}
    # byte for byte: the host's frames in the new log are the recorded ones, faulty ones included
    assert _sent(new_log) == _sent(bus_fault_log)
    assert (decode_log(new_log).temps == decode_log(bus_fault_log).temps).all()
