"""Several measurements per row over CAN (DBC 1.7.0): an observer with a stator NTC and the flux linkage. The host
sends the NTC in Measurements and the d/q voltages in DriveVoltages; the target computes the flux magnet temperature
itself from them, the row's DriveCurrents and MotorSpeed, with its own winding estimate. Its replies equal the
offline float32 observer on the decoded channels, Innovations carries both innovations, a lost or corrupted
DriveVoltages frame is counted and that interval makes no flux update, and the observer's checkpoint (lag states,
UD factors) restores the filter bit for bit."""

from __future__ import annotations

import json

import can
import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.runs import drive_matrix
from bench.run.inputs import measurements_for
from dbc.codec import FrameCodec, decode_any
from dbc.contract import REPLY_SIGNALS, Command, MeasurementStatus, place_temperatures
from dbc.database import frame_id
from host.replay import encode_row, measurement_signals
from target_sim.artifact import ModelArtifact, load_artifact
from target_sim.node import TargetNode
from target_sim.observer import run_observer_offline
from target_sim.observer.node import (
    NodeObserver,
    can_refusal,
    measured_columns,
    measurement_slots,
    measurement_width,
    raw_channels,
    raw_sources,
)

from helpers import SESSION_INITIAL, session_frames, session_start

ROWS = 400


@pytest.fixture(scope="module")
def observed(flux_observer_artifact):
    return load_artifact(flux_observer_artifact[0])


@pytest.fixture(scope="module")
def rows(observed, flux_observer_artifact):
    """The dataset's drive rows (with the currents) and the host's measurement matrix (NTC, -, u_d, u_q)."""
    dataset = load_dataset(flux_observer_artifact[1])
    drive = drive_matrix(dataset, observed.drive_signals)[:ROWS]
    measured = measurements_for(dataset, observed)[:ROWS].copy()
    measured[::9, 2:] = np.nan          # the inverter flags some rows' voltages: no flux reading there
    return drive, measured


def decoded_channels(observed, drive, measured):
    """The observer's raw channels per row as the target decodes them (0.01 °C, 0.01 V; NaN where absent)."""
    host = FrameCodec("HOST")
    values = np.full(measured.shape, np.nan)
    for row in range(len(drive)):
        for frame in encode_row(host, row, drive[row].tolist(), measured[row].tolist()):
            d = decode_any(frame)
            if d.name == "Measurements" and d.signals["SensorStatus"] == MeasurementStatus.VALID:
                values[row, 0] = d.signals["SensorTemp"]
            elif d.name == "DriveVoltages" and d.signals["VoltageStatus"] == MeasurementStatus.VALID:
                values[row, 2:] = d.signals["VoltageD"], d.signals["VoltageQ"]
    return raw_channels(raw_sources(observed), drive, values)


def replies(frames):
    temps = np.full((ROWS, 4), np.nan)
    innovations = []
    for frame in frames:
        d = decode_any(frame)
        if d.name in REPLY_SIGNALS:
            place_temperatures(d.name, d.signals, temps[int(d.signals["Step"])])
        elif d.name == "Innovations":
            innovations.append(d.signals)
    return temps, innovations


def test_the_flux_linkage_reads_the_voltages_and_the_rows_currents(observed):
    assert measurement_slots(observed) == ["sensor", "flux"]
    assert measured_columns(observed) == {"sensor": "ntc_C", "u_d": "u_d_V", "u_q": "u_q_V"}
    assert measurement_width(observed) == 4 and can_refusal(observed) is None
    # the NTC from the matrix, u_d and u_q from DriveVoltages' columns, i_d and i_q from the row's DriveCurrents
    assert raw_sources(observed) == [("channel", 0), ("channel", 2), ("channel", 3), ("row", 4), ("row", 5)]
    assert NodeObserver(observed).messages == ("Measurements", "DriveVoltages")


