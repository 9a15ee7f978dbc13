"""Kinds of virtual thermal plant (bench.drive.virtual.plants): the registry, lptn4 as the default, and the
distributed network of examples/suite/ipm-60kw-distributed (energy balance, step size and an ODE solver, positions
and sensor columns, loss placement, bad tables)."""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.drive.mapping import load_mapping
from bench.drive.virtual import VirtualPlantError, virtual_plant
from bench.drive.virtual.plants import PLANT_KINDS, LossComponents, StepInputs
from bench.drive.virtual.plants import correlations as corr
from bench.motor.description import motor_from_dict

ROOT = Path(__file__).resolve().parents[3]
IPM = ROOT / "examples" / "motor-ipm" / "motor.json"
EXAMPLE = ROOT / "examples" / "suite" / "ipm-60kw-distributed"
BALANCE = 0.005          # total losses = heat to coolant + heat to ambient, within 0.5 %
SHORT = [{"kind": "constant", "torque_Nm": 100, "speed_rpm": 3000, "duration_s": 900}]
VARIANTS = {
    "water": {},
    "air": {"cooling": {"kind": "air", "air_speed_m_s": 10.0, "fins": 40, "fin_height_mm": 25.0,
                        "fin_thickness_mm": 3.0}},
    "outer": {"rotor": "outer", "geometry": {"stator_back_diameter_mm": 90.0, "shaft_diameter_mm": 25.0,
                                             "bearing_outer_diameter_mm": 50.0, "magnet_depth_mm": 0.0,
                                             "rotor_back_iron_mm": 12.0}},
}


def distributed_dict(variant: str = "water", profiles=None) -> dict:
    content = json.loads((EXAMPLE / "motor.json").read_text(encoding="utf-8"))
    thermal = content["virtual_plant"]["thermal"]
    for key, value in VARIANTS[variant].items():
        if key == "geometry":
            thermal["geometry"].update(value)
        else:
            thermal[key] = value
    if profiles is not None:
        content["virtual_plant"]["profiles"] = profiles
    return content


def short_profiles(coolant: float = 25.0) -> list[dict]:
    return [{"name": "short", "role": "train", "coolant_C": coolant, "phases": copy.deepcopy(SHORT)}]


@pytest.fixture(scope="module")
def plant():
    return virtual_plant(motor_from_dict(distributed_dict(profiles=short_profiles())))


@pytest.fixture(scope="module")
def short_run(plant):
    return plant.simulate(plant.profiles[0])


def operating_point(plant, torque: float, speed: float) -> dict[str, float]:
    op = plant.operating_point(np.array([torque]), np.array([speed]))
    return {k: float(np.ravel(v)[0]) for k, v in op.items()}


def imbalance(total: float, flows: dict[str, float]) -> float:
    return abs(total - flows["coolant"] - flows["ambient"]) / total


# ------------------------------------------------------------------ the registry and lptn4
def test_the_kinds_are_registered_and_an_unknown_one_is_one_sentence():
    assert PLANT_KINDS.names() == ("lptn4", "distributed")
    content = json.loads(IPM.read_text(encoding="utf-8"))
    content["virtual_plant"]["thermal"]["kind"] = "fem"
    with pytest.raises(VirtualPlantError, match=r"m.json: virtual_plant.thermal.kind 'fem' is not one of lptn4, "
                                                r"distributed$"):
        virtual_plant(motor_from_dict(content, Path("m.json")))


def test_lptn4_is_the_default_and_kind_lptn4_changes_nothing():
    content = json.loads(IPM.read_text(encoding="utf-8"))
    content["virtual_plant"]["profiles"] = short_profiles(40.0)
    implicit = virtual_plant(motor_from_dict(content))
    content["virtual_plant"]["thermal"]["kind"] = "lptn4"
    explicit = virtual_plant(motor_from_dict(content))
    assert implicit.thermal.kind == explicit.thermal.kind == "lptn4"
    a, b = implicit.simulate(implicit.profiles[0]), explicit.simulate(explicit.profiles[0])
    assert implicit.csv_bytes(a.measured) == explicit.csv_bytes(b.measured)
    assert a.losses.shape[1] == 4 and a.truth["winding"].max() > 80.0


