"""The observer's measurement kinds (target_sim.observer.measurements) and their calibrations (bench.observer.measures):
each kind's float32 reading, the flux-linkage calibration recovering ψ_0, α_B, L_d and R_s, and the winding-resistance
calibration recovering R_s0 and L_q from synthetic voltages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bench.errors import BenchError, UsageError
from bench.observer.measures import LAB_MEASUREMENT_KINDS, kind_of
from bench.observer.measures.flux_linkage import FluxLinkage, calibrate_flux
from bench.observer.measures.lagged_sensor import Sensor
from bench.observer.measures.winding_resistance import WindingResistance, calibrate_resistance
from target_sim.observer.measurements import MEASUREMENT_KINDS
from target_sim.observer.measurements.flux_linkage import RAD_S_PER_RPM

F32 = np.float32
PSI_0, ALPHA_B, L_D, L_Q, R_S, ALPHA_CU, POLES = 0.065, -0.0011, 1.5e-4, 3.5e-4, 0.0158, 0.0039, 4


def test_the_kinds_are_registered_by_name():
    assert MEASUREMENT_KINDS.names() == ("lagged-sensor", "flux-linkage", "winding-resistance")
    assert LAB_MEASUREMENT_KINDS.names() == MEASUREMENT_KINDS.names()     # the lab's side of each


CALIBRATION = {"steps": 40, "fitted": ["psi_0", "slope"], "residual_rms_K": 0.5, "residual_max_K": 1.25}


@pytest.mark.parametrize(("lab", "r", "stored"), [
    (Sensor("winding", "ntc_C", offset_C=0.8, lag_s=25.0, gradient=-0.12), 0.37, 0.37),
    (Sensor("magnet", "pm_C"), 2.5, 2.5),
    (FluxLinkage(0.065, -0.0011, 20.0, 1.5e-4, 0.0158, 0.0039, 20.0, 4.0, 1500.0, 0.5, 4.0, CALIBRATION), 3.0, 1.0),
    (WindingResistance(0.0158, 0.0039, 20.0, 3.5e-4, 4.0, 2000.0, 50.0, 9.0, 900.0, CALIBRATION), 3.0, 1.0),
])
def test_the_lab_reads_back_the_entry_it_writes(lab, r, stored):
    """An artifact's entry read back by its lab kind is the measurement with the tuned R folded in where the kind
    folds it (the flux linkage's R_floor and R_speed) and stored apart otherwise (a sensor's R)."""
    kind = kind_of(lab)
    entry = lab.entry(0.5, r)
    back = kind.from_entry(entry, 0.5)
    assert kind.stored_r(entry) == stored and back.kind == lab.kind and back.columns == lab.columns
    assert back.describe().keys() == lab.describe().keys()
    if isinstance(lab, Sensor):
        assert back == Sensor(lab.node, lab.column, lab.offset_C, pytest.approx(lab.lag_s, rel=1e-12), lab.gradient)
        assert back.calibration_text() is None
    elif isinstance(lab, WindingResistance):
        assert (back.R_floor_C2, back.R_current_C2) == (r * lab.R_floor_C2, r * lab.R_current_C2)
        assert (back.R_s_ohm, back.L_q_H, back.current_min_A, back.calibration) == (0.0158, 3.5e-4, 50.0, CALIBRATION)
        assert back.calibration_text() == ("winding resistance: R_s 0.0158 ohm, L_q 0.00035 H (fitted psi_0, slope) "
                                           "on 40 steps at or below 2000 rpm with |i_d| >= 50 A; residual RMS 0.50 "
                                           "K, max 1.2 K")
    else:
        assert (back.R_floor_C2, back.R_speed_C2) == (r * lab.R_floor_C2, r * lab.R_speed_C2)
        assert (back.psi_0_Vs, back.speed_min_rpm, back.calibration) == (lab.psi_0_Vs, 1500.0, CALIBRATION)
        assert back.calibration_text() == ("flux linkage: psi_0 0.065 Vs, alpha_B -0.0011 /K, L_d 0.00015 H, R_s "
                                           "0.0158 ohm (fitted psi_0, slope) on 40 steps at or above 1500 rpm; "
                                           "residual RMS 0.50 K, max 1.2 K")


def _target(lab, dt=1.0, r=0.5):
    entry = lab.entry(dt, r)
    return MEASUREMENT_KINDS[entry["kind"]].load(entry, "observer.measurements[0]", F32)


def test_a_lagged_sensor_reads_its_node_mix_less_its_offset():
    ntc = _target(Sensor("winding", "ntc_C", offset_C=0.8, lag_s=25.0, gradient=-0.12))
    assert ntc.width == 1 and ntc.lag_pole == pytest.approx(math.exp(-1 / 25), rel=1e-6)
    assert np.allclose(ntc.sees, [0.12, 0.88, 0.0, 0.0])
    z, r = ntc.reading(np.array([80.8], dtype=F32), F32(3000), np.zeros(4, dtype=F32))
    assert z == pytest.approx(80.0, abs=1e-5) and r == pytest.approx(0.5)
    assert ntc.reading(np.array([np.nan], dtype=F32), F32(3000), np.zeros(4, dtype=F32)) is None
    assert _target(Sensor()).lag_pole == 0


def _flux(speed_min=1500.0) -> FluxLinkage:
    return FluxLinkage(PSI_0, ALPHA_B, 20.0, L_D, R_S, ALPHA_CU, 20.0, POLES, speed_min, 0.5, 4.0)


def _voltages(speed_rpm, i_d, i_q, magnet, winding):
    omega = POLES * RAD_S_PER_RPM * speed_rpm
    r = R_S * (1 + ALPHA_CU * (winding - 20.0))
    psi = PSI_0 * (1 + ALPHA_B * (magnet - 20.0))
    return r * i_d - omega * L_Q * i_q, r * i_q + omega * (psi + L_D * i_d)


def test_the_flux_linkage_inverts_the_voltage_equation_above_its_speed():
    flux = _target(_flux(), r=1.0)
    y = np.array([60.0, 95.0, 70.0, 0.0], dtype=F32)          # winding estimate 95 °C
    for speed in (1500.0, 4000.0, 9000.0):
        u_d, u_q = _voltages(speed, -120.0, 250.0, 85.0, 95.0)
        z, r = flux.reading(np.array([u_d, u_q, -120.0, 250.0], dtype=F32), F32(speed), y)
        assert z == pytest.approx(85.0, abs=0.05)       # float32 rounding of u_q/ω: hundredths of a kelvin
        assert r == pytest.approx(0.5 + 4.0 * (1500.0 / speed) ** 2, rel=1e-5)
    assert flux.reading(np.array([0.0, 5.0, 0.0, 10.0], dtype=F32), F32(1000.0), y) is None
    assert flux.reading(np.array([0.0, np.nan, 0.0, 10.0], dtype=F32), F32(3000.0), y) is None


def test_the_folded_flux_reading_is_the_voltage_equation_to_float32_rounding():
    """The reading divides once (its constants folded at load); over random operating points it equals the
    unfolded formula in float64 on the same float32 inputs within 5e-4 °C (measured: 1.5e-4)."""
    flux = _target(_flux(), r=1.0)
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(2000):
        speed, i_d, i_q, winding = (F32(v) for v in (rng.uniform(1500, 12000), rng.uniform(-300, 0),
                                                      rng.uniform(-300, 300), rng.uniform(20, 150)))
        u_d, u_q = (F32(v) for v in _voltages(float(speed), float(i_d), float(i_q), rng.uniform(20, 150),
                                              float(winding)))
        z, _ = flux.reading(np.array([u_d, u_q, i_d, i_q], dtype=F32), speed, np.array([0, winding, 0, 0], dtype=F32))
        r_s = R_S * (1 + ALPHA_CU * (float(winding) - 20.0))
        psi = (float(u_q) - r_s * float(i_q)) / (POLES * RAD_S_PER_RPM * float(speed)) - L_D * float(i_d)
        worst = max(worst, abs(float(z) - (20.0 + (psi / PSI_0 - 1) / ALPHA_B)))
    assert worst < 5e-4


class _Data:
    """What the calibration reads of a dataset: columns per name, the sample period, a path."""

    def __init__(self, columns: dict, period: float = 1.0):
        self.columns, self.sample_period_s, self.path = columns, period, Path("synthetic.csv")

    def has(self, name):
        return name in self.columns

    def column(self, name):
        return self.columns[name]


def _synthetic(rows=3000, seed=3, noise_v=0.3):
    rng = np.random.default_rng(seed)
    speed = np.clip(4000 + np.cumsum(rng.normal(0, 80, rows)), 200, 12000)
    i_d = -np.abs(np.cumsum(rng.normal(0, 4, rows))) - 20
    i_q = 150 + 100 * np.sin(np.arange(rows) / 97.0)
    magnet = 40 + 60 * (1 - np.exp(-np.arange(rows) / 900.0))
    winding = 45 + 70 * (1 - np.exp(-np.arange(rows) / 400.0))
    u_d, u_q = _voltages(speed, i_d, i_q, magnet, winding)
    return _Data({"speed_rpm": speed, "u_d_V": u_d + rng.normal(0, noise_v, rows), "u_q_V": u_q + rng.normal(
        0, noise_v, rows), "i_d_A": i_d, "i_q_A": i_q, "pm_C": magnet, "winding_C": winding})


def test_the_calibration_recovers_psi_0_alpha_b_and_l_d():
    fit = calibrate_flux([_synthetic()], 1.0, POLES, ALPHA_CU, 20.0, 0.015)
    assert fit.psi_0_Vs == pytest.approx(PSI_0, rel=2e-3)
    assert fit.alpha_B_per_K == pytest.approx(ALPHA_B, rel=0.02)
    assert fit.L_d_H == pytest.approx(L_D, rel=0.05) and fit.R_s_ohm == pytest.approx(R_S, rel=0.1)
    assert fit.calibration["fitted"] == ["psi_0", "slope", "L_d", "R_s0"]
    # the residual is the voltage noise seen through ω ψ_0 α_B: about 0.3 V / (ω·7e-5 Vs/K), a few K at 4000 rpm
    assert 0.3 < fit.calibration["residual_rms_K"] < 5.0 and fit.R_speed_C2 > 0


def test_a_constant_d_current_leaves_l_d_to_the_given_value():
    data = _synthetic()
    data.columns["i_d_A"] = np.full_like(data.columns["i_d_A"], -50.0)
    u_d, u_q = _voltages(data.columns["speed_rpm"], -50.0, data.columns["i_q_A"], data.columns["pm_C"],
                         data.columns["winding_C"])
    data.columns["u_q_V"] = u_q
    fit = calibrate_flux([data], 1.0, POLES, ALPHA_CU, 20.0, 0.015, l_d_fixed=0.0)
    assert "L_d" not in fit.calibration["fitted"] and fit.L_d_H == 0.0
    # ψ_0 then absorbs L_d·i_d; the temperature slope is still the magnet's
    assert fit.alpha_B_per_K * fit.psi_0_Vs == pytest.approx(ALPHA_B * PSI_0, rel=0.02)


def test_too_few_fast_steps_is_one_sentence():
    data = _synthetic()
    data.columns["speed_rpm"] = np.full(3000, 500.0)
    with pytest.raises(BenchError, match="at or above 1500 rpm") as info:
        calibrate_flux([data], 1.0, POLES, ALPHA_CU, 20.0, 0.015)
    assert "\n" not in str(info.value)


def _resistance(speed_max=2000.0, current_min=50.0) -> WindingResistance:
    return WindingResistance(R_S, ALPHA_CU, 20.0, L_Q, POLES, speed_max, current_min, 4.0, 900.0)


def test_the_winding_resistance_inverts_the_d_voltage_at_low_speed_and_enough_current():
    """Steady-state voltages of a known winding temperature read back as it (float32), below the speed limit and
    where |i_d| is large enough; the variance grows as (i_min/i_d)²."""
    res = _target(_resistance(), r=1.0)
    assert res.width == 4 and res.lag_pole == 0 and np.array_equal(res.sees, [0, 1, 0, 0])
    y = np.zeros(4, dtype=F32)            # the reading does not use the estimate
    for speed, i_d, winding in ((0.0, -200.0, 60.0), (800.0, -120.0, 95.0), (2000.0, 80.0, 140.0)):
        u_d, u_q = _voltages(speed, i_d, 250.0, 85.0, winding)
        z, r = res.reading(np.array([u_d, u_q, i_d, 250.0], dtype=F32), F32(speed), y)
        # float32: u_d is a few volts of which the speed voltage cancels most: within a few hundredths of a kelvin
        assert z == pytest.approx(winding, abs=0.1)
        assert r == pytest.approx(4.0 + 900.0 * (50.0 / i_d) ** 2, rel=1e-5)
    u_d, u_q = _voltages(3000.0, -120.0, 250.0, 85.0, 95.0)
    assert res.reading(np.array([u_d, u_q, -120.0, 250.0], dtype=F32), F32(3000.0), y) is None     # too fast
    assert res.reading(np.array([0.1, 1.0, -20.0, 10.0], dtype=F32), F32(500.0), y) is None         # |i_d| < 50 A
    assert res.reading(np.array([0.1, np.nan, -120.0, 10.0], dtype=F32), F32(500.0), y) is None     # u_q invalid


def test_the_lab_readings_equal_the_target_reading():
    """The float64 readings per step the reference filter takes are the target's reading (to float32 rounding)."""
    data = _synthetic(rows=400)
    lab = _resistance(speed_max=6000.0)
    z0, z1, rel = lab.readings(data, 1.0, 400)
    target = _target(lab, r=1.0)
    raw = np.column_stack([data.columns[c] for c in lab.columns]).astype(F32)
    checked = 0
    for k in range(400):
        got = target.reading(raw[k], F32(data.columns["speed_rpm"][k]), np.zeros(4, dtype=F32))
        assert (got is None) == np.isnan(z0[k])
        if got is not None:
            checked += 1
            assert got[0] == pytest.approx(z0[k], abs=0.5) and got[1] == pytest.approx(rel[k], rel=1e-4)
    assert checked > 20 and not z1.any()


