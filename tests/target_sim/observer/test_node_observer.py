"""The Python target node with an observer artifact (DBC 1.6.0): the row's Measurements frame feeds the filter, its
replies equal the offline float32 observer on the decoded measurements, every model step is answered with each
node's 1-sigma and the innovation; a lost, corrupted or misplaced Measurements frame is counted and the filter then
predicts only; an artifact without an observer ignores the frames and answers as before."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest

from dbc.codec import FrameCodec, decode_any
from dbc.contract import (
    MEASUREMENT_SLOTS,
    REPLY_SIGNALS,
    SIGMA_SIGNALS,
    Command,
    MeasurementStatus,
    place_temperatures,
)
from dbc.database import frame_id
from host.replay import encode_row, measurement_signals
from target_sim.artifact import load_artifact
from target_sim.model import run_offline
from target_sim.node import TargetNode
from target_sim.observer import run_observer_offline
from target_sim.observer.node import measurement_slots

from helpers import SESSION_INITIAL, session_drive, session_frames, session_start

ROWS = 200


@pytest.fixture(scope="module")
def observed(observer_artifact):
    return load_artifact(observer_artifact)


@pytest.fixture(scope="module")
def rows(observed):
    """Drive rows and a winding sensor that reads the open loop's winding 1.5 K warm, with noise and gaps (NaN:
    absent, every 7th row), as the host sends it: one column per slot."""
    drive = session_drive(ROWS, 3)
    steps, open_loop = run_offline(observed, drive, SESSION_INITIAL)
    rng = np.random.default_rng(1)
    sensor = np.round(np.interp(np.arange(ROWS), steps, open_loop[:, 1]) + 1.5 + rng.normal(0, 0.3, ROWS), 2)
    sensor[::7] = np.nan
    return drive, np.column_stack([sensor, np.full(ROWS, np.nan)])


def decoded(frames):
    """(temps per row, {message: count}, sigma rows, innovations) from a session's frames."""
    temps = np.full((ROWS, 4), np.nan)
    counts: dict[str, int] = {}
    sigma, innovations = {}, []
    for frame in frames:
        d = decode_any(frame)
        counts[d.name] = counts.get(d.name, 0) + 1
        step = int(d.signals.get("Step", -1))
        if d.name in REPLY_SIGNALS:
            place_temperatures(d.name, d.signals, temps[step])
        elif d.name in SIGMA_SIGNALS:
            place_temperatures(d.name, d.signals, sigma.setdefault(step, np.full(4, np.nan)), SIGMA_SIGNALS)
        elif d.name == "Innovations":
            innovations.append((step, d.signals))
    return temps, counts, sigma, innovations


def the_targets_measurement(values: np.ndarray) -> np.ndarray:
    """A column as the target decodes it from Measurements (0.01 °C steps; NaN where absent)."""
    out = []
    for value in values:
        frame = FrameCodec("HOST").encode("Measurements", measurement_signals(0, [value, math.nan])["Measurements"])
        out.append(np.nan if math.isnan(value) else decode_any(frame).signals["SensorTemp"])
    return np.array(out)


def test_the_observer_reads_the_sensor_slot(observed):
    assert measurement_slots(observed) == ["sensor"] and MEASUREMENT_SLOTS == ("sensor", "flux")


