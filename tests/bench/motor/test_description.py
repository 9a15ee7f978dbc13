"""Motor description files: the template, the built-in motor, the loss models, and bad files in one sentence."""

import json

import numpy as np
import pytest

from bench.cli import main
from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps
from bench.motor.description import (
    MotorFileError,
    default_motor,
    load_motor,
    load_prior,
    motor_from_dict,
    parse_bounds,
)
from bench.motor.losses import ElectricalLosses
from bench.motor.losskinds.maps import loss_maps_csv
from bench.motor.template import template
from bench.thermal.parameters import TABLE1


def test_the_built_in_motor_file_is_the_virtual_motor_bit_for_bit():
    motor = default_motor()
    maps = nominal_loss_maps()
    assert motor.loss_kind == "maps" and not motor.needs_currents
    for name, table in maps.tables.items():
        assert np.array_equal(motor.loss_model.tables[name], table), name
    assert np.array_equal(motor.loss_model.torque_Nm, maps.torque_Nm)
    assert np.array_equal(motor.loss_model.speed_rpm, maps.speed_rpm)
    assert motor.constants().i_max_A == VIRTUAL_MOTOR.i_max_A
    assert motor.constants().max_speed_rpm == VIRTUAL_MOTOR.max_speed_rpm
    assert motor.constants().alpha_cu_per_K == VIRTUAL_MOTOR.alpha_cu_per_K
    assert motor.prior.parameters == TABLE1 and motor.prior.bounds == (0.6, 1.6)


@pytest.mark.parametrize("fmt", ["toml", "json"])
def test_the_template_is_a_valid_motor_in_both_formats(tmp_path, fmt):
    path = tmp_path / f"motor.{fmt}"
    path.write_text(template(fmt))
    motor = load_motor(path)
    assert motor.name == "my-ipm-60kw" and motor.pole_pairs == 4 and motor.needs_currents
    assert motor.loss_model.current_max_A == 400.0
    # a new user has no fitted network: the template starts from the training data, in a wide box
    assert motor.prior.automatic and motor.prior.parameters is None and motor.prior.bounds == (0.1, 10.0)


def test_electrical_losses_follow_the_documented_formulas():
    model = ElectricalLosses(pole_pairs=4, stator_resistance_ohm=0.02, ac_factor=0.5, ac_reference_Hz=800.0,
                             iron_hysteresis_W=400.0, iron_eddy_W=600.0, iron_reference_Hz=800.0,
                             iron_current_factor=0.25, magnet_W=200.0, magnet_reference_Hz=800.0,
                             magnet_no_load_share=0.4, current_max_A=400.0)
    out = model.evaluate_columns({"speed_rpm": np.array([-12000.0]), "i_d_A": np.array([-120.0]),
                                  "i_q_A": np.array([160.0])})
    f = 4 * 12000 / 60                        # 800 Hz: every ratio is 1
    i = 200.0                                 # |(-120, 160)|
    assert f == 800.0
    assert out["current"][0] == pytest.approx(i)
    assert out["p_dc0"][0] == pytest.approx(1.5 * 0.02 * i * i)
    assert out["p_ac0"][0] == pytest.approx(0.5 * 1.5 * 0.02 * i * i)
    assert out["p_stator"][0] == pytest.approx((400 + 600) * (1 + 0.25 * 0.25))
    assert out["p_magnet"][0] == pytest.approx(200 * (0.4 + 0.6 * 0.5) ** 2)


def test_a_maps_motor_reads_its_csv_beside_it(tmp_path):
    (tmp_path / "maps.csv").write_text(loss_maps_csv(nominal_loss_maps(speed_points=5, torque_points=3)))
    content = json.loads(template("json"))
    content["losses"] = {"kind": "maps", "file": "maps.csv", "copper_reference_C": 20, "copper_alpha_per_K": 0.0039}
    path = tmp_path / "m.json"
    path.write_text(json.dumps(content))
    motor = load_motor(path)
    assert motor.loss_kind == "maps" and motor.loss_model.tables["p_dc0"].shape == (3, 5)
    assert motor.provenance()["loss_maps_sha256"]