def _low_speed(rows=3000, seed=5, noise_v=0.05):
    data = _synthetic(rows, seed, noise_v)
    rng = np.random.default_rng(seed + 1)
    data.columns["speed_rpm"] = np.clip(900 + np.cumsum(rng.normal(0, 40, rows)), 0, 1900)
    data.columns["i_d_A"] = -60 - 150 * np.abs(np.sin(np.arange(rows) / 53.0))
    u_d, u_q = _voltages(data.columns["speed_rpm"], data.columns["i_d_A"], data.columns["i_q_A"],
                         data.columns["pm_C"], data.columns["winding_C"])
    data.columns["u_d_V"], data.columns["u_q_V"] = u_d + rng.normal(0, noise_v, rows), u_q
    return data


def test_the_resistance_calibration_recovers_r_s0_and_l_q():
    fit = calibrate_resistance([_low_speed()], 1.0, POLES, ALPHA_CU, 20.0)
    assert fit.R_s_ohm == pytest.approx(R_S, rel=2e-3) and fit.L_q_H == pytest.approx(L_Q, rel=2e-3)
    assert fit.calibration["fitted"] == ["R_s0", "L_q"] and fit.calibration["steps"] == 3000
    # the residual is the voltage noise through i_d R_s0 α_cu: 0.05 V / (60..210 A · 6.2e-5 Ω/K), a few K
    assert 1.0 < fit.calibration["residual_rms_K"] < 15.0 and fit.R_current_C2 > 0