@pytest.mark.parametrize("sabotage", [False, True])
def test_lptn4_energy_balance(sabotage, monkeypatch):
    """Steady state at fixed node losses: the losses leave through R_cy to the coolant and R_ma to the ambient. A
    network that counts the yoke-coolant conductance twice on its diagonal loses heat, and the check sees it."""
    import bench.drive.plant as plant_module

    content = json.loads(IPM.read_text(encoding="utf-8"))
    lptn = virtual_plant(motor_from_dict(content)).thermal
    if sabotage:
        honest = plant_module.pv_network

        def double_counted(p, speed_ratio, coolant_c):
            g, g_cy, g_ma = honest(p, speed_ratio, coolant_c)
            g = g.copy()
            g[..., 0, 0] -= g_cy
            return g, g_cy, g_ma

        monkeypatch.setattr(plant_module, "pv_network", double_counted)
    losses = np.array([300.0, 1500.0, 200.0, 60.0])
    x = lptn.steady(losses, 6000.0, 40.0, 25.0)
    flows = lptn.heat_flows(x, 6000.0, 40.0, 25.0)
    if sabotage:
        assert imbalance(losses.sum(), flows) > 0.1
    else:
        assert imbalance(losses.sum(), flows) < BALANCE
        assert flows["coolant"] > 10 * flows["ambient"] > 0


# ------------------------------------------------------------------ the distributed network
@pytest.mark.parametrize("variant, torque, speed", [("water", 100.0, 3000.0), ("water", 40.0, 9000.0),
                                                    ("air", 30.0, 3000.0), ("outer", 60.0, 3000.0),
                                                    ("outer", 30.0, 9000.0)])
def test_distributed_energy_balance(variant, torque, speed):
    """At steady state the losses (copper at their temperatures, iron, magnets, bearings, windage) leave as the
    coolant's enthalpy rise ṁc_p(T_out - T_in) and as heat to the ambient, within 0.5 %."""
    plant = virtual_plant(motor_from_dict(distributed_dict(variant, short_profiles())))
    thermal = plant.thermal
    x, p = thermal.steady(operating_point(plant, torque, speed), speed, 25.0, 24.0, plant.loss_components())
    flows = thermal.heat_flows(x, speed, 25.0, 24.0)
    assert thermal.net.size >= 30 and p.sum() > 300.0
    assert imbalance(p.sum(), flows) < BALANCE
    assert flows["coolant"] > flows["ambient"] > 0
    assert x[thermal.ids["coolant"][-1]] > x[thermal.ids["coolant"][0]] > 25.0      # warms along its path


def test_a_double_counted_coolant_conductance_breaks_the_balance(plant, monkeypatch):
    """The housing-coolant film counted twice on the housing's diagonal (heat leaves the housing but never reaches
    the water): the enthalpy balance is off by far more than 0.5 %."""
    thermal = plant.thermal
    honest = thermal.net.matrices
    pairs = list(zip(thermal.ids["housing"], thermal.ids["coolant"], strict=True))

    def double_counted(cond):
        g, e = honest(cond)
        g = g.copy()
        for h, c in pairs:
            g[h, h] -= g[h, c]
        return g, e

    monkeypatch.setattr(thermal.net, "matrices", double_counted)
    x, p = thermal.steady(operating_point(plant, 100.0, 3000.0), 3000.0, 25.0, 24.0, plant.loss_components())
    assert imbalance(p.sum(), thermal.heat_flows(x, 3000.0, 25.0, 24.0)) > 0.2


def test_the_network_is_distributed(plant):
    thermal = plant.thermal
    assert thermal.net.size == 49 and thermal.slices == 4
    for layer in ("w_bot", "w_top", "tip", "body", "yoke_in", "yoke_back", "housing", "coolant", "rotor", "magnet"):
        assert len(thermal.ids[layer]) == 4, layer
    assert {"ew_a", "ew_b", "air_a", "air_b", "cap_a", "cap_b", "brg_a", "brg_b", "shaft"} <= set(thermal.node_names)
    caps = thermal.net.capacitances
    copper_kg = caps[thermal.copper_nodes].sum() / 385.0
    assert 5.0 < copper_kg < 15.0                 # slot-equivalent mass of a 60 kW stator winding (kg of copper)
    # conductances change with speed: the air gap (Taylor-Couette) and the end spaces, not the yoke
    g0, _ = thermal.matrices(0.0, 40.0)
    g9, _ = thermal.matrices(9000.0, 40.0)
    tip, rotor = thermal.ids["tip"][1], thermal.ids["rotor"][1]
    ew, air_a = thermal.ids["ew"][0], thermal.ids["air"][0]
    assert g9[tip, rotor] > 1.5 * g0[tip, rotor] and g9[ew, air_a] > 5 * g0[ew, air_a]
    yb, yi = thermal.ids["yoke_back"][1], thermal.ids["yoke_in"][1]
    assert g9[yb, yi] == g0[yb, yi]
    # the laminations conduct far less along the stack than across it
    assert g0[yb, thermal.ids["yoke_back"][2]] < 0.1 * g0[yb, yi]


