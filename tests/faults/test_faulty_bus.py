"""The fault layer without processes: options, the plan, what each kind does to a frame, and that the target
node's journal names exactly the injected frame (reconcile)."""

from __future__ import annotations

import itertools

import can
import numpy as np
import pytest

from bench.model.default import default_artifact_path
from dbc import FrameCodec, decode_any, frame_id, frame_ids
from dbc.codec import profile2_crc
from host.faults import (
    KINDS,
    FaultPlan,
    FaultSpecError,
    FaultyBus,
    parse_faults,
    reconcile,
)
from host.faults.lockstep import FaultRun
from host.faults.reconcile import Journal
from target_sim.artifact import load_artifact
from target_sim.node import TargetNode

from helpers import session_start


class ListBus:
    """A python-can-like bus that keeps what was sent."""

    def __init__(self):
        self.sent: list[can.Message] = []

    def send(self, msg, timeout=None):
        self.sent.append(msg)

    def recv(self, timeout=None):
        return None

    def shutdown(self):
        pass


# ---------------------------------------------------------------- options


def test_fault_options_parse_with_aliases_and_compact_lists():
    spec = parse_faults(["drop=0.01,corrupt=0.001", "kill-target=1", "Stale-Counter=0.002"], seed=7)
    assert dict(spec.rates) == {"drop": 0.01, "corrupt": 0.001, "stale_counter": 0.002}
    assert dict(spec.counts) == {"kill": 1} and spec.seed == 7 and spec.active and spec.process_faults == 1
    assert spec.kinds() == ["drop", "corrupt", "stale_counter", "kill"]
    assert spec.describe() == "drop=0.01, corrupt=0.001, stale_counter=0.002, kill=1 (seed 7)"
    assert not parse_faults(["drop=0"]).active


@pytest.mark.parametrize(("items", "needle"), [
    (["bitrot=0.1"], "unknown fault kind 'bitrot'; use one of drop, delay"),
    (["drop"], "needs a value"),
    (["drop=often"], "is not a number"),
    (["drop=1.5"], "between 0 and 1"),
    (["drop=0.1", "drop=0.2"], "given twice"),
    (["kill=0.5"], "whole number"),
    (["drop=0.6,corrupt=0.6"], "add up to 1.2"),
])
def test_bad_fault_options_are_one_sentence(items, needle):
    with pytest.raises(FaultSpecError, match=needle):
        parse_faults(items)


# ---------------------------------------------------------------- the plan


def test_the_plan_is_a_function_of_seed_row_and_pass():
    spec = parse_faults(["drop=0.05,corrupt=0.05,reorder=0.02,delay=0.02"], seed=4)
    a, b = FaultPlan(spec, 20000), FaultPlan(spec, 20000)
    faults = [a.row_faults(r, 0) for r in range(20000)]
    assert faults == [b.row_faults(r, 0) for r in range(20000)]                  # same seed, same faults
    assert faults != [FaultPlan(parse_faults(["drop=0.05,corrupt=0.05,reorder=0.02,delay=0.02"], seed=5), 20000)
                      .row_faults(r, 0) for r in range(20000)]
    assert [a.row_faults(r, 1) for r in range(200)] != faults[:200]               # a re-sent row draws anew
    row_kinds = [f.row_kind for f in faults if f is not None]
    frame_kinds = [k for f in faults if f is not None for k in f.frame_kinds if k is not None]
    # the rates hold: reorder/delay per row, drop/corrupt per frame (of the rows with no row-level fault)
    assert row_kinds.count("reorder") == pytest.approx(400, rel=0.15)
    assert row_kinds.count("delay") == pytest.approx(400, rel=0.15)
    assert frame_kinds.count("drop") == pytest.approx(0.05 * 2 * 20000 * 0.96, rel=0.1)
    assert frame_kinds.count("corrupt") == pytest.approx(0.05 * 2 * 20000 * 0.96, rel=0.1)


def test_process_faults_fall_in_the_middle_of_the_run_and_apart():
    plan = FaultPlan(parse_faults(["kill=3,freeze=2"], seed=1), 1000)
    rows = sorted(plan.process_rows)
    assert len(rows) == 5 and sorted(plan.process_rows.values()).count("kill") == 3
    assert 100 <= rows[0] and rows[-1] < 900 and min(np.diff(rows)) >= 1
    assert plan.process_fault(rows[0], 0) is not None and plan.process_fault(rows[0], 1) is None
    with pytest.raises(FaultSpecError, match="need at least"):
        FaultPlan(parse_faults(["kill=30"]), 100)


# ---------------------------------------------------------------- what each kind does


