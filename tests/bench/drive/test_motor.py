from __future__ import annotations

import json

import numpy as np
import pytest

from bench.drive.motor import VIRTUAL_MOTOR, LossMaps, nominal_loss_maps, parametric_losses, phase_current

MAPS = nominal_loss_maps()


def test_spec_is_a_200_kW_machine():
    spec = VIRTUAL_MOTOR
    assert spec.rated_power_W == 200e3
    assert spec.peak_torque_Nm * spec.base_speed_rpm * 2 * np.pi / 60 == pytest.approx(200e3)
    assert spec.torque_limit(spec.max_speed_rpm) == pytest.approx(200e3 / (spec.max_speed_rpm * 2 * np.pi / 60))
    assert phase_current(spec, spec.peak_torque_Nm, 1000.0) == pytest.approx(spec.i_max_A)


def test_field_weakening_current_only_above_base_speed():
    base = VIRTUAL_MOTOR.base_speed_rpm
    assert phase_current(VIRTUAL_MOTOR, 0.0, 0.99 * base) == 0.0
    assert phase_current(VIRTUAL_MOTOR, 0.0, VIRTUAL_MOTOR.max_speed_rpm) > 0.2 * VIRTUAL_MOTOR.i_max_A


def test_maps_cover_the_plane_and_reproduce_grid_nodes():
    assert MAPS.torque_Nm[0] == -VIRTUAL_MOTOR.peak_torque_Nm and MAPS.torque_Nm[-1] == VIRTUAL_MOTOR.peak_torque_Nm
    assert MAPS.speed_rpm[0] == 0 and MAPS.speed_rpm[-1] == VIRTUAL_MOTOR.max_speed_rpm
    assert MAPS.tables["p_dc0"].shape == (21, 16)
    tq, sp = np.meshgrid(MAPS.torque_Nm, MAPS.speed_rpm, indexing="ij")
    got = MAPS.evaluate(tq, sp)
    for name, table in MAPS.tables.items():
        np.testing.assert_array_equal(got[name], table)
    np.testing.assert_allclose(MAPS.tables["p_stator"], MAPS.tables["p_stator"][::-1], rtol=1e-12)  # ± torque


def test_bilinear_interpolation_and_clamping():
    i, j = 13, 5
    t0, t1 = MAPS.torque_Nm[i], MAPS.torque_Nm[i + 1]
    s0, s1 = MAPS.speed_rpm[j], MAPS.speed_rpm[j + 1]
    tab = MAPS.tables["p_dc0"]
    mid = MAPS.evaluate(t0 + 0.25 * (t1 - t0), s0 + 0.5 * (s1 - s0))["p_dc0"]
    expected = 0.75 * 0.5 * (tab[i, j] + tab[i, j + 1]) + 0.25 * 0.5 * (tab[i + 1, j] + tab[i + 1, j + 1])
    assert mid == pytest.approx(expected, rel=1e-12)
    outside = MAPS.evaluate(np.array([2000.0, -2000.0]), np.array([20000.0, -5.0]))["current"]
    assert list(outside) == [MAPS.tables["current"][-1, -1], MAPS.tables["current"][0, 0]]


def test_maps_are_close_to_the_parametric_model_between_nodes():
    rng = np.random.default_rng(0)
    tq = rng.uniform(-640, 640, 500)
    sp = rng.uniform(0, 9000, 500)
    exact = parametric_losses(VIRTUAL_MOTOR, tq, sp)
    approx = MAPS.evaluate(tq, sp)
    total = lambda d: d["p_dc0"] + d["p_ac0"] + d["p_stator"] + d["p_magnet"]  # noqa: E731
    assert np.max(np.abs(total(approx) - total(exact))) < 0.05 * total(exact).max()


def test_dict_round_trip_through_json():
    again = LossMaps.from_dict(json.loads(json.dumps(MAPS.to_dict())))
    for name in MAPS.tables:
        np.testing.assert_array_equal(again.tables[name], MAPS.tables[name])
    np.testing.assert_array_equal(again.speed_rpm, MAPS.speed_rpm)


def test_bad_maps_are_rejected():
    data = MAPS.to_dict()
    data["tables"]["current"] = data["tables"]["current"][:-1]
    with pytest.raises(ValueError, match="table current has shape"):
        LossMaps.from_dict(data)