def test_correlations():
    assert corr.airgap_nu(1000.0) == 2.0                                  # laminar Couette flow: conduction
    assert corr.airgap_nu(1699.0) == pytest.approx(corr.airgap_nu(1701.0), abs=0.1)
    assert corr.airgap_nu(9999.0) == pytest.approx(corr.airgap_nu(10001.0), rel=0.01)
    water = corr.water(40.0)
    assert water.mu == pytest.approx(6.53e-4, rel=0.03) and water.pr == pytest.approx(4.3, rel=0.05)
    dittus_boelter = 0.023 * 2e4 ** 0.8 * water.pr ** 0.4
    assert corr.gnielinski_nu(2e4, water.pr) == pytest.approx(dittus_boelter, rel=0.15)
    assert corr.gnielinski_nu(2000.0, 5.0) == corr.LAMINAR_NU
    assert corr.end_space_h(0.0, 15.0, 0.4, 0.9) == 15.0
    assert corr.end_space_h(30.0, 15.0, 0.4, 0.9) == pytest.approx(15.0 * (1 + 0.4 * 30 ** 0.9))
    assert 0.4 < corr.slot_conductivity(0.45, 390.0, 0.25) < 1.0          # Staton/Boglietti: 0.4-1.5 W/mK
    air = corr.air(60.0)
    # Couette friction below Re = 10⁴: C_f ∝ Re^-½, so windage ∝ ω^2.5
    ratio = corr.windage_W(1400.0, 0.079, 0.12, 0.00075, air) / corr.windage_W(700.0, 0.079, 0.12, 0.00075, air)
    assert ratio == pytest.approx(2 ** 2.5, rel=1e-9)


def test_losses_are_placed_where_they_arise(plant):
    thermal = plant.thermal
    assert thermal.dc_share.sum() == pytest.approx(1.0) and thermal.ac_share.sum() == pytest.approx(1.0)
    n = thermal.slices
    end_dc = thermal.dc_share[2 * n:]
    assert end_dc == pytest.approx([95.0 / 310.0] * 2)                  # conductor length: 120 mm + 2 × 95 mm
    top, bottom, ends = thermal.ac_share[n:2 * n], thermal.ac_share[:n], thermal.ac_share[2 * n:]
    np.testing.assert_allclose(top, 3 * bottom, rtol=1e-12)             # ac_top_share 0.75: the slot opening
    assert ends[0] == pytest.approx(0.3 * (top[0] + bottom[0]) * 95.0 / 30.0)      # end_ac_factor 0.3 per length
    magnet = thermal.magnet[thermal.ids["magnet"]]
    assert magnet.sum() == pytest.approx(1.0) and magnet[0] == pytest.approx(1.3 * magnet[1])
    assert thermal.iron.sum() == pytest.approx(1.0) and 0.3 < thermal.yoke_share < 0.7
    bearing, windage = thermal.mechanical(np.array([3000.0, 6000.0]))
    assert bearing[1] == pytest.approx(2 * bearing[0]) and bearing[0] == pytest.approx(0.05 * 3000 * np.pi / 30)
    assert 5.0 < windage[1] / windage[0] < 8.5 and windage[0] < 10.0


