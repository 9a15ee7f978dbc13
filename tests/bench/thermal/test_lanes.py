"""The batch kernel steps its models as lanes side by side (`bench.thermal.estimator._lanes`): every lane must give
the bits of the one-model step (`model_step`) that the observer's filter and the target's reference share, whatever
the number of models, so the groups of lanes never change an identification's result."""

from __future__ import annotations

import numpy as np
import pytest

from bench.thermal import portable
from bench.thermal.estimator import StepInputs, identity_sigmoid, lane_width, model_step, run_batch, step_buffers

STEPS = 120


def _problem(models: int, sigmoid: bool, seed: int = 7):
    rng = np.random.default_rng(seed)
    lut = np.abs(rng.normal(500.0, 300.0, (STEPS, 5)))
    inputs = StepInputs(lut, rng.random(STEPS), 40.0 + 20.0 * rng.random(STEPS), 25.0 + rng.random(STEPS), 400.0)
    a = np.eye(4)[None] * 0.97 + rng.normal(0.0, 0.005, (models, 4, 4))
    b = np.abs(rng.normal(0.002, 0.001, (models, 4, 8)))
    c = np.eye(4)[None] + rng.normal(0.0, 0.1, (models, 4, 4))
    theta = np.abs(rng.normal(1.0, 0.3, (models, 14)))
    theta[:, 13] *= -0.01
    sig = identity_sigmoid(np.full((models, 4), 1000.0))
    if sigmoid:
        sig[:, 1:] += rng.normal(0.0, 0.1, (models, 5, 4))
    refs = [40.0 + rng.random(STEPS) for _ in range(4)]
    return a, b, c, theta, sig, inputs, np.array([41.0, 45.0, 43.0, 42.0]), refs


def _one_by_one(a, b, c, theta, sig, inputs, y0, refs, use_sigmoid):
    """Each model alone through `model_step`, its errors summed in the kernel's order."""
    trajectories, sums = [], []
    for p in range(len(a)):
        x, x_new, y, u, gains = step_buffers(portable.inv(c[p]), y0)
        traj, sse = np.zeros((STEPS, 4)), [0.0, 0.0, 0.0, 0.0]
        for k in range(STEPS):
            model_step(a[p], b[p], c[p], theta[p], sig[p], inputs.table_losses, inputs.speed_ratio, inputs.coolant,
                       inputs.ambient, inputs.current_max, inputs.alpha_cu, inputs.copper_reference, k, x, x_new, y,
                       u, gains, use_sigmoid)
            traj[k] = y
            for node, (index, ref) in enumerate(zip((1, 3, 0, 2), refs, strict=True)):
                d = y[index] - ref[k]
                sse[node] += d * d
        trajectories.append(traj)
        sums.append(sse)
    return np.array(sums), np.array(trajectories)


@pytest.mark.parametrize("models", [1, 3, 17, 37])
@pytest.mark.parametrize("sigmoid", [False, True])
def test_every_lane_gives_the_bits_of_the_one_model_step(models, sigmoid):
    a, b, c, theta, sig, inputs, y0, refs = _problem(models, sigmoid)
    expected_sse, expected_traj = _one_by_one(a, b, c, theta, sig, inputs, y0, refs, sigmoid)
    for keep in (False, True):
        sse, traj = run_batch(a, b, c, theta, sig, inputs, y0, refs[0], refs[1], keep_trajectories=keep,
                              ref_y=refs[2], ref_t=refs[3])
        assert np.array_equal(sse, expected_sse)
        if keep:
            assert np.array_equal(traj, expected_traj)


def test_a_diverging_model_costs_inf_and_leaves_its_neighbours_alone():
    """A lane that blows up (a division by zero gives inf, not an error) does not touch the other lanes."""
    a, b, c, theta, sig, inputs, y0, refs = _problem(5, False)
    a[2] *= 1e200
    sse, _ = run_batch(a, b, c, theta, sig, inputs, y0, refs[0], refs[1])
    alone, _ = run_batch(np.delete(a, 2, 0), np.delete(b, 2, 0), np.delete(c, 2, 0), np.delete(theta, 2, 0),
                         np.delete(sig, 2, 0), inputs, y0, refs[0], refs[1])
    assert not np.all(np.isfinite(sse[2]))
    assert np.array_equal(np.delete(sse, 2, 0), alone)


def test_lane_groups_fill_every_thread_and_hold_at_most_the_lanes():
    from bench.thermal.estimator import LANES

    for models in (1, 2, 5, 37, 220, 1000):
        width = lane_width(models)
        assert 1 <= width <= min(LANES, models)
        assert width * -(-models // width) >= models


@pytest.mark.parametrize("stride", [None, STEPS + 5])
def test_residuals_written_by_the_kernel_equal_the_trajectories_minus_the_references(stride):
    """A fit's residual rows (weighted model - measurement), written in place, are those of the kept trajectories."""
    a, b, c, theta, sig, inputs, y0, refs = _problem(11, True)
    _, traj = run_batch(a, b, c, theta, sig, inputs, y0, keep_trajectories=True)
    nodes, weights = [1, 3, 0], np.array([1.0, 2.0, 0.7071067811865476])
    step = STEPS if stride is None else stride
    out = np.full((11, 3 + 2 * step + STEPS + 4), np.nan)
    run_batch(a, b, c, theta, sig, inputs, y0, residuals=(out, 3, nodes, refs[:3], weights)
              + (() if stride is None else (stride,)))
    for r, (node, weight) in enumerate(zip(nodes, weights, strict=True)):
        expected = traj[:, :, node] - refs[r] if weight == 1.0 else weight * (traj[:, :, node] - refs[r])
        assert np.array_equal(out[:, 3 + r * step:3 + r * step + STEPS], expected)
    assert np.isnan(out[:, :3]).all()     # nothing written outside the rows


def test_residuals_without_room_are_refused():
    a, b, c, theta, sig, inputs, y0, refs = _problem(2, False)
    with pytest.raises(ValueError, match="room"):
        run_batch(a, b, c, theta, sig, inputs, y0, residuals=(np.empty((2, STEPS)), 1, [1], refs[:1], np.ones(1)))
