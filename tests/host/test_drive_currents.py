"""The host and the d/q currents (DBC 1.4.0): a drive matrix with six columns sends each row's DriveCurrents after
its DriveInputs and DriveTemps, one with four sends exactly what it sent before; the range check names a current
the DBC cannot carry; the fault plan draws a third frame's faults without changing those of two-frame rows; a
log replay waits for a row's replies after its last frame."""

from __future__ import annotations

import can
import numpy as np
import pytest

from dbc import FrameCodec, decode_any
from host.faults import FaultyBus
from host.faults.plan import FaultPlan
from host.faults.spec import parse_faults
from host.replay import DataRangeError, check_drive_range, encode_row, last_row_frame_id

ROW = [123.4, 4500.0, 40.1, 25.2]
CURRENTS = [-321.7, 456.8]


def test_a_row_with_currents_is_three_frames_in_row_order():
    frames = encode_row(FrameCodec("HOST"), 70000, ROW + CURRENTS)
    decoded = [decode_any(f) for f in frames]
    assert [f.name for f in decoded] == ["DriveInputs", "DriveTemps", "DriveCurrents"]
    assert [f.arbitration_id for f in frames] == [0x110, 0x111, 0x112]
    assert all(f.signals["Step"] == 70000 % 65536 for f in decoded)
    assert decoded[2].signals == pytest.approx({"Step": 4464, "CurrentD": -321.7, "CurrentQ": 456.8})
    # without the currents: the very frames of DBC 1.3.0's host (same bytes, counters and CRCs)
    plain = encode_row(FrameCodec("HOST"), 70000, ROW)
    assert [(f.arbitration_id, bytes(f.data)) for f in plain] == [(f.arbitration_id, bytes(f.data))
                                                                  for f in frames[:2]]


def test_the_range_check_covers_the_currents():
    drive = np.array([ROW + CURRENTS, ROW + [-3000.0, 3000.0]])
    check_drive_range(drive)
    check_drive_range(drive[:, :4])
    bad = drive.copy()
    bad[1, 5] = 3000.4
    with pytest.raises(DataRangeError, match=r"data row 1 has q-axis current 3000\.4, outside what "
                                             r"DriveCurrents\.CurrentQ can carry \(-3000 to 3000\)"):
        check_drive_range(bad)
    with pytest.raises(DataRangeError, match="not \\(rows, 4\\) or \\(rows, 6\\)"):
        check_drive_range(drive[:, :5])


def test_the_fault_plan_of_three_frame_rows_keeps_the_faults_of_two_frame_rows():
    spec = parse_faults(["drop=0.05,corrupt=0.05,reorder=0.02"], seed=11)
    two, three = FaultPlan(spec, 5000), FaultPlan(spec, 5000, frames_per_row=3)
    third = 0
    for row in range(5000):
        a, b = two.row_faults(row, 0), three.row_faults(row, 0)
        if a is not None:
            assert b is not None and b.row_kind == a.row_kind and b.frame_kinds[:2] == a.frame_kinds
        if b is not None:
            assert len(b.frame_kinds) == 3
            third += b.frame_kinds[2] is not None
            if a is None:      # only the DriveCurrents frame is faulted
                assert b.frame_kinds[:2] == (None, None) and b.frame_kinds[2] is not None
    assert third == pytest.approx(0.1 * 5000 * 0.98, rel=0.15)


def test_the_fault_layer_hits_drive_currents_frames():
    inner = can.Bus(interface="virtual", channel="currents-faults", receive_own_messages=False)
    listener = can.Bus(interface="virtual", channel="currents-faults", receive_own_messages=False)
    try:
        spec = parse_faults(["drop=0.3"], seed=2)
        bus = FaultyBus(inner, FaultPlan(spec, 200, frames_per_row=3), delay_s=0.0)
        codec = FrameCodec("HOST")
        for row in range(200):
            bus.begin_row(row, 0, eligible=row > 0)
            for frame in encode_row(codec, row, ROW + CURRENTS):
                bus.send(frame)
            bus.end_row()
        dropped = [i for i in bus.injections if i.kind == "drop" and i.frame_id == 0x112]
        assert len(dropped) == pytest.approx(0.3 * 199, rel=0.3)
        received = []
        while (msg := listener.recv(0.0)) is not None:
            received.append(msg.arbitration_id)
        assert received.count(0x112) == 200 - len(dropped)
        assert all(i.witness is not None for i in dropped[:-1])    # the next DriveCurrents shows each loss
    finally:
        inner.shutdown()
        listener.shutdown()


def test_a_log_replay_waits_after_the_rows_last_frame():
    codec = FrameCodec("HOST")
    with_currents = [f for row in range(3) for f in encode_row(codec, row, ROW + CURRENTS)]
    without = [f for row in range(3) for f in encode_row(FrameCodec("HOST"), row, ROW)]
    assert last_row_frame_id(with_currents) == 0x112
    assert last_row_frame_id(without) == 0x111
