"""The virtual plant of a motor file (bench.drive.virtual) and `bench data --motor`, on examples/motor-ipm."""

from __future__ import annotations

import copy
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.drive.dataset import load_dataset
from bench.drive.virtual import VirtualPlantError, generate_profiles, load_virtual_plant, virtual_plant
from bench.motor.description import load_motor, motor_from_dict

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "motor-ipm"
MOTOR = EXAMPLE / "motor.json"
MAPPING = EXAMPLE / "mapping.json"
# 15 min at about the continuous rating, then the WLTC's extra-high phase: quick, and hot enough to matter
SHORT = [{"kind": "constant", "torque_Nm": 100, "speed_rpm": 3000, "duration_s": 900},
         {"kind": "cycle", "cycle": "wltc3b", "from_s": 1477, "to_s": 1795, "coolant_C": 35}]


def example_dict() -> dict:
    return json.loads(MOTOR.read_text(encoding="utf-8"))


def short_dict(coolant: float = 40.0) -> dict:
    content = example_dict()
    content["virtual_plant"]["profiles"] = [{"name": "short", "role": "train", "coolant_C": coolant,
                                             "phases": copy.deepcopy(SHORT)}]
    return content


@pytest.fixture(scope="module")
def short_plant():
    return virtual_plant(motor_from_dict(short_dict()))


@pytest.fixture(scope="module")
def short_run(short_plant):
    return short_plant.simulate(short_plant.profiles[0])


def mapping():
    from bench.drive.mapping import load_mapping

    return load_mapping(MAPPING)


def test_the_example_motor_loads_with_ten_mixed_profiles():
    motor = load_motor(MOTOR)
    assert motor.loss_kind == "electrical" and motor.limits.torque_Nm == 200.0
    plant = virtual_plant(motor)
    assert plant.sample_period_s == 1.0 and len(plant.profiles) == 10
    assert [p.role for p in plant.profiles].count("validate") == 2
    for p in plant.profiles:
        assert 40 * 60 <= p.duration_s <= 90 * 60, p.name
        assert all(20.0 <= c <= 70.0 for c in p.setpoints_C)
    kinds = {ph.kind for p in plant.profiles for ph in p.phases}
    cycles = {ph.cycle for p in plant.profiles for ph in p.phases if ph.kind == "cycle"}
    assert kinds == {"cycle", "constant", "steps", "rest"} and cycles == {"ftp75", "wltc3b"}
    # the designer's prior is the truth perturbed, inside the identification's bounds around it
    truth, prior = plant.params.as_dict(), motor.prior.parameters.as_dict()
    low, high = motor.prior.bounds
    for name, value in truth.items():
        ratio = value / prior[name]
        assert 1 / 1.45 < ratio < 1 / 0.7 and abs(ratio - 1) > 0.05, name
        if name[:2] in ("C_", "R_", "a_"):
            assert low < ratio < high, name
    signals = [c.signal for c in plant.columns]
    assert signals.count("winding") == 2 and "time" not in [c.name for c in plant.columns]


def test_the_machine_follows_mtpa_and_field_weakening(short_plant):
    dq, m = short_plant.dq, short_plant.machine
    speed = np.linspace(0.0, 14000.0, 57)
    torque = dq.torque_limit(speed)
    i_d, i_q, ok = dq.currents(torque, speed)
    assert ok.all() and np.all(i_d < 0) and np.all(np.hypot(i_d, i_q) <= 400.0 + 1e-6)
    produced = 1.5 * 4 * (m.flux_linkage_Vs * i_q + (m.L_d_H - m.L_q_H) * i_d * i_q)
    np.testing.assert_allclose(produced, torque, rtol=1e-9)
    u_d, u_q = dq.voltages(i_d, i_q, speed, 1.0, 0.0)
    assert np.all(np.hypot(u_d, u_q) <= m.voltage_limit_V * (1 + 1e-9))
    assert np.hypot(u_d, u_q)[-1] == pytest.approx(m.voltage_limit_V)      # field weakening at top speed
    # a hotter magnet (less flux) needs more current for the same torque
    hot_d, hot_q, _ = dq.currents(150.0, 2000.0, 0.9)
    cold_d, cold_q, _ = dq.currents(150.0, 2000.0, 1.0)
    assert np.hypot(hot_d, hot_q) > np.hypot(cold_d, cold_q)
    # regeneration: negative i_q, same i_d
    neg_d, neg_q, _ = dq.currents(-150.0, 2000.0)
    assert neg_q == pytest.approx(-cold_q) and neg_d == pytest.approx(cold_d)


