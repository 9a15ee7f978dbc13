"""The shared motor-file checker (bench.motor.check): one sentence naming the file and the key, in both wordings."""

import math

import pytest

from bench.motor.check import Checker, is_number
from bench.motor.errors import MotorFileError


class PlantError(MotorFileError):
    pass


def plant_checker() -> Checker:
    return Checker("motor file m.json", PlantError, prefix="virtual_plant.", hint="see the example", terse=True)


@pytest.mark.parametrize("value, ok", [(1, True), (2.5, True), (True, False), (math.inf, False), (math.nan, False),
                                       ("1", False), (None, False)])
def test_is_number(value, ok):
    assert is_number(value) is ok


@pytest.mark.parametrize("content, kwargs, sentence", [
    ({}, {}, "motor file m.json: limits.torque_Nm is missing; see 'bench motor template'"),
    ({"torque_Nm": "9"}, {}, "motor file m.json: limits.torque_Nm must be a finite number, not '9'"),
    ({"torque_Nm": 0}, {"positive": True}, "motor file m.json: limits.torque_Nm must be positive, not 0"),
    ({"torque_Nm": 5}, {"low": 10.0}, "motor file m.json: limits.torque_Nm = 5 must be at least 10"),
    ({"torque_Nm": 5}, {"high": 1.0}, "motor file m.json: limits.torque_Nm = 5 must be at most 1"),
    ({"torque_Nm": 5}, {"low": 0.0, "high": 1.0}, "motor file m.json: limits.torque_Nm = 5 must be from 0 to 1"),
])
def test_number_sentences(content, kwargs, sentence):
    with pytest.raises(MotorFileError) as err:
        Checker("motor file m.json").number(content, "limits.torque_Nm", **kwargs)   # a dotted key: its last part
    assert str(err.value) == sentence


def test_a_good_number_is_a_float_and_a_default_fills_in():
    assert Checker("f").number({"x": 3}, "x", positive=True) == 3.0 and Checker("f").number({}, "x", default=2) == 2.0


def test_the_virtual_plant_wording():
    c = plant_checker()
    cases = [
        (lambda: c.number({}, "resolution", "columns[2]."), "virtual_plant.columns[2].resolution is missing"),
        (lambda: c.table({}, "thermal"), "virtual_plant.thermal is missing or not a table; see the example"),
        (lambda: c.only({"x": 1}, "", ("seed",)), "virtual_plant.x is not a known key (known: seed)"),
        (lambda: c.only({"x": 1}, "stand", ("a", "b")), "virtual_plant.stand.x is not a known key (known: a, b)"),
        (lambda: c.whole({"seed": 1.0}, "seed", low=0), "virtual_plant.seed must be a non-negative whole number, "
                                                         "not 1.0"),
        (lambda: c.version({"schema_version": 2}, 1), "virtual_plant.schema_version 2 is not supported (this "
                                                       "bench reads 1)"),
    ]
    for call, tail in cases:
        with pytest.raises(PlantError) as err:
            call()
        assert str(err.value) == f"motor file m.json: {tail}"


def test_the_motor_file_wording():
    c = Checker("motor file m.toml")
    with pytest.raises(MotorFileError, match=r"^motor file m.toml: \[limits\] is missing or not a table; see "):
        c.table({}, "limits")
    with pytest.raises(MotorFileError, match=r"^motor file m.toml: losses.x is not a known key here \(known: kind\)$"):
        c.only({"x": 1}, "losses", ("kind",))
    with pytest.raises(MotorFileError, match=r"^motor file m.toml: pole_pairs must be a whole number from 1 to 100, "
                                             r"not True$"):
        c.whole({"pole_pairs": True}, "pole_pairs", low=1, high=100)
    with pytest.raises(MotorFileError, match=r"^motor file m.toml: losses.file is missing or not text; see "):
        c.text({"file": " "}, "losses.file")