def test_halving_the_step_and_an_ode_solver_agree():
    """Exact steps at h = 0.25 s and 0.125 s and an adaptive stiff ODE solver (BDF, the conductances and losses
    evaluated where it asks) agree within 0.05 K at every node over 20 min of ramps, 120 Nm and 9000 rpm, with the
    coolant inlet rising from 40 to 52 °C (the tabulated steps are interpolated in speed and inlet temperature)."""
    from scipy.integrate import solve_ivp

    plant = virtual_plant(motor_from_dict(distributed_dict(profiles=short_profiles())))
    thermal, components = plant.thermal, plant.loss_components()
    knots = ([0, 60, 560, 600, 1000, 1040, 1200], [0, 120, 120, 40, 40, 0, 0], [0, 4000, 4000, 9000, 9000, 0, 0])
    amb = 25.0

    def drive(t):
        return np.interp(t, knots[0], knots[1]), np.interp(t, knots[0], knots[2])

    def inlet(t):
        return 40.0 + 12.0 * np.asarray(t) / 1200.0

    def exact(h):
        n = int(round(1200 / h))
        mid = (np.arange(n) + 0.5) * h
        torque, speed = drive(mid)
        steps = StepInputs(plant.operating_point(torque, speed), speed, inlet(mid), np.full(n, amb), h)
        return thermal.simulate(steps, components, 40.0, int(round(1 / h))).states

    fine = np.arange(0.0, 1200.001, 0.05)
    op = plant.operating_point(*drive(fine))
    place, caps = thermal.placer(components), thermal.net.capacitances

    def rhs(t, x):
        _, speed = drive(t)
        g, e = thermal.matrices(float(speed), float(inlet(t)))
        inputs = tuple(float(np.interp(t, fine, op[k])) for k in LossComponents.INPUTS)
        bearing, windage = thermal.mechanical(float(speed))
        p, _ = place(x, inputs, float(bearing), float(windage))
        return (g @ x + e @ np.array([float(inlet(t)), amb]) + p) / caps

    def jac(t, x):
        return thermal.matrices(float(drive(t)[1]), float(inlet(t)))[0] / caps[:, None]

    x = np.full(thermal.net.size, 40.0)
    ode = [x]
    for lo, hi in zip(knots[0][:-1], knots[0][1:], strict=True):    # restart at the corners of the ramps
        sol = solve_ivp(rhs, (lo, hi), x, method="BDF", jac=jac, rtol=1e-8, atol=1e-7,
                        t_eval=np.arange(lo, hi + 0.5, 1.0))
        assert sol.success
        ode.extend(sol.y.T[1:])
        x = sol.y[:, -1]
    ode = np.array(ode)
    coarse, half = exact(0.25), exact(0.125)
    assert coarse.shape == ode.shape == (1201, thermal.net.size)
    assert coarse.max() > 100.0                                     # it got hot: the comparison means something
    assert np.abs(coarse - half).max() < 0.05
    assert np.abs(coarse - ode).max() < 0.05 and np.abs(half - ode).max() < 0.05


# ------------------------------------------------------------------ positions and sensor columns
def test_the_example_heats_plausibly_and_the_columns_read_their_positions(plant, short_run):
    truth, measured = short_run.truth, short_run.measured
    assert 60.0 < truth["winding"][-1] < 130.0 and 10.0 < truth["magnet"][-1] - 25.0 < 50.0   # 15 min, 25 °C
    end = -1
    assert truth["winding"][end] > truth["at:winding.slot_mid"][end] > truth["tooth"][end] > truth["yoke"][end]
    assert truth["yoke"][end] > truth["at:housing"][end] > truth["coolant_out"][end] > truth["coolant"][end]
    noise = {c.name: c.noise for c in plant.columns}
    for column, key in (("stator_winding_1", "winding"), ("stator_winding_2", "at:winding.end_a"),
                        ("slot_mid", "at:winding.slot_mid"), ("housing", "at:housing"),
                        ("coolant_out", "coolant_out"), ("pm", "at:magnet")):
        residual = measured[column] - truth[key]
        assert abs(residual.mean()) < 0.1 and residual.std() == pytest.approx(noise[column], rel=0.15), column
    assert short_run.losses.shape == (900, 5) and np.all(short_run.losses[-100:, 4] > 0)   # bearings, windage


def test_the_files_load_through_the_example_mapping(plant, short_run, tmp_path):
    """The extra thermocouples (slot_mid, housing, coolant_out) are columns the mapping leaves alone."""
    from bench.drive.virtual import generate_profiles

    index = generate_profiles(plant, tmp_path)
    assert [c.get("at") for c in index["columns"]][2:4] == ["winding.end_b", "winding.end_a"]
    data = load_dataset(tmp_path / "short.csv", load_mapping(EXAMPLE / "mapping.json"), sample_period_s=1.0)
    truth = short_run.truth
    mean = 0.5 * (truth["winding"] + truth["at:winding.end_a"])
    np.testing.assert_allclose(data.column("winding_C"), mean, atol=0.6)
    np.testing.assert_allclose(data.column("pm_C"), truth["at:magnet"], atol=1.5)