def test_measurement_frames_carry_a_status_per_slot():
    (signals,) = measurement_signals(7, [45.678, math.nan]).values()
    assert signals == {"Step": 7, "SensorTemp": 45.678, "SensorStatus": MeasurementStatus.VALID,
                       "FluxMagnetTemp": -50.0, "FluxMagnetStatus": MeasurementStatus.ABSENT}
    assert measurement_signals(7, [700.0, -60.0])["Measurements"]["SensorStatus"] == MeasurementStatus.INVALID
    frame = FrameCodec("HOST").encode("Measurements", signals)
    assert frame.arbitration_id == 0x113 and frame.dlc == 8
    d = decode_any(frame)
    assert d.signals["SensorTemp"] == pytest.approx(45.68) and d.signals["SensorStatus"] == 1
    from dbc.contract import channel_values

    values = channel_values("Measurements", d.signals)
    assert values["sensor"] == pytest.approx(45.68) and math.isnan(values["flux"]) and set(values) == {"sensor", "flux"}
    # a row's frames: Measurements first, then DriveInputs and DriveTemps of the same Step
    names = [decode_any(f).name for f in encode_row(FrameCodec("HOST"), 3, [1.0, 100.0, 40.0, 25.0], [40.0, 60.0])]
    assert names == ["Measurements", "DriveInputs", "DriveTemps"]


def test_replies_equal_the_offline_observer_on_the_decoded_measurements(observed, rows):
    drive, measurements = rows
    temps, counts, sigma, innovations = decoded(session_frames(observed, drive, measurements=measurements))
    z = the_targets_measurement(measurements[:, 0])
    run = run_observer_offline(observed, drive, z, SESSION_INITIAL)
    assert np.max(np.abs(temps[run.rows] - run.outputs)) <= 0.005 + 1e-9
    # the open loop answers otherwise: the measurements reached the filter
    _, open_loop = run_offline(observed, drive, SESSION_INITIAL)
    assert np.max(np.abs(temps[run.rows] - open_loop)) > 0.1
    # every model step: Uncertainty1, Uncertainty2, Innovations, after its timing frames
    steps = len(run.rows)
    assert counts["Uncertainty1"] == counts["Uncertainty2"] == counts["Innovations"] == counts["Timing1"] == steps
    used = np.array([bool(s["SensorUsed"]) for _, s in innovations])
    assert not any(s["FluxMagnetUsed"] for _, s in innovations)
    np.testing.assert_array_equal(used, np.isfinite(run.innovations))
    assert 0 < used.sum() < steps           # an interval with an absent row predicts only
    got = np.array([s["SensorInnovation"] for _, s in innovations])[used]
    np.testing.assert_allclose(got, run.innovations[used], atol=0.005 + 1e-9)
    # 1-sigma: the filter's own (0.001 K steps); the magnet, never measured, stays the least certain
    first = sigma[int(run.rows[0])]
    assert first[3] > first[1] > 0
    last = sigma[int(run.rows[-1])]
    assert np.all(last < np.array([15.0, 2.0, 15.0, 15.0]))


def _run_node(artifact, frames_per_row):
    """A node through RESET, START and the given rows' frames; (node, replies per row: temperatures)."""
    node, host = TargetNode(artifact, clock_ns=lambda: 0), FrameCodec("HOST")
    for frame in session_start(host):
        node.handle(frame)
    temps = np.full((len(frames_per_row), 4), np.nan)
    for row, frames in enumerate(frames_per_row):
        for frame in frames(host, row):
            for reply in node.handle(frame):
                d = decode_any(reply)
                if d.name in REPLY_SIGNALS:
                    place_temperatures(d.name, d.signals, temps[row])
    return node, temps