def _motor_with(tmp_path, change, fmt="json"):
    content = json.loads(template("json"))
    change(content)
    path = tmp_path / f"bad.{fmt}"
    path.write_text(json.dumps(content))
    return path


BAD = [
    (lambda c: c.pop("name"), "name is missing"),
    (lambda c: c.update(name="a b"), "must be 1-64 letters"),
    (lambda c: c.update(pole_pairs=2.5), "pole_pairs must be a whole number"),
    (lambda c: c["limits"].update(current_A=-1), "limits.current_A must be positive"),
    (lambda c: c["limits"].pop("speed_rpm"), "limits.speed_rpm is missing"),
    (lambda c: c["losses"].update(kind="fe"), "losses.kind must be one of maps, electrical"),
    (lambda c: c["losses"].update(magnet_no_load_share=1.5), "magnet_no_load_share = 1.5 must be from 0 to 1"),
    (lambda c: c["losses"].update(stator_resistance_ohm="0.1"), "stator_resistance_ohm must be a finite number"),
    (lambda c: c["losses"].update(iron_W=3), "losses.iron_W is not a known key"),
    (lambda c: c.update(colour="red"), "unknown key 'colour'"),
    (lambda c: c.update(schema_version=7), "schema_version 7 is not supported"),
    (lambda c: c["thermal_prior"].update(bounds=[1.2, 3]), "must be two factors LOW,HIGH"),
    (lambda c: c["thermal_prior"].update(parameters="table9"), "is not a parameter set"),
    (lambda c: c["thermal_prior"].update(parameters={"C_y": 1.0}), "lacks 'C_w'"),
    (lambda c: c["losses"].update(kind="maps", file="nowhere.csv"), "losses.file"),
]


@pytest.mark.parametrize(("change", "expected"), BAD)
def test_a_bad_motor_file_is_one_sentence_naming_the_key(tmp_path, change, expected):
    def edit(content):
        if "maps" in expected or "losses.file" in expected:
            for key in list(content["losses"]):
                if key not in ("kind", "copper_reference_C", "copper_alpha_per_K"):
                    content["losses"].pop(key)
        change(content)

    path = _motor_with(tmp_path, edit)
    with pytest.raises(MotorFileError) as info:
        load_motor(path)
    message = str(info.value)
    assert expected in message and str(path) in message and "\n" not in message


@pytest.mark.parametrize(("name", "text", "expected"), [
    ("m.json", "{", "is not valid JSON"),
    ("m.toml", "name = ", "is not valid TOML"),
    ("m.yaml", "name: x", "must end in .json or .toml"),
    ("m.json", "[1, 2]", "must hold one object"),
])
def test_unparsable_motor_files(tmp_path, name, text, expected):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(MotorFileError, match=expected):
        load_motor(path)


def test_missing_motor_file_and_cli_sentence(tmp_path, capsys):
    assert main(["motor", "check", str(tmp_path / "none.toml")]) == 1
    err = capsys.readouterr().err
    assert "does not exist" in err and "bench motor template" in err and "Traceback" not in err


def test_motor_check_json_summarizes(tmp_path, capsys):
    path = tmp_path / "m.toml"
    path.write_text(template("toml"))
    assert main(["motor", "check", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["loss_model"] == "electrical" and summary["needs_currents"] is True
    assert summary["loss_coefficients"]["stator_resistance_ohm"] == 0.018


def test_prior_file_and_bounds(tmp_path):
    path = tmp_path / "prior.json"
    path.write_text(json.dumps({"parameters": TABLE1.as_dict(), "bounds": [0.3, 3]}))
    prior = load_prior(path)
    assert prior.parameters == TABLE1 and prior.source == "file" and prior.bounds == (0.3, 3.0)
    assert parse_bounds("0.5,2", "--bounds") == (0.5, 2.0)
    with pytest.raises(MotorFileError, match="--bounds must be two factors"):
        parse_bounds("2,0.5", "--bounds")
    bad = dict(TABLE1.as_dict(), C_y=-1.0)
    with pytest.raises(MotorFileError, match="C_y must be positive"):
        motor_from_dict({**json.loads(template("json")), "thermal_prior": {"parameters": bad}})