def test_a_hard_short_profile_heats_the_machine_sensibly(short_run):
    truth = short_run.truth
    rise = short_run.rise_K()
    assert 40.0 < rise["winding"] < 100.0
    assert 10.0 < rise["magnet"] < rise["winding"]
    cool = truth["coolant"]
    assert np.all(truth["winding"] >= truth["yoke"] - 0.5)
    assert np.all(truth["yoke"] > cool - 1.0)
    assert abs(truth["winding"][0] - 40.0) < 1e-9                   # soaked at the first set point
    assert abs(cool[-1] - 35.0) < 2.0                                   # followed the set point change
    assert np.all(np.abs(truth["torque"]) <= 200.0) and truth["speed"].max() <= 14000.0
    # the controller limits |u| with the cold winding's resistance; a hot winding adds a little
    assert np.hypot(truth["u_d"], truth["u_q"]).max() <= 1.02 * 230.0


def test_generation_is_deterministic_per_seed(short_plant, short_run):
    profile = short_plant.profiles[0]
    again = short_plant.simulate(profile)
    first = short_plant.csv_bytes(short_run.measured)
    assert short_plant.csv_bytes(again.measured) == first
    other = short_plant.simulate(profile, seed=short_plant.seed + 1)
    assert short_plant.csv_bytes(other.measured) != first
    np.testing.assert_array_equal(other.truth["torque"], short_run.truth["torque"])