def test_the_measurements_frame_is_a_fourth_draw_that_leaves_the_others_and_spares_the_last_row():
    """A model with an observer adds its rows' Measurements frame to the faultable ones (index 3): the drive frames
    get the faults they get without it; the last row's Measurements frame is never faulted (nothing after it would
    show its loss)."""
    spec = parse_faults(["drop=0.05,corrupt=0.05"], seed=4)
    rows = 5000
    plain, measured = FaultPlan(spec, rows), FaultPlan(spec, rows, measurements=True)
    with_currents = FaultPlan(spec, rows, frames_per_row=3, measurements=True)
    hits = 0
    for row in range(rows):
        a, b, c = plain.row_faults(row, 0), measured.row_faults(row, 0), with_currents.row_faults(row, 0)
        kinds = b.frame_kinds if b is not None else (None,) * 4
        assert (a.frame_kinds if a is not None else (None, None)) == kinds[:2]
        assert kinds[2] is None and (c.frame_kinds[3] if c is not None else None) == kinds[3]
        hits += kinds[3] is not None
    assert hits == pytest.approx(0.1 * rows, rel=0.15)
    assert all(measured.row_faults(rows - 1, p) is None or measured.row_faults(rows - 1, p).frame_kinds[3] is None
               for p in range(50))


def test_every_corruption_the_injector_makes_is_caught_by_the_crc():
    """1 to 3 flipped bits of 64: CRC8H2F's Hamming distance 4 catches every pattern (all 43 744 checked)."""
    msg = FrameCodec("HOST").encode("DriveInputs", {"Step": 1234, "MotorTorque": 345.6, "MotorSpeed": 3000})
    data_id = frame_id("DriveInputs") & 0xFF
    word = int.from_bytes(bytes(msg.data), "little")
    escaped = 0
    for flips in (1, 2, 3):
        for bits in itertools.combinations(range(64), flips):
            mask = sum(1 << b for b in bits)
            payload = (word ^ mask).to_bytes(8, "little")
            escaped += payload[0] == profile2_crc(payload, data_id)
    assert escaped == 0


def frames_through(kind: str, rows: int = 60):
    """Rows 1.. through a FaultyBus that injects only `kind` (rate 1 where it can), into a target node."""
    spec = parse_faults([f"{kind}=1"] if kind not in ("kill", "freeze") else [], seed=2)
    inner = ListBus()
    bus = FaultyBus(inner, FaultPlan(spec, rows), delay_s=0.0)
    codec = FrameCodec("HOST")
    for row in range(rows):
        bus.begin_row(row, 0, eligible=row > 0)
        bus.send(codec.encode("DriveInputs", {"Step": row, "MotorTorque": 10.0 + row, "MotorSpeed": 1000}))
        bus.send(codec.encode("DriveTemps", {"Step": row, "CoolantTemp": 40.0, "AmbientTemp": 25.0}))
        bus.end_row()
    bus.flush_held()
    return bus, inner.sent


@pytest.mark.parametrize("kind", ["drop", "duplicate", "corrupt", "stale_counter", "wrong_length", "unknown_id",
                                  "out_of_range", "reorder", "delay"])
def test_what_each_bus_fault_puts_on_the_bus(kind):
    bus, sent = frames_through(kind, rows=4)
    injections = bus.injections
    # a dropped frame's witness (the next frame of its id) goes out intact, so drops hit every other row here
    expected = {"reorder": [1, 2, 3], "delay": [1, 2, 3], "drop": [1, 1, 3, 3]}.get(kind, [1, 1, 2, 2, 3, 3])
    assert [i.row for i in injections] == expected
    ids = [m.arbitration_id for m in sent]
    di, dt = frame_id("DriveInputs"), frame_id("DriveTemps")
    if kind == "drop":
        assert ids == [di, dt] * 2  # rows 0 and 2 went out
        assert [i.witness for i in injections[:2]] == [bytes(m.data).hex() for m in sent[2:]]
    elif kind == "duplicate":
        assert len(sent) == 2 + 12 and bytes(sent[2].data) == bytes(sent[3].data)
    elif kind == "reorder":
        assert ids == [di, dt] + [dt, di] * 3
    elif kind == "delay":
        assert ids == [di, dt] * 4
    elif kind == "unknown_id":
        assert ids[2:] == [di ^ 8, dt ^ 8] * 3 and not set(ids[2:]) & set(frame_ids().values())
    elif kind == "wrong_length":
        assert all(len(m.data) < 8 and m.dlc == len(m.data) for m in sent[2:])
    elif kind == "stale_counter":  # a valid CRC and the counter of the frame before
        assert all(decode_any(m) for m in sent[2:])
        assert [m.data[1] & 0xF for m in sent[2::2]] == [0, 1, 2]
    else:
        for msg in sent[2:]:
            with pytest.raises(ValueError) as info:
                decode_any(msg)
            assert info.value.kind == {"corrupt": "crc", "out_of_range": "out_of_range"}[kind]
    for injection in injections:
        assert injection.data is None if kind == "drop" else injection.data is not None


