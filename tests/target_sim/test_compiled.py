"""The compiled model step (`target_sim.compiled`) is the numpy step bit for bit, for every kind and realization it
covers, over a drive cycle; what it does not cover falls back to numpy; the node uses it."""

import json

import numpy as np
import pytest

from target_sim.artifact import verify
from target_sim.compiled import compiled_step, exp_f32
from target_sim.fmath import EXP_CONSTANTS
from target_sim.fmath import exp_f32 as exp_reference
from target_sim.model import Float32Estimator, InputAccumulator
from target_sim.node import TargetNode

from helpers import ROOT, artifact_text, electrical_artifact_text, synthetic_columns


def loads(text: str):
    return verify(json.loads(text))


ROWS = 6000      # 20 minutes of drive at 5 Hz: 2400 model steps through the whole speed and torque range


def _drive(rows: int = ROWS) -> np.ndarray:
    columns = synthetic_columns(rows, seed=11, torque_sd=40.0, speed_sd=300.0)
    return np.stack([columns[k] for k in ("torque_Nm", "speed_rpm", "coolant_C", "ambient_C")], axis=1)


def _bits(values: np.ndarray) -> np.ndarray:
    return np.asarray(values, dtype=np.float32).view(np.uint32)


def _run_both(artifact, drive: np.ndarray) -> int:
    """Step the numpy estimator and the compiled one side by side; every output, x and y the same bits. Steps run."""
    reference, fast = Float32Estimator(artifact), Float32Estimator(artifact)
    step = compiled_step(fast)
    assert step is not None
    for est in (reference, fast):
        est.reset([45.0, 60.0, 52.0, 48.0])
    accumulator = InputAccumulator(artifact.data_sample_period, artifact.dt, 4)
    steps = 0
    for row, sample in enumerate(drive.astype(np.float32)):
        inputs = accumulator.add(row, sample)
        if inputs is None:
            continue
        expected, got = reference.step(*inputs), step(*inputs)
        assert np.array_equal(_bits(expected), _bits(got)), f"row {row}: {expected} != {got}"
        assert np.array_equal(_bits(reference.x), _bits(fast.x)) and np.array_equal(_bits(reference.y), _bits(fast.y))
        steps += 1
    return steps


@pytest.mark.parametrize(("kind", "realization"), [
    ("hammerstein", "balanced"), ("hammerstein", "delta"), ("hammerstein", "modal"), ("hammerstein", "physical"),
    ("lti-lptn", "balanced"), ("lti-lptn", "delta"), ("lti-lptn", "original")])
def test_the_compiled_step_is_the_numpy_step_bit_for_bit_over_a_drive_cycle(kind, realization):
    assert _run_both(loads(artifact_text(kind, realization)), _drive()) == ROWS * 2 // 5


def test_the_packaged_model_compiled_is_the_numpy_step_bit_for_bit_over_the_default_run():
    from bench.drive.dataset import load_dataset
    from bench.drive.generate import ensure_default_datasets
    from bench.model.runs import drive_matrix

    artifact = loads((ROOT / "bench" / "data" / "default_model.json").read_text(encoding="utf-8"))
    drive = drive_matrix(load_dataset(ensure_default_datasets(ROOT / "out" / "data")[40]))
    assert _run_both(artifact, drive) > 10_000


def test_exp_is_fmath_exp_f32_bit_for_bit_over_its_range_and_beyond():
    c = np.zeros(64, dtype=np.float32)
    from target_sim import compiled

    for name, value in EXP_CONSTANTS.items():
        c[compiled._EXP_INDEX[name]] = value
    rng = np.random.default_rng(3)
    xs = np.concatenate([rng.uniform(-90, 90, 20000), rng.uniform(-1, 1, 5000), [0.0, -0.0, 80.0, -80.0, 1e30,
                                                                                 -1e30, np.nan, np.inf, -np.inf]])
    for x in xs.astype(np.float32):
        assert _bits(exp_f32(c, x)) == _bits(exp_reference(x)), x


def test_a_calibrated_copper_coefficient_reaches_the_compiled_step():
    artifact = loads(artifact_text("hammerstein", "balanced"))
    reference, fast = Float32Estimator(artifact), Float32Estimator(artifact)
    step = compiled_step(fast)
    for est in (reference, fast):
        est.reset([45.0, 90.0, 52.0, 48.0])
        est.alpha_cu = np.float32(0.006)        # what XCP's cal_alpha_cu writes
    inputs = [np.float32(v) for v in (150.0, 4000.0, 40.0, 25.0)]
    assert np.array_equal(_bits(reference.step(*inputs)), _bits(step(*inputs)))


def test_what_it_does_not_cover_steps_with_numpy():
    assert compiled_step(Float32Estimator(loads(artifact_text("pv-lptn")))) is None
    assert compiled_step(Float32Estimator(loads(electrical_artifact_text()))) is None
    assert compiled_step(Float32Estimator(loads(artifact_text()), dtype=np.float64)) is None
    assert TargetNode(loads(artifact_text("pv-lptn"))).model_step.__self__.__class__ is Float32Estimator


def test_the_python_engine_steps_with_the_compiled_step():
    node = TargetNode(loads(artifact_text()))
    assert node.model_step.__qualname__.startswith("compiled_step")


def test_a_nodes_replies_in_two_parts_are_its_replies_in_one():
    """`TargetNode.handle_split` (what `serve` sends: the temperatures, then the rest once they are out) gives the
    frames `handle` gives, in the same order, on every row of a session (model steps and checkpoints among them)."""
    from dbc import FrameCodec
    from host.replay import encode_row

    from helpers import session_drive, session_start

    artifact = loads(artifact_text())
    whole, split = TargetNode(artifact, clock_ns=lambda: 0), TargetNode(artifact, clock_ns=lambda: 0)
    host = FrameCodec("HOST")
    messages = session_start(host)
    for row, values in enumerate(session_drive(400, seed=4)):
        messages += encode_row(host, row, values)
    rests = 0
    for message in messages:
        first, rest = split.handle_split(message)
        rests += rest is not None
        got = first + (rest() if rest is not None else [])
        expected = whole.handle(message)
        assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(m.arbitration_id, bytes(m.data))
                                                                    for m in expected]
    assert rests == 400