@pytest.mark.parametrize("column, words", [
    ({"at": "winding.middle"}, "columns[2].at 'winding.middle' is not a position of the distributed plant; "
                               "positions: winding.slot_bottom, winding.slot_top"),
    ({"signal": "temperature", "unit": "°C", "gradient": 0.0}, "columns[2].at is needed for signal 'temperature'"),
])
def test_a_bad_sensor_position_is_one_sentence(column, words):
    content = distributed_dict(profiles=short_profiles())
    content["virtual_plant"]["columns"][2].update(column)
    if "at" not in column:
        del content["virtual_plant"]["columns"][2]["at"]
    with pytest.raises(VirtualPlantError) as err:
        virtual_plant(motor_from_dict(content, Path("m.json")))
    assert words in str(err.value) and "\n" not in str(err.value)


def test_positions_belong_to_temperatures_and_lptn4_has_no_coolant_outlet():
    content = distributed_dict(profiles=short_profiles())
    content["virtual_plant"]["columns"][0]["at"] = "housing"             # u_q
    with pytest.raises(VirtualPlantError, match=r"columns\[0\].at applies to the plant's temperature signals only"):
        virtual_plant(motor_from_dict(content))
    content = json.loads(IPM.read_text(encoding="utf-8"))
    content["virtual_plant"]["columns"].append({"name": "out", "signal": "coolant_out", "unit": "°C",
                                                "resolution": 0.01, "noise": 0.0})
    with pytest.raises(VirtualPlantError, match=r"columns\[14\].at is needed for signal 'coolant_out' \(a lptn4 "
                                                r"plant has no default position for it\); positions: yoke, winding, "
                                                r"tooth, magnet$"):
        virtual_plant(motor_from_dict(content))


@pytest.mark.parametrize("key, value, words", [
    ("slices", 3, "virtual_plant.thermal.slices must be a whole number from 4 to 20, not 3"),
    ("rotor", "middle", "virtual_plant.thermal.rotor 'middle' is not one of inner, outer"),
    ("cooling", {"kind": "oil"}, "virtual_plant.thermal.cooling.kind 'oil' is not one of water_jacket, air"),
    ("geometry.slots", KeyError, "virtual_plant.thermal.geometry.slots must be a whole number"),
    ("geometry.stator_back_diameter_mm", 200.0, "leaves a yoke of -4.0 mm"),
    ("geometry.flux", 1.0, "virtual_plant.thermal.geometry.flux is not a known key"),
    ("materials", {"copper": {"k_W_mK": -1}}, "virtual_plant.thermal.materials.copper.k_W_mK must be positive"),
    ("cooling.turns", 9, "virtual_plant.thermal.cooling.turns × channel_width_mm exceeds the stack length"),
    ("magic", 1, "virtual_plant.thermal.magic is not a known key"),
])
def test_a_bad_distributed_table_is_one_sentence(key, value, words):
    content = distributed_dict(profiles=short_profiles())
    node = content["virtual_plant"]["thermal"]
    *path, last = key.split(".")
    for part in path:
        node = node[part]
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    with pytest.raises(VirtualPlantError) as err:
        virtual_plant(motor_from_dict(content, Path("m.json")))
    message = str(err.value)
    assert words in message and message.startswith("motor file m.json: ") and "\n" not in message


# ------------------------------------------------------------------ the designer's prior
def test_the_lumped_prior_is_a_valid_lptn_close_to_the_plant_at_half_speed(plant):
    """The 22 parameters pass the motor file's checks, the capacitances are the groups' sums, and at half the top
    speed the four-node network's steady state is within 25 % of the plant's group means (rise above coolant)."""
    from bench.drive.plant import steady_state
    from bench.drive.virtual.plants.lump import ORDER, _injections, designer_prior, group_nodes
    from bench.motor.description import prior_parameters

    thermal = plant.thermal
    prior = designer_prior(thermal, 14000.0)
    params, _ = prior_parameters(prior.parameters.as_dict(), "lumped")
    nodes = group_nodes(thermal)
    caps = thermal.net.capacitances
    assert params.C_w == pytest.approx(caps[nodes["winding"]].sum()) and params.k_0 == thermal.yoke_share
    assert sum(len(v) for v in nodes.values()) == thermal.net.size - len(thermal.ids["coolant"]) - 2   # not fluids
    losses = np.array([300.0, 1800.0, 250.0, 60.0])
    g, e = thermal.matrices(7000.0, 40.0)
    x = np.linalg.solve(g, -(e @ np.array([40.0, 40.0]) + _injections(thermal, nodes) @ losses))
    means = np.array([x[nodes[k]] @ caps[nodes[k]] / caps[nodes[k]].sum() for k in ORDER])
    lumped = steady_state(params, losses, 0.5, 40.0, 40.0)
    np.testing.assert_allclose(lumped - 40.0, means - 40.0, rtol=0.25)
    assert max(prior.fit_error.values()) < 50.0