def test_a_resistance_without_speed_voltage_leaves_l_q_to_the_given_value():
    data = _low_speed(noise_v=0.0)
    data.columns["speed_rpm"] = np.zeros(3000)
    data.columns["u_d_V"] = _voltages(0.0, data.columns["i_d_A"], 0.0, 0.0, data.columns["winding_C"])[0]
    fit = calibrate_resistance([data], 1.0, POLES, ALPHA_CU, 20.0, l_q_fixed=2e-4)
    assert "L_q" not in fit.calibration["fitted"] and fit.L_q_H == 2e-4
    assert fit.R_s_ohm == pytest.approx(R_S, rel=1e-9)


@pytest.mark.parametrize(("change", "said"), [
    ({"speed_rpm": np.full(3000, 5000.0)}, "have 0 model steps at or below 2000 rpm with |i_d| of at least 50 A; the "
                                           "winding-resistance calibration needs at least 20"),
    ({"u_d_V": np.random.default_rng(0).normal(0, 1.0, 3000)}, "the voltage columns do not carry the winding's "
                                                                 "resistance"),
])
def test_a_resistance_the_data_do_not_allow_is_one_sentence(change, said):
    data = _low_speed()
    data.columns.update(change)
    with pytest.raises(BenchError) as info:
        calibrate_resistance([data], 1.0, POLES, ALPHA_CU, 20.0)
    assert said in str(info.value) and "\n" not in str(info.value)


