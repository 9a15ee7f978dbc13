from __future__ import annotations

import numpy as np
import pytest

from bench.drive.motor import VIRTUAL_MOTOR, parametric_losses
from bench.drive.plant import (
    NO_EFFECTS,
    TRUE_EFFECTS,
    exact_steps,
    loss_inputs,
    make_true_losses,
    pv_network,
    simulate,
    simulate_ode,
    steady_state,
)
from bench.drive.sequence import ConstantDrive, TestSequence
from bench.drive.stand import environment, sequence_losses
from bench.thermal.discretize import discretize
from bench.thermal.losses import node_losses
from bench.thermal.lptn import pv_matrices
from bench.thermal.parameters import TABLE1_REFINED as P

SEQ = TestSequence()


def test_vectorized_network_equals_pv_matrices():
    speed, coolant = np.array([0.0, 0.3, 0.75]), np.array([20.0, 40.0, 61.5])
    g, g_cy, g_ma = pv_network(P, speed, coolant)
    a_d, b_loss, b_env = exact_steps(P, speed, coolant, 0.1)
    caps = np.array([P.C_y, P.C_w, P.C_t, P.C_m])
    for k in range(3):
        a, b = pv_matrices(P, speed[k], coolant[k])
        np.testing.assert_allclose(g[k] / caps[:, None], a, rtol=1e-12)
        ad, bd = discretize(a, b, 0.1, "zoh")
        np.testing.assert_allclose(a_d[k], ad, atol=1e-12)
        np.testing.assert_allclose(np.concatenate([b_loss[k], b_env[k]], axis=1), bd, atol=1e-12)


def test_true_losses_without_effects_are_the_nominal_model_with_eqs_3_to_8():
    rng = np.random.default_rng(1)
    tq, sp = rng.uniform(-640, 640, 200), rng.uniform(0, 9000, 200)
    th = rng.uniform(20, 150, (4, 200))
    li = loss_inputs(VIRTUAL_MOTOR, tq, sp)
    got = np.column_stack(make_true_losses(VIRTUAL_MOTOR, NO_EFFECTS, P)(li.i_q, li.i_d, li.tau, li.w, li.f, *th))
    m = parametric_losses(VIRTUAL_MOTOR, tq, sp)
    expected = node_losses(P, m["p_dc0"], m["p_ac0"], m["p_stator"], m["p_magnet"],
                           m["current"] / VIRTUAL_MOTOR.i_max_A, sp / VIRTUAL_MOTOR.max_speed_rpm, th[1])
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_true_effects_raise_losses_at_high_load_and_lower_them_when_hot():
    li = loss_inputs(VIRTUAL_MOTOR, 500.0, 2500.0)
    nominal = make_true_losses(VIRTUAL_MOTOR, NO_EFFECTS, P)(li.i_q, li.i_d, li.tau, li.w, li.f, 20, 20, 20, 20)
    true = make_true_losses(VIRTUAL_MOTOR, TRUE_EFFECTS, P)
    cold = true(li.i_q, li.i_d, li.tau, li.w, li.f, 20, 20, 20, 20)
    assert cold[1] > 1.15 * nominal[1]                      # copper: map error grows with load
    hot = true(li.i_q, li.i_d, li.tau, li.w, li.f, 120, 20, 120, 20)
    assert hot[0] < 0.92 * cold[0] and hot[2] < 0.92 * cold[2]   # iron falls with iron temperature
    hot_magnet = true(li.i_q, li.i_d, li.tau, li.w, li.f, 20, 20, 20, 120)
    assert hot_magnet[1] > 1.05 * cold[1]                   # a weaker magnet needs more current


def test_energy_balance_at_steady_state():
    drive = ConstantDrive(400.0, 2500.0)
    coolant, ambient = (lambda t: np.full_like(np.asarray(t, float), 40.0)), (lambda t: np.full_like(t, 25.0))
    run = simulate(drive, coolant, ambient, 40000.0, [40.0] * 4, h=2.0)
    x = run.states[-1]
    assert np.max(np.abs(x - run.states[-51])) < 1e-5      # settled: < 0.01 mK change over the last 100 s
    li = loss_inputs(VIRTUAL_MOTOR, 400.0, 2500.0)
    losses = np.array(make_true_losses(VIRTUAL_MOTOR, TRUE_EFFECTS, P)(li.i_q, li.i_d, li.tau, li.w, li.f, *x))
    _, g_cy, g_ma = pv_network(P, li.w, 40.0)
    heat_out = g_cy * (x[0] - 40.0) + g_ma * (x[3] - 25.0)
    assert heat_out == pytest.approx(losses.sum(), rel=1e-6)
    np.testing.assert_allclose(steady_state(P, losses, li.w, 40.0, 25.0), x, atol=1e-5)
    assert 30 < x[1] - 40 < 150                             # hot but below class-H insulation (180 °C)


@pytest.fixture(scope="module")
def stand40():
    return environment(SEQ.duration_s, 40.0, sequence_losses(SEQ), np.random.default_rng(3))


def test_step_size_does_not_matter(stand40):
    start = simulate(SEQ, stand40.coolant, stand40.ambient, 1500.0, [40.0] * 4).states[-1]
    coarse = simulate(SEQ, stand40.coolant, stand40.ambient, 3700.0, start, h=0.1, t_start=1500.0)
    fine = simulate(SEQ, stand40.coolant, stand40.ambient, 3700.0, start, h=0.02, t_start=1500.0)
    assert np.max(np.abs(coarse.states - fine.states[::5])) < 0.01
    assert np.ptp(coarse.states[:, 1]) > 40  # the window has real transients


def test_ode_solver_agrees_with_the_exact_steps(stand40):
    start = simulate(SEQ, stand40.coolant, stand40.ambient, 1780.0, [40.0] * 4).states[-1]
    ode = simulate_ode(SEQ, stand40.coolant, stand40.ambient, 1780, 1900, start)
    steps = simulate(SEQ, stand40.coolant, stand40.ambient, 1900.0, start, h=0.1, t_start=1780.0)
    assert np.max(np.abs(steps.states[::10] - ode.states)) < 0.01
    assert np.ptp(ode.states[:, 1]) > 10


def test_plant_starts_soaked_at_the_coolant_set_point(datasets):
    d = datasets[60]
    assert abs(d.winding_C[0] - 60.0) < 0.6 and abs(d.pm_C[0] - 60.0) < 0.8