def test_written_files_load_through_the_mapping(short_plant, short_run, tmp_path):
    index = generate_profiles(short_plant, tmp_path)
    path = tmp_path / "short.csv"
    header = path.read_text().splitlines()[0].split(",")
    assert header[:3] == ["u_q", "coolant", "stator_winding_1"] and "time_s" not in header
    (entry,) = index["profiles"]
    assert entry["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert json.loads((tmp_path / "profiles.json").read_text()) == index
    assert index["roles"] == {"train": ["short.csv"], "validate": [], "test": []}
    assert entry["coolant_setpoints_C"] == [40.0, 35.0]
    assert [p["kind"] for p in entry["phases"]] == ["constant", "cycle"]
    data = load_dataset(path, mapping(), sample_period_s=1.0)
    truth = short_run.truth
    assert data.rows == len(short_run.time_s) == 900 + 318 + 1 and data.has_currents
    for column, signal, tolerance in (("winding_C", "winding", 0.6), ("pm_C", "magnet", 1.5),
                                      ("coolant_C", "coolant", 0.3), ("ambient_C", "ambient", 0.5),
                                      ("speed_rpm", "speed", 2.0), ("torque_Nm", "torque", 1.5),
                                      ("i_d_A", "i_d", 2.5), ("u_q_V", "u_q", 1.5), ("yoke_C", "yoke", 0.8)):
        np.testing.assert_allclose(data.column(column), truth[signal], atol=tolerance, err_msg=column)


def test_electrical_losses_from_the_files_are_close_to_but_not_the_truth(short_plant, short_run):
    """The estimator's nominal model, on the measured currents, misses what a Hammerstein nonlinearity learns."""
    truth = short_run.truth
    nominal = short_plant.nominal.evaluate_columns({"speed_rpm": truth["speed"], "i_d_A": truth["i_d"],
                                                    "i_q_A": truth["i_q"]})
    hold = slice(600, 870)                          # the constant phase, winding hot
    true_copper = short_run.losses[hold, 1]
    dc = nominal["p_dc0"][hold] * (1 + 0.0039 * (truth["winding"][hold] - 20))
    ratio = true_copper / (dc + nominal["p_ac0"][hold])
    assert np.all((1.3 < ratio) & (ratio < 1.5))    # resistance, copper load error: (1 + 1.0·(I/I_max)²) ≈ 1.3


def test_a_subset_keeps_the_other_profiles_in_the_index(tmp_path):
    content = short_dict()
    second = copy.deepcopy(content["virtual_plant"]["profiles"][0])
    second["name"], second["phases"] = "rest", [{"kind": "rest", "duration_s": 120}]
    content["virtual_plant"]["profiles"].append(second)
    motor_file = tmp_path / "motor.json"
    motor_file.write_text(json.dumps(content))
    plant = load_virtual_plant(motor_file)
    generate_profiles(plant, tmp_path / "out")
    index = generate_profiles(plant, tmp_path / "out", names=["rest"])
    assert [e["name"] for e in index["profiles"]] == ["short", "rest"]
    (tmp_path / "out" / "short.csv").write_text("changed\n")
    index = generate_profiles(plant, tmp_path / "out", names=["rest"])
    assert [e["name"] for e in index["profiles"]] == ["rest"]


def _mutate(content: dict, path: str, value) -> dict:
    content = copy.deepcopy(content)
    keys = path.split(".")
    node = content
    for key in keys[:-1]:
        node = node[int(key)] if isinstance(node, list) else node[key]
    last = keys[-1]
    if value is KeyError:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return content


@pytest.mark.parametrize("path, value, words", [
    ("virtual_plant.thermal", KeyError, "virtual_plant.thermal"),
    ("virtual_plant.thermal.C_w", -1.0, "C_w"),
    ("virtual_plant.machine.L_q_H", 0.0001, "L_q_H must exceed L_d_H"),
    ("virtual_plant.machine.voltage_limit_V", 60.0, "cannot produce"),
    ("virtual_plant.sample_period_s", 0.25, "whole number of plant_step_s"),
    ("virtual_plant.true_losses.magic", 1.0, "true_losses.magic"),
    ("virtual_plant.columns.0.signal", "flux", "columns[0].signal"),
    ("virtual_plant.columns.1.unit", "rpm", "columns[1].unit"),
    ("virtual_plant.columns.3.name", "stator_winding_1", "appears twice"),
    ("virtual_plant.profiles.0.phases.0.torque_Nm", 150, "outside the motor's envelope"),
    ("virtual_plant.profiles.0.phases.1.from_s", 1100, "standstill"),
    ("virtual_plant.profiles.0.phases.1.speed_scale", 1.9, "limits.speed_rpm"),
    ("virtual_plant.profiles.0.role", "exam", "profiles[0].role"),
    ("virtual_plant.profiles.0.start_C", 400, "profiles[0].start_C"),
    ("virtual_plant.profiles.0.phases.0", {"kind": "random_steps", "seed": 1, "count": 3, "torque_Nm": [10, 5],
                                           "speed_rpm": [0, 1000], "hold_s": [60, 600]},
     "torque_Nm must be [low, high]"),
    ("virtual_plant.profiles.0.phases.0", {"kind": "random_steps", "count": 3, "torque_Nm": [0, 5],
                                           "speed_rpm": [0, 1000], "hold_s": [60, 600]}, "seed"),
    ("virtual_plant.profiles.0.phases.0.kind", "sprint", "kind"),
    ("virtual_plant.columns.0.signal", ["torque"], "columns[0].signal"),     # unhashable: once a TypeError
    ("virtual_plant.columns.1.unit", {"V": 1}, "columns[1].unit"),
    ("virtual_plant.profiles.0.phases.1.cycle", ["ftp75"], "phases[1].cycle"),
    ("virtual_plant.seed", -1, "seed must be a non-negative whole number"),
    ("virtual_plant.stand.coolant_heat_lag_s", 0.0, "stand.coolant_heat_lag_s must be positive"),
])
def test_a_bad_virtual_plant_is_one_sentence(path, value, words):
    if path.startswith("virtual_plant.profiles.0.phases.0.torque_Nm"):
        content = _mutate(short_dict(), "virtual_plant.profiles.0.phases.0.speed_rpm", 9000)
        content = _mutate(content, path, value)
    else:
        content = _mutate(short_dict(), path, value)
    with pytest.raises(VirtualPlantError) as err:
        virtual_plant(motor_from_dict(content, Path("m.json")))
    message = str(err.value)
    assert words in message and "\n" not in message and message.startswith("motor file m.json")


def test_a_motor_without_a_virtual_plant_is_refused(tmp_path, capsys):
    content = example_dict()
    del content["virtual_plant"]
    path = tmp_path / "plain.json"
    path.write_text(json.dumps(content))
    assert main(["data", "--motor", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "describes no virtual plant; bench data only generates data for virtual motors" in err
    assert "Traceback" not in err and not (tmp_path / "out").exists()


def test_bench_data_with_a_motor(tmp_path, capsys):
    path = tmp_path / "short.json"
    path.write_text(json.dumps(short_dict()))
    out = tmp_path / "out"
    assert main(["data", "--motor", str(path), "--out", str(out), "--seed", "7", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["seed"] == 7 and [p["file"] for p in report["profiles"]] == ["short.csv"]
    assert report["profiles"][0]["sha256"] == hashlib.sha256((out / "short.csv").read_bytes()).hexdigest()
    assert main(["data", "--motor", str(path), "--out", str(out), "--profiles", "short"]) == 0
    captured = capsys.readouterr()
    assert "short" in captured.out and "short.csv" in captured.err
    assert main(["data", "--motor", str(path), "--profiles", "long", "--out", str(out)]) == 1
    assert "has no profile 'long'" in capsys.readouterr().err
    assert main(["data", "--motor", str(path), "--coolant", "20", "--out", str(out)]) == 2
    assert main(["data", "--profiles", "short", "--out", str(out)]) == 2


def test_the_stator_ntc_sees_the_end_winding_late_and_offset(short_run):
    """stator_ntc: the winding node 12 % toward the yoke, a 25 s lag, +0.8 K: while the winding heats up the NTC
    reads below it by about rate × lag, and in the mean it is offset from the gradient-moved winding by +0.8 K."""
    truth, ntc = short_run.truth, short_run.measured["stator_ntc"]
    end_winding = truth["winding"] - 0.12 * (truth["winding"] - truth["yoke"])
    rate = np.gradient(end_winding, short_run.time_s)
    heating = rate > 0.02                                     # K/s, the first minutes at 100 Nm
    lagged = ntc[heating] - 0.8 - end_winding[heating]
    assert np.mean(lagged) == pytest.approx(-25.0 * np.mean(rate[heating]), rel=0.25)
    # an exact 25 s first-order lag of the end winding, +0.8 K, leaves only the 0.2 K noise and 0.1 K rounding
    a = np.exp(-1.0 / 25.0)
    model = np.empty_like(end_winding)
    model[0] = end_winding[0]
    for k in range(1, len(model)):
        model[k] = a * model[k - 1] + (1 - a) * end_winding[k]
    residual = ntc - (model + 0.8)
    assert abs(np.mean(residual)) < 0.02 and np.std(residual) == pytest.approx(np.hypot(0.2, 0.1 / 12 ** 0.5), rel=0.1)


def test_lag_and_offset_belong_to_temperature_sensors():
    content = short_dict()
    content["virtual_plant"]["columns"][0]["lag_s"] = 5      # u_q: a voltage
    with pytest.raises(VirtualPlantError, match=r"columns\[0\].lag_s applies to temperature sensors only"):
        virtual_plant(motor_from_dict(content))


def test_random_steps_are_fixed_by_their_own_seed_and_stay_in_the_envelope():
    content = short_dict()
    random = {"kind": "random_steps", "seed": 7, "count": 6, "torque_Nm": [-50, 200], "speed_rpm": [0, 14000],
              "hold_s": [60, 1800]}
    content["virtual_plant"]["profiles"][0]["phases"] = [random]
    first = virtual_plant(motor_from_dict(content)).profiles[0].phases[0]
    again = virtual_plant(motor_from_dict(copy.deepcopy(content))).profiles[0].phases[0]
    assert first.points == again.points and len(first.points) == 6
    content["virtual_plant"]["profiles"][0]["phases"][0]["seed"] = 8
    other = virtual_plant(motor_from_dict(content)).profiles[0].phases[0]
    assert other.points != first.points
    plant = virtual_plant(motor_from_dict(short_dict()))
    for torque, speed, hold in first.points:
        assert 0 <= speed <= 14000 and 60 <= hold <= 1800 and hold % 10 == 0
        assert -50 <= torque <= float(plant.dq.torque_limit(speed)) + 0.05
    assert first.duration_s == sum(p[2] for p in first.points) + 10.0 * 7   # seven 10 s ramps


def test_a_hot_start_and_the_new_cycles():
    content = short_dict(coolant=30.0)
    profile = content["virtual_plant"]["profiles"][0]
    profile["start_C"] = 90.0
    profile["phases"] = [{"kind": "cycle", "cycle": "us06"}, {"kind": "cycle", "cycle": "hwfet"},
                         {"kind": "rest", "duration_s": 600}]
    plant = virtual_plant(motor_from_dict(content))
    run = plant.simulate(plant.profiles[0])
    assert plant.profiles[0].duration_s == 600 + 765 + 600
    assert run.truth["winding"][0] == pytest.approx(90.0) and run.truth["magnet"][0] == pytest.approx(90.0)
    assert run.truth["speed"].max() > 9000          # US06 at 129 km/h: 9.5 × 129/3.6/0.31 rad/s ≈ 10 500 rpm
    assert run.truth["magnet"][-1] < 80.0           # cooling toward the 30 °C coolant