def test_a_row_sends_measurements_then_voltages_then_the_drive_frames(observed, rows):
    drive, measured = rows
    names = [decode_any(f).name for f in encode_row(FrameCodec("HOST"), 1, drive[1].tolist(), measured[1].tolist())]
    assert names == ["Measurements", "DriveVoltages", "DriveInputs", "DriveTemps", "DriveCurrents"]
    flagged = measurement_signals(0, [40.0, np.nan, np.nan, 30.0])["DriveVoltages"]
    assert flagged["VoltageStatus"] == MeasurementStatus.ABSENT
    assert measurement_signals(0, [40.0, np.nan, 1.0, 400.0])["DriveVoltages"]["VoltageStatus"] == \
        MeasurementStatus.INVALID


def test_replies_equal_the_offline_observer_with_both_measurements(observed, rows):
    drive, measured = rows
    temps, innovations = replies(session_frames(observed, drive, measurements=measured))
    z = decoded_channels(observed, drive, measured)
    run = run_observer_offline(observed, drive, z, SESSION_INITIAL)
    assert np.max(np.abs(temps[run.rows] - run.outputs)) <= 0.005 + 1e-9
    used = np.array([[s["SensorUsed"], s["FluxMagnetUsed"]] for s in innovations], dtype=bool)
    np.testing.assert_array_equal(used, np.isfinite(run.all_innovations))
    assert used[:, 0].sum() > 0.9 * len(used) and 0 < used[:, 1].sum() < len(used)   # the flux: fast rows only
    got = np.array([s["FluxMagnetInnovation"] for s in innovations])[used[:, 1]]
    np.testing.assert_allclose(got, run.all_innovations[used[:, 1], 1], atol=0.005 + 1e-9)
    # without the flux linkage's frames the filter answers otherwise: the target did compute it
    no_voltages = measured.copy()
    no_voltages[:, 2:] = np.nan
    alone = run_observer_offline(observed, drive, decoded_channels(observed, drive, no_voltages), SESSION_INITIAL)
    assert np.max(np.abs(alone.outputs[:, 3] - run.outputs[:, 3])) > 0.01


@pytest.mark.parametrize("fault", ["drop", "corrupt"])
def test_a_lost_or_corrupted_voltage_frame_is_counted_and_no_flux_update_follows(observed, rows, fault):
    drive, measured = rows
    hit = 41
    host, node = FrameCodec("HOST"), TargetNode(observed, clock_ns=lambda: 0)
    for frame in session_start(host):
        node.handle(frame)
    out = []
    for row in range(ROWS):
        frames = encode_row(host, row, drive[row].tolist(), measured[row].tolist())
        if row == hit:
            if fault == "drop":
                frames = [frames[0], *frames[2:]]
            else:
                data = bytearray(frames[1].data)
                data[5] ^= 0x04
                frames[1] = can.Message(arbitration_id=frames[1].arbitration_id, is_extended_id=False,
                                        data=bytes(data))
        for frame in frames:
            out.extend(node.handle(frame))
    expected = {"drop": {"counter": 1}, "corrupt": {"crc": 1, "counter": 1}}[fault]
    assert {kind: n for kind, n in node.errors.items() if n} == expected
    z = decoded_channels(observed, drive, measured)
    z[hit, 1:3] = np.nan
    z[hit + 1, 1:3] = np.nan       # the next frame's counter jump: refused too
    run = run_observer_offline(observed, drive, z, SESSION_INITIAL)
    temps, _ = replies(out)
    assert np.max(np.abs(temps[run.rows] - run.outputs)) <= 0.005 + 1e-9
    assert node.rows_used == ROWS


