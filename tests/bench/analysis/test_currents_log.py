"""The analysis of a log whose rows carry the d/q currents (DBC 1.4.0): the decoder gives six drive columns (a
DriveCurrents belongs to the pair of its Step right before it; copies of frames change nothing), the references of
an electrical loss model run on them, a loss-map model uses the first four, and a log without currents cannot be
compared with an electrical model (one sentence)."""

from __future__ import annotations

import copy
import time

import numpy as np
import pytest

from bench.analysis.canmetrics import compute, float64_reference
from bench.analysis.logdecode import decode_log
from dbc import Command, FrameCodec
from host.canlog import FrameLog
from host.replay import encode_row
from target_sim.artifact import load_artifact
from target_sim.model import run_offline
from target_sim.node import TargetNode

from helpers import electrical_artifact_text

INITIAL = [40.0, 45.0, 41.0, 50.0]


@pytest.fixture(scope="module")
def electrical(tmp_path_factory):
    path = tmp_path_factory.mktemp("electrical") / "electrical.json"
    path.write_text(electrical_artifact_text(), encoding="utf-8")
    return load_artifact(path)


def drive(n: int, seed: int = 12) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([np.round(rng.uniform(0, 400, n), 1), np.round(rng.uniform(500, 8000, n)),
                            np.full(n, 40.0), np.full(n, 25.0), np.round(rng.uniform(-300, 0, n), 1),
                            np.round(rng.uniform(0, 350, n), 1)])


def write_session(path, artifact, values: np.ndarray, *, with_currents: bool = True, stray: bool = False) -> None:
    """A session as the host logs it, the target's replies included (a Python node answers in-process): rows with
    their DriveCurrents; row 5's DriveTemps and row 8's DriveCurrents go out twice (the target refuses the copies
    by their alive counter; the log decoder does not judge counters), a stray DriveCurrents of another Step after
    row 11's pair with `stray` (an electrical model's target then never completes row 11; a loss-map model's ignores
    it)."""
    node, host, log = TargetNode(artifact, clock_ns=lambda: 0), FrameCodec("HOST"), FrameLog(path)
    yoke, winding, tooth, magnet = INITIAL
    frames = [host.encode("ResetTemps1", {"Step": 0, "WindingTempInit": winding, "MagnetTempInit": magnet}),
              host.encode("ResetTemps2", {"Step": 0, "YokeTempInit": yoke, "ToothTempInit": tooth}),
              host.encode("Control", {"Command": int(Command.RESET), "Step": 0}),
              host.encode("Control", {"Command": int(Command.START), "Step": 0})]
    for row, value in enumerate(values):
        extra = host.encode("DriveCurrents", {"Step": 40, "CurrentD": 0.0, "CurrentQ": 0.0}) \
            if row == 11 and stray else None     # encoded first: its alive counter comes before row 11's
        row_frames = encode_row(host, row, value if with_currents else value[:4])
        if row == 5:
            row_frames.insert(2, copy.copy(row_frames[1]))
        if row == 8 and with_currents:
            row_frames.append(copy.copy(row_frames[2]))
        if extra is not None:
            row_frames.insert(2, extra)
        frames += row_frames
    for frame in frames:
        frame.timestamp = time.time()
        log.write(frame)
        for reply in node.handle(frame):
            log.write(reply)
    log.close()


def test_a_log_with_currents_decodes_to_six_columns_and_the_references_use_them(electrical, tmp_path):
    values = drive(40)
    write_session(tmp_path / "run.asc", electrical, values)
    record = decode_log(tmp_path / "run.asc")
    np.testing.assert_allclose(record.drive, values, atol=1e-9)
    assert record.answered.all()
    results, refs = compute(record, electrical)
    metrics = results.to_json()
    assert metrics["can_agrees_with_float32"] and metrics["model"]["loss_model"] == "electrical"
    assert all(v <= 0.005 + 1e-9 for v in metrics["max_abs_can_minus_float32_C"].values())
    assert metrics["rows_lost_on_the_bus"] == 0 and metrics["model_steps"] == 16
    _, expected = run_offline(electrical, values, record.initial)
    np.testing.assert_array_equal(refs.f32, expected.astype(np.float64))
    assert 0 < np.max(np.abs(refs.f64 - refs.f32)) < 0.01        # the float64 twin of the electrical model


def test_a_drive_currents_of_another_step_loses_the_row_as_at_the_target(electrical, tmp_path):
    values = drive(40)
    write_session(tmp_path / "stray.asc", electrical, values, stray=True)
    record = decode_log(tmp_path / "stray.asc")
    expected = values.copy()
    expected[11, 4:] = np.nan           # the row's currents came after a DriveCurrents of another Step
    np.testing.assert_allclose(record.drive, expected, atol=1e-9)
    assert not record.answered[11] and np.count_nonzero(record.answered) == 39
    results, _ = compute(record, electrical)
    metrics = results.to_json()
    assert (metrics["rows_lost_on_the_bus"], metrics["can_reference"]) == (1, "target twin")
    assert metrics["can_agrees_with_float32"] and all(v == 0 for v in metrics["max_abs_can_minus_float32_C"].values())


def test_a_loss_map_model_uses_the_first_four_columns(artifacts, tmp_path):
    lti = load_artifact(artifacts["lti"])
    values = drive(30, seed=3)
    write_session(tmp_path / "maps.asc", lti, values)
    record = decode_log(tmp_path / "maps.asc")
    assert record.drive.shape == (30, 6)
    results, refs = compute(record, lti)
    metrics = results.to_json()
    assert metrics["can_agrees_with_float32"] and metrics["replies"] == 30
    _, expected = run_offline(lti, values[:, :4], record.initial)
    np.testing.assert_array_equal(refs.f32, expected.astype(np.float64))


def test_an_electrical_model_cannot_be_compared_with_a_log_without_currents(electrical, artifacts, tmp_path):
    write_session(tmp_path / "plain.asc", load_artifact(artifacts["lti"]), drive(20), with_currents=False)
    record = decode_log(tmp_path / "plain.asc")
    assert record.drive.shape == (20, 4)
    with pytest.raises(ValueError) as info:
        compute(record, electrical)
    assert str(info.value) == (f"model {electrical.model_id:08x} has an electrical loss model, which needs the d/q "
                               "currents, and the log's rows carry none (no DriveCurrents frames)")


def test_float64_reference_of_an_electrical_model_tracks_float32(electrical):
    values = drive(1500, seed=4)
    rows, f32 = run_offline(electrical, values, INITIAL)
    f64 = float64_reference(electrical, values, INITIAL)
    assert f64.shape == f32.shape == (600, 4)
    assert 0 < np.max(np.abs(f32 - f64)) < 0.02 and np.max(f64[:, 1]) > 50.0