def _model_with_resistance(tmp_path, r_s: float):
    """The electrical test artifact with stator resistance r_s (what a calibration's fitted R_s0 is checked against)."""
    import json

    from target_sim.artifact import dumps, encode_array, load_artifact

    from helpers import electrical_artifact_text

    content = json.loads(electrical_artifact_text())
    content.pop("sha256")
    content["losses"]["stator_resistance_ohm"] = encode_array(r_s)
    path = tmp_path / "electrical.json"
    path.write_text(dumps(content), encoding="utf-8")
    return load_artifact(path)


def _asked(kind: str, force: bool = False):
    """`bench observer`'s options asking for the kind's calibration (pole pairs POLES)."""
    import argparse

    parser = argparse.ArgumentParser()
    LAB_MEASUREMENT_KINDS[kind].add_arguments(parser)
    flag = {"flux-linkage": "--flux", "winding-resistance": "--resistance"}[kind]
    force_flag = [f"{flag}-force"] if force else []
    return argparse.Namespace(**vars(parser.parse_args([flag, *force_flag])), pole_pairs=float(POLES))


CALIBRATED = {"flux-linkage": _synthetic, "winding-resistance": _low_speed}
MODEL_DT = 0.5       # the electrical test artifact's step: the synthetic files sampled at it, one sample per step