@pytest.mark.parametrize("fault", ["drop", "corrupt", "other_step"])
def test_a_lost_or_bad_measurement_frame_is_counted_and_the_filter_predicts_only(observed, rows, fault):
    drive, measurements = rows
    hit = 40      # a row whose interval has a measurement in every row but this frame's

    def frames(host, row):
        if row == hit and fault == "other_step":   # a valid frame, in sequence, naming another row
            signals = measurement_signals(row + 5, measurements[row].tolist())["Measurements"]
            wrong = host.encode("Measurements", signals)
            return [wrong, *encode_row(host, row, drive[row].tolist())]
        out = encode_row(host, row, drive[row].tolist(), measurements[row].tolist())
        if row != hit:
            return out
        if fault == "drop":
            return out[1:]
        data = bytearray(out[0].data)
        data[4] ^= 0x10
        return [can.Message(arbitration_id=out[0].arbitration_id, is_extended_id=False, data=bytes(data)), *out[1:]]

    node, temps = _run_node(observed, [frames] * ROWS)
    # a lost or refused frame shows as the alive-counter jump of the next one, which is refused too
    expected = {"drop": {"counter": 1}, "corrupt": {"crc": 1, "counter": 1}, "other_step": {"sequence": 1}}[fault]
    assert {kind: n for kind, n in node.errors.items() if n} == expected
    z = the_targets_measurement(measurements[:, 0])
    z[hit] = np.nan
    if fault != "other_step":
        z[hit + 1] = np.nan
    run = run_observer_offline(observed, drive, z, SESSION_INITIAL)
    assert np.max(np.abs(temps[run.rows] - run.outputs)) <= 0.005 + 1e-9
    assert node.rows_used == ROWS


def test_a_row_without_a_measurement_frame_predicts_only_without_an_error(observed, rows):
    drive, _ = rows
    node, temps = _run_node(observed, [lambda host, row: encode_row(host, row, drive[row].tolist())] * ROWS)
    assert sum(node.errors.values()) == 0
    run = run_observer_offline(observed, drive, np.full(ROWS, np.nan), SESSION_INITIAL)
    assert np.max(np.abs(temps[run.rows] - run.outputs)) <= 0.005 + 1e-9


def test_an_artifact_without_an_observer_ignores_the_frames_and_sends_the_same_bytes(artifacts, rows):
    artifact = load_artifact(artifacts["hammerstein"])
    drive, measurements = rows
    plain = session_frames(artifact, drive)
    measured = session_frames(artifact, drive, measurements=measurements)
    targets = [f for f in measured if f.arbitration_id >= 0x200]
    assert [(f.arbitration_id, bytes(f.data)) for f in targets] == \
        [(f.arbitration_id, bytes(f.data)) for f in plain if f.arbitration_id >= 0x200]
    assert not any(f.arbitration_id in (frame_id("Uncertainty1"), frame_id("Innovations")) for f in measured)


def test_a_restored_target_continues_from_the_state_with_a_fresh_covariance(observed, rows):
    """RESTORE: x bit for bit from the checkpoint, P = P0 (a checkpoint carries no covariance); the reference of a
    restarted segment (`segment_estimates`) restarts the same way."""
    from bench.analysis.canmetrics import segment_estimates

    drive, measurements = rows
    z = the_targets_measurement(measurements[:, 0])
    frames = session_frames(observed, drive, measurements=measurements)
    checkpoint = {}
    for frame in frames:
        d = decode_any(frame)
        if d.name == "StateCheckpoint":
            checkpoint.setdefault(int(d.signals["Step"]), {})[int(d.signals["StateIndex"])] = d.signals["StateValue"]
    step = min(checkpoint)
    state = [checkpoint[step][i] for i in range(4)]
    start = step + 1
    host, node = FrameCodec("HOST"), TargetNode(observed, clock_ns=lambda: 0)
    for index, value in enumerate(state):
        node.handle(host.encode("RestoreState", {"Step": start, "StateIndex": index, "StateValue": value}))
    node.handle(host.encode("Control", {"Command": int(Command.RESTORE), "Step": start}))
    node.handle(host.encode("Control", {"Command": int(Command.START), "Step": start}))
    temps = np.full((ROWS, 4), np.nan)
    for row in range(start, ROWS):
        for frame in encode_row(host, row, drive[row].tolist(), measurements[row].tolist()):
            for reply in node.handle(frame):
                d = decode_any(reply)
                if d.name in REPLY_SIGNALS:
                    place_temperatures(d.name, d.signals, temps[row])
    expected = segment_estimates(observed, drive, start, None, ROWS, state=state, measured=z)
    assert np.max(np.abs(temps[start:] - expected)) <= 0.005 + 1e-9