@pytest.mark.parametrize("kind", ["drop", "duplicate", "corrupt", "stale_counter", "wrong_length", "unknown_id",
                                  "out_of_range", "reorder"])
def test_the_target_journal_names_each_injected_frame(kind):
    """Frames of a fault-injected replay (each faulted row retransmitted as the host does) into a TargetNode:
    every injection is matched by one journal record, and every row reaches the model exactly once."""
    node_journal: list[dict] = []
    node = TargetNode(load_artifact(default_artifact_path()), journal=node_journal.append)
    inner = ListBus()
    spec = parse_faults([f"{kind}=0.2"], seed=9)
    bus = FaultyBus(inner, FaultPlan(spec, 200), delay_s=0.0)
    codec = FrameCodec("HOST")

    def deliver():
        out = []
        for msg in inner.sent:
            out += node.handle(msg)
        inner.sent.clear()
        return [decode_any(m) for m in out if m.arbitration_id == frame_id("Temperatures1")]

    def row_frames(row):
        return [codec.encode("DriveInputs", {"Step": row, "MotorTorque": 100.0 + row, "MotorSpeed": 2000}),
                codec.encode("DriveTemps", {"Step": row, "CoolantTemp": 40.0, "AmbientTemp": 25.0})]

    for frame in session_start(codec):
        bus.send(frame)
    deliver()
    answered = []
    for row in range(200):
        bus.begin_row(row, 0, eligible=row > 0)
        for frame in row_frames(row):
            bus.send(frame)
        bus.end_row()
        replies = deliver()
        if not replies:  # the host's retransmission: the row twice more, never faulted
            bus.begin_row(row, 0, retransmission=True)
            for frame in row_frames(row) + row_frames(row):
                bus.send(frame)
            bus.end_row()
            replies = deliver()
        answered += [int(r.signals["Step"]) for r in replies]
    # every row used once, in order (a row retransmitted after it was used is answered again, not stepped again)
    assert sorted(set(answered)) == list(range(200)) and answered == sorted(answered)
    assert node.rows_used == 200
    run = FaultRun(spec, injections=bus.injections)
    summary = reconcile(run, Journal(entries=node_journal, instances=1))
    assert summary["injected"][kind] >= 10
    assert summary["detected"][kind] == summary["injected"][kind] and summary["undetected"] == 0
    assert all(i.detected for i in bus.injections)
    assert sum(node.errors.values()) == len(node_journal)  # the journal is the counters, event by event


def test_without_the_journal_target_side_detection_is_unknown_and_a_problem():
    from host.faults import fault_note, fault_problems

    bus, _ = frames_through("corrupt", rows=5)
    summary = reconcile(FaultRun(parse_faults(["corrupt=1"]), injections=bus.injections), None)
    assert summary["detected"]["corrupt"] is None and summary["undetected"] is None
    assert "journal is not available" in fault_problems(summary)[0]
    assert "detection unchecked" in fault_note(summary)
    assert set(summary["injected"]) <= set(KINDS)


def test_a_stale_counter_is_not_put_on_a_measurements_frame_whose_previous_one_was_lost():
    """Its stale counter would be the one the target expects after the lost frame (an undetectable fault): that
    Measurements frame goes out intact, and the target's journal names every stale counter injected."""
    from host.replay import encode_row

    rows = 12
    spec = parse_faults(["stale_counter=1"], seed=2)
    inner = ListBus()
    bus = FaultyBus(inner, FaultPlan(spec, rows, measurements=True), delay_s=0.0)
    codec = FrameCodec("HOST")
    for row in range(rows):
        bus.begin_row(row, 0, eligible=row > 0)
        for frame in encode_row(codec, row, [10.0, 1000.0, 40.0, 25.0], [60.0, float("nan")]):
            bus.send(frame)
        bus.end_row()
    measured = [i.row for i in bus.injections if i.frame_id == frame_id("Measurements")]
    assert measured == [1, 3, 5, 7, 9]       # every other row: never after a faulted one, never the last row
    node = TargetNode(load_artifact(default_artifact_path()), journal=(records := []).append)
    for frame in inner.sent:
        node.handle(frame)
    stale = [r for r in records if r["id"] == frame_id("Measurements") and "repeats alive counter" in r["detail"]]
    assert len(stale) == len(measured)