def _sampled_at_model_step(data: _Data) -> _Data:
    data.sample_period_s = MODEL_DT
    return data


@pytest.mark.parametrize("kind", ["flux-linkage", "winding-resistance"])
def test_a_fitted_resistance_far_from_the_models_is_refused_unless_forced(kind, tmp_path):
    """The calibration fits R_s0 = 15.8 mOhm where the model says a quarter of it: one sentence, exit 2; with the
    kind's force option the same sentence is a warning; against the model's own resistance, nothing."""
    data = _sampled_at_model_step(CALIBRATED[kind]())
    what, node = kind, {"flux-linkage": "magnet", "winding-resistance": "winding"}[kind]
    with pytest.raises(UsageError) as info:
        LAB_MEASUREMENT_KINDS[kind].from_arguments(_asked(kind), _model_with_resistance(tmp_path, R_S / 4), [data])
    said = str(info.value)
    assert said.startswith(f"the {what} calibration is useless: its fitted R_s 15.") and info.value.exit_status == 2
    assert "times the model's 3.95 mOhm, so its readings would make the " + node + " estimate worse" in said
    flag = {"flux-linkage": "--flux-force", "winding-resistance": "--resistance-force"}[kind]
    assert said.endswith(f", or give {flag} to use it anyway") and "\n" not in said
    forced = LAB_MEASUREMENT_KINDS[kind].from_arguments(_asked(kind, force=True),
                                                        _model_with_resistance(tmp_path, R_S / 4), [data])
    assert forced.warnings == (said.removesuffix(f", or give {flag} to use it anyway") + f"; used anyway ({flag})",)
    ok = LAB_MEASUREMENT_KINDS[kind].from_arguments(_asked(kind), _model_with_resistance(tmp_path, R_S), [data])
    assert ok.R_s_ohm == pytest.approx(R_S, rel=0.05)
    assert ok.warnings == (() if kind == "flux-linkage" else (
        "the winding-resistance calibration's residual is 6.4 K RMS (max 40 K), above 5 K: its readings may make "
        "the winding estimate worse; compare the observer with and without it (bench evaluate)",))


@pytest.mark.parametrize(("noise_v", "refused", "said"), [
    (1.5, False, "the flux-linkage calibration's residual is 7.2 K RMS (max 33 K), above 5 K: its readings may make "
                 "the magnet estimate worse; compare the observer with and without it (bench evaluate)"),
    (5.0, True, "the flux-linkage calibration is useless: its residual is 24.3 K RMS (max 110 K), above the 15 K it "
                "may have, so its readings would make the magnet estimate worse; check the voltage and current "
                "columns and --pole-pairs, or raise --flux-min-speed, or give --flux-force to use it anyway"),
])
def test_a_flux_calibration_residual_is_warned_or_refused(noise_v, refused, said, tmp_path):
    """Noisy voltages (1.5 V, 5 V): a residual above 5 K RMS is a warning, above 15 K a refusal (exit 2)."""
    kind, model = LAB_MEASUREMENT_KINDS["flux-linkage"], _model_with_resistance(tmp_path, R_S)
    data = [_sampled_at_model_step(_synthetic(noise_v=noise_v))]
    if refused:
        with pytest.raises(UsageError) as info:
            kind.from_arguments(_asked("flux-linkage"), model, data)
        assert str(info.value) == said
    else:
        assert kind.from_arguments(_asked("flux-linkage"), model, data).warnings == (said,)
