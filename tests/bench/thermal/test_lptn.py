import numpy as np
import pytest

from bench.thermal.discretize import discretize
from bench.thermal.losses import copper_losses, node_losses, stator_split_factor
from bench.thermal.lptn import (
    continuous_eigenvalues,
    lti_matrices,
    pv_matrices,
    temperature_sources,
    time_constants,
)
from bench.thermal.parameters import TABLE1, TABLE1_REFINED, LptnParameters, parameter_set

EQ27 = np.array([-0.1320, -0.0254, -0.0120, -0.0045])


def test_refined_parameters_reproduce_eq27():
    assert np.max(np.abs(continuous_eigenvalues(TABLE1_REFINED) - EQ27)) < 1e-6


def test_printed_table1_gives_the_reference_eigenvalues_and_time_constants():
    np.testing.assert_allclose(continuous_eigenvalues(TABLE1), [-0.13793, -0.025219, -0.012521, -0.0044587],
                               rtol=5e-5)
    np.testing.assert_allclose(time_constants(TABLE1), [7.250, 39.65, 79.87, 224.28], atol=0.01)


def test_parameter_sets_have_22_parameters_and_refined_stays_inside_rounding():
    assert len(LptnParameters.names()) == 22
    for name in ("R_yw", "R_yt", "R_cy0", "a_tm", "a_ma"):
        assert abs(getattr(TABLE1_REFINED, name) - getattr(TABLE1, name)) <= 0.0005 + 1e-12
    with pytest.raises(KeyError, match="table1-refined"):
        parameter_set("table2")


def test_b_matrix_matches_reference_entries():
    p = TABLE1_REFINED
    _, b, c, d = lti_matrices(p)
    assert b[0, 4] == pytest.approx(1 / (p.C_y * p.R_cy0))
    assert b[3, 6] == pytest.approx(-1 / (p.C_m * p.a_tm))
    assert b[1, 7] == pytest.approx(-1 / (p.C_w * p.a_wm))
    assert np.count_nonzero(b) == 10
    assert np.array_equal(c, np.eye(4)) and not d.any()


@pytest.mark.parametrize("speed_ratio,coolant", [(0.0, 40.0), (0.3, 20.0), (0.9, 60.0)])
def test_lti_network_with_sources_has_the_heat_flows_of_the_pv_network(speed_ratio, coolant):
    """With eqs. 9-18 evaluated at the current state, the LTI form equals the PV LPTN exactly."""
    p = TABLE1_REFINED
    x = np.array([55.0, 92.0, 61.0, 70.0])
    losses = np.array([400.0, 1500.0, 300.0, 80.0])
    ambient = 25.0
    a, b, _, _ = lti_matrices(p)
    sources = temperature_sources(p, x, speed_ratio, coolant, ambient)
    lti_rate = a @ x + b @ np.concatenate([losses, sources])
    a_pv, b_pv = pv_matrices(p, speed_ratio, coolant)
    pv_rate = a_pv @ x + b_pv @ np.concatenate([losses, [coolant, ambient]])
    np.testing.assert_allclose(lti_rate, pv_rate, rtol=1e-12, atol=1e-12)


def test_sources_reduce_to_node_temperatures_without_varying_parts():
    p = TABLE1_REFINED.with_values(R_wm0=0.0, R_tm0=0.0, R_ma0=0.0)
    x = np.array([50.0, 90.0, 60.0, 70.0])
    np.testing.assert_allclose(temperature_sources(p, x, 0.5, 40.0, 25.0), [40.0, 25.0, 70.0, 90.0])


@pytest.mark.parametrize("dt", [0.5, 1.0, 2.0, 4.0])
def test_discrete_poles(dt):
    a, b, _, _ = lti_matrices(TABLE1_REFINED)
    lam = continuous_eigenvalues(TABLE1_REFINED)
    zoh = np.sort(np.linalg.eigvals(discretize(a, b, dt, "zoh")[0]).real)
    np.testing.assert_allclose(zoh, np.sort(np.exp(lam * dt)), rtol=1e-12)
    tustin = np.sort(np.linalg.eigvals(discretize(a, b, dt, "tustin")[0]).real)
    np.testing.assert_allclose(tustin, np.sort((1 + lam * dt / 2) / (1 - lam * dt / 2)), rtol=1e-12)
    euler = np.sort(np.linalg.eigvals(discretize(a, b, dt, "euler")[0]).real)
    np.testing.assert_allclose(euler, np.sort(1 + lam * dt), rtol=1e-12)


def test_table2_double_precision_row():
    a, b, _, _ = lti_matrices(TABLE1_REFINED)
    poles = np.sort(np.linalg.eigvals(discretize(a, b, 0.5, "zoh")[0]).real)[::-1]
    np.testing.assert_allclose(poles, [0.9978, 0.9940, 0.9874, 0.9361], atol=5e-5)


@pytest.mark.parametrize("method", ["zoh", "tustin", "euler"])
def test_discrete_models_keep_the_dc_gain(method):
    a, b, _, _ = lti_matrices(TABLE1_REFINED)
    a_d, b_d = discretize(a, b, 1.0, method)
    np.testing.assert_allclose(np.linalg.solve(np.eye(4) - a_d, b_d), -np.linalg.solve(a, b), rtol=1e-9)


def test_copper_losses_follow_eqs_3_to_5():
    assert copper_losses(1000.0, 200.0, 20.0) == pytest.approx(1200.0)
    hot = copper_losses(1000.0, 200.0, 120.0)
    assert hot == pytest.approx(1000 * 1.39 + 200 / 1.39)


def test_stator_split_eqs_6_to_8():
    p = TABLE1
    k = stator_split_factor(p, 0.5, 0.5)
    assert k == pytest.approx(0.775 - 0.04 - 0.004 - 0.115 * 0.25)
    losses = node_losses(p, 100.0, 0.0, 1000.0, 50.0, 0.5, 0.5, 20.0)
    np.testing.assert_allclose(losses, [1000 * k, 100.0, 1000 * (1 - k), 50.0])