def _checkpoint_and_restore(observed, drive, measured, echo: bool):
    """A clean session's first checkpoint (StateCheckpoint and ObserverCheckpoint), a fresh node restored from it
    (with the RestoreObserver echo or without), and the rows after it: (restored replies, the clean replies)."""
    frames = session_frames(observed, drive, measurements=measured)
    clean, _ = replies(frames)
    state, observer = {}, {}
    for frame in frames:
        d = decode_any(frame)
        if d.name == "StateCheckpoint":
            state.setdefault(int(d.signals["Step"]), {})[int(d.signals["StateIndex"])] = d.signals["StateValue"]
        elif d.name == "ObserverCheckpoint":
            observer.setdefault(int(d.signals["StepLow"]), {})[int(d.signals["Index"])] = d.signals["Value"]
    step = min(state)
    start = step + 1
    host, node = FrameCodec("HOST"), TargetNode(observed, clock_ns=lambda: 0)
    for index, value in state[step].items():
        node.handle(host.encode("RestoreState", {"Step": start, "StateIndex": index, "StateValue": value}))
    if echo:
        for index, value in sorted(observer[step].items()):
            node.handle(host.encode("RestoreObserver", {"Index": index, "StepLow": start, "Value": value}))
    node.handle(host.encode("Control", {"Command": int(Command.RESTORE), "Step": start}))
    node.handle(host.encode("Control", {"Command": int(Command.START), "Step": start}))
    out = []
    for row in range(start, ROWS):
        for frame in encode_row(host, row, drive[row].tolist(), measured[row].tolist()):
            out.extend(node.handle(frame))
    restored, _ = replies(out)
    return restored[start:], clean[start:], observer[step]


def test_the_observer_checkpoint_restores_the_filter_bit_for_bit(observed, rows):
    drive, measured = rows
    restored, clean, elements = _checkpoint_and_restore(observed, drive, measured, echo=True)
    # one extra state (the NTC's lag; none for the flux), then the UD factors of the 5-state covariance: d, U
    assert len(elements) == 1 + 5 + 10 == NodeObserver(observed).filter.checkpoint_size()
    np.testing.assert_array_equal(restored, clean)
    # without the echo the covariance starts again at P0: the replies differ
    fresh, clean, _ = _checkpoint_and_restore(observed, drive, measured, echo=False)
    assert np.max(np.abs(fresh - clean)) > 0.01


def test_the_checkpoint_is_the_filters_state_in_every_form(observed, rows):
    """checkpoint() then restore_checkpoint() on a fresh filter: the same next steps, in every covariance form."""
    from target_sim.observer import OBSERVER_FORMS, Float32Observer

    drive, measured = rows
    z = decoded_channels(observed, drive, measured)
    for form in OBSERVER_FORMS.names():
        a, b = Float32Observer(observed, form), Float32Observer(observed, form)
        a.reset(SESSION_INITIAL)
        for k in range(0, 30, 5):
            a.step(*drive[k], z=z[k])
        b.reset(SESSION_INITIAL)
        b.est.restore(a.est.x.tolist())
        b.restore_checkpoint(a.checkpoint())
        for k in range(30, 60, 5):
            np.testing.assert_array_equal(a.step(*drive[k], z=z[k]), b.step(*drive[k], z=z[k]))
    with pytest.raises(ValueError, match="elements"):     # (the gated steady form's: the lag, 2 gate counts)
        a.restore_checkpoint([1.0] * (a.checkpoint_size() + 1))


def test_a_flux_observer_of_a_loss_map_model_is_refused_in_one_sentence(observed, artifacts, tmp_path):
    """The flux linkage needs the row's currents, which a loss-map model's rows do not carry."""
    from bench.observer.section import with_observer

    plain = load_artifact(artifacts["hammerstein"])
    content = with_observer(plain, observed.content["observer"])
    path = tmp_path / "maps-flux.json"
    path.write_text(json.dumps(content), encoding="utf-8")
    refusal = can_refusal(load_artifact(path))
    assert refusal is not None and "\n" not in refusal
    assert "flux linkage from the d/q currents" in refusal and "loss model" in refusal


def test_two_measurements_in_one_slot_are_refused(observed):
    content = json.loads(json.dumps(observed.content))
    content["observer"]["measurements"] = [content["observer"]["measurements"][0]] * 2
    refusal = can_refusal(ModelArtifact(content, None))
    assert refusal is not None and "sensor slot" in refusal and "\n" not in refusal


def test_the_voltage_frame_is_new_in_1_7(observed):
    assert frame_id("DriveVoltages") == 0x114 and frame_id("ObserverCheckpoint") == 0x234
    assert frame_id("RestoreObserver") == 0x104