def test_bench_motor_lump(capsys):
    from bench.cli import main

    assert main(["motor", "lump", str(EXAMPLE / "motor.json"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["parameters"]) == set(json.loads(IPM.read_text())["thermal_prior"]["parameters"])
    assert main(["motor", "lump", str(IPM)]) == 1
    assert "bench motor lump lumps 'distributed' plants" in capsys.readouterr().err


@pytest.mark.parametrize("variant", ["air", "outer"])
def test_air_cooling_and_an_outer_rotor_run_a_profile(variant):
    """15 min at 40 Nm, 3000 rpm: the winding is the hottest, the fluid warms on its way, and an out-runner's
    magnets sit between the stator and its rotor back iron, which the outside air cools."""
    profiles = short_profiles()
    profiles[0]["phases"][0]["torque_Nm"] = 40
    content = distributed_dict(variant, profiles)
    content["virtual_plant"]["columns"].append({"name": "rotor", "signal": "temperature", "unit": "°C",
                                                "resolution": 0.01, "noise": 0.0, "at": "rotor"})
    plant = virtual_plant(motor_from_dict(content))
    run = plant.simulate(plant.profiles[0])
    truth = run.truth
    assert np.all(np.isfinite(run.measured["housing"])) and truth["winding"][-1] > truth["tooth"][-1] > 30.0
    assert truth["coolant_out"][-1] > truth["coolant"][-1] + 0.2
    if variant == "outer":
        assert truth["tooth"][-1] > truth["at:magnet"][-1] > truth["at:rotor"][-1] > truth["ambient"][-1]


PORTABLE_RUN = """
import hashlib, json, sys
import numpy as np
from bench.drive.virtual.schema import virtual_plant
from bench.motor.description import motor_from_dict
plant = virtual_plant(motor_from_dict(json.loads(open(sys.argv[1], encoding="utf-8").read())))
run = plant.simulate(plant.profiles[0])
digest = hashlib.sha256()
for name in sorted(run.truth):
    digest.update(np.ascontiguousarray(run.truth[name], dtype=float).tobytes())
digest.update(np.ascontiguousarray(run.losses, dtype=float).tobytes())
print(digest.hexdigest())
"""
# numpy's SIMD dispatch targets (names of numpy 1.2x and 2.x; a name a build lacks is ignored)
NUMPY_SIMD = "X86_V3,X86_V4,AVX512_ICL,AVX512_SPR,AVX512_SKX,AVX512F,AVX2,FMA3"


def test_a_suite_motor_is_the_same_bits_under_other_blas_and_simd_kernels(tmp_path):
    """The plant's linear algebra is bench.thermal.portable's, so a profile's float64 truth and losses do not depend
    on the machine: OpenBLAS's Haswell kernel (FMA) and its Sandybridge kernel with numpy's AVX2/AVX-512 loops off
    give the same bytes. (With numpy's and scipy's BLAS calls, as before, the three digests of this profile under
    Haswell, SkylakeX and Sandybridge were all different.)"""
    content = json.loads((ROOT / "examples" / "suite" / "air-30kw" / "motor.json").read_text(encoding="utf-8"))
    content["virtual_plant"]["profiles"] = [{
        "name": "steps", "role": "train", "coolant_C": 45,
        "phases": [{"kind": "random_steps", "seed": 210, "count": 6, "torque_Nm": [0.0, 33.0],
                    "speed_rpm": [600.0, 11400.0], "hold_s": [60, 300]}]}]
    motor = tmp_path / "motor.json"
    motor.write_text(json.dumps(content), encoding="utf-8")
    digests = []
    for env in ({"OPENBLAS_CORETYPE": "Haswell"},
                {"OPENBLAS_CORETYPE": "Sandybridge", "NPY_DISABLE_CPU_FEATURES": NUMPY_SIMD}):
        done = subprocess.run([sys.executable, "-c", PORTABLE_RUN, str(motor)], capture_output=True, text=True,
                              env={**os.environ, **env}, cwd=ROOT, timeout=600)
        assert done.returncode == 0, done.stderr
        digests.append(done.stdout.strip())
    assert digests[0] == digests[1]
