"""Mapping files (JSON/TOML), a user's own motor data through them, and the --mapping/--sample-period options."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from bench.commands.common import add_data_arguments, data_options, sample_period
from bench.drive.dataset import ColumnMapping, DatasetError, load_dataset
from bench.drive.mapping import load_mapping
from bench.errors import UsageError

IPMSM_MAPPING = {
    "columns": {"motor_speed": "speed_rpm", "coolant": "coolant_C", "ambient": "ambient_C", "torque": "torque_Nm",
                "i_d": "i_d_A", "i_q": "i_q_A", "u_d": "u_d_V", "u_q": "u_q_V", "pm": "pm_C"},
    "units": {"speed_rpm": "krpm", "coolant_C": "K", "ambient_C": "K", "pm_C": "K", "winding_C": "K"},
    "derived": {"winding_C": {"mean_of": ["stator_winding_1", "stator_winding_2"]}},
    "time": {"column": None, "sample_period_s": 1.0},
}
IPMSM_TOML = """
comment = "the IPMSM test bench, one profile per file"
[columns]
motor_speed = "speed_rpm"
coolant = "coolant_C"
ambient = "ambient_C"
torque = "torque_Nm"
i_d = "i_d_A"
i_q = "i_q_A"
u_d = "u_d_V"
u_q = "u_q_V"
pm = "pm_C"
[units]
speed_rpm = "krpm"
coolant_C = "K"
ambient_C = "K"
pm_C = "K"
winding_C = "K"
[derived.winding_C]
mean_of = ["stator_winding_1", "stator_winding_2"]
[time]
column = false
sample_period_s = 1.0
"""
IPMSM_HEADER = "u_q,coolant,stator_winding_1,u_d,stator_winding_2,motor_speed,i_d,i_q,pm,ambient,torque,profile_id"


def ipmsm_file(tmp_path, n=8, name="profile_4.csv", edit=None):
    """A file like the public IPMSM bench's: no time column, speed in krpm, temperatures in K, two winding sensors."""
    lines = [IPMSM_HEADER]
    for k in range(n):
        row = ["101.5", f"{313.15 + 0.1 * k:.2f}", f"{333.15 + k:.2f}", "-12.25", f"{335.15 + k:.2f}",
               f"{2.5 + 0.1 * k:.1f}", "-40.0", "120.5", "320.15", "298.15", "150.0", "4"]
        if edit:
            edit(k, row)
        lines.append(",".join(row))
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def mapping_file(tmp_path, content, suffix=".json"):
    path = tmp_path / f"map{suffix}"
    path.write_text(content if isinstance(content, str) else json.dumps(content), encoding="utf-8")
    return path


def test_json_and_toml_mapping_files_load_the_same(tmp_path):
    m = load_mapping(mapping_file(tmp_path, IPMSM_MAPPING))
    assert m.columns["motor_speed"] == "speed_rpm" and m.units["speed_rpm"] == "krpm"
    assert m.derived == {"winding_C": ("stator_winding_1", "stator_winding_2")}
    assert m.time_column is None and m.sample_period_s == 1.0 and (m.separator, m.decimal) == (",", ".")
    assert m.origin == f"mapping file {tmp_path / 'map.json'}"
    assert load_mapping(mapping_file(tmp_path, IPMSM_TOML, ".toml")) == m
    empty = load_mapping(mapping_file(tmp_path, "{}"))
    assert empty == ColumnMapping() and empty.time_column == "time_s"


def test_a_headerless_time_file_at_1_s_with_krpm_kelvin_and_a_mean_winding(tmp_path):
    mapping = load_mapping(mapping_file(tmp_path, IPMSM_MAPPING))
    d = load_dataset(ipmsm_file(tmp_path), mapping, None)
    assert d.rows == 8 and d.sample_period_s == 1.0
    np.testing.assert_array_equal(d.time_s, np.arange(8.0))
    np.testing.assert_allclose(d.speed_rpm, 2500.0 + 100.0 * np.arange(8))
    np.testing.assert_allclose(d.coolant_C, 40.0 + 0.1 * np.arange(8), atol=1e-9)
    np.testing.assert_allclose(d.ambient_C, 25.0, atol=1e-9)
    np.testing.assert_allclose(d.winding_C, 61.0 + np.arange(8), atol=1e-9)   # mean of 60+k and 62+k °C
    np.testing.assert_allclose(d.pm_C, 47.0, atol=1e-9)
    np.testing.assert_allclose(d.rotor_surface_C, 42.0, atol=1e-9)
    assert d.has_currents and d.i_d_A[0] == -40.0 and d.i_q_A[0] == 120.5
    assert d.u_d_V[0] == -12.25 and d.u_q_V[0] == 101.5 and not d.has("yoke_C")
    assert d.metadata["derived"] == ["winding_C = mean(stator_winding_1, stator_winding_2)",
                                     "rotor_surface_C = pm_C - 5", "time_s = row index × 1 s"]
    assert d.metadata["ignored_columns"] == ["profile_id"]
    assert d.metadata["mapping"] == mapping.origin
    # the same period given by the caller instead of the mapping
    d2 = load_dataset(ipmsm_file(tmp_path), ColumnMapping(mapping.columns, mapping.units, mapping.derived, None), 1.0)
    np.testing.assert_array_equal(d2.winding_C, d.winding_C)


def fails(path, *fragments, mapping=None, period=None):
    with pytest.raises(DatasetError) as info:
        load_dataset(path, mapping, period)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, message
    assert "\n" not in message
    return message


def test_no_time_column_needs_a_period(tmp_path):
    m = load_mapping(mapping_file(tmp_path, {**IPMSM_MAPPING, "time": {"column": None}}))
    fails(ipmsm_file(tmp_path), "has no time column", f"{m.origin}, key 'time.column' is null",
          "no sample period is given", "--sample-period", mapping=m)
    m = load_mapping(mapping_file(tmp_path, IPMSM_MAPPING))
    fails(ipmsm_file(tmp_path), "the sample period 1 s (key 'time.sample_period_s'), but 0.2 s is needed",
          mapping=m, period=0.2)
    # no time column, and the mapping does not say so: the missing time_s says how to declare it
    fails(ipmsm_file(tmp_path), "column 'time_s' is missing", '"time": {"column": null}',
          mapping=ColumnMapping(m.columns, m.units, m.derived))


def test_the_mapping_says_no_time_column_but_the_file_has_one(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("time_s,torque_Nm,speed_rpm,coolant_C,ambient_C,winding_C,pm_C\n0,1,2,3,4,5,6\n1,1,2,3,4,5,6\n")
    fails(path, "has a time column 'time_s'", "says it has none", mapping=ColumnMapping(time_column=None),
          period=1.0)


def test_a_named_time_column_and_a_period_checked_against_it(tmp_path):
    path = tmp_path / "t.csv"
    lines = ["t_ms,torque_Nm,speed_rpm,coolant_C,ambient_C,winding_C,pm_C"]
    lines += [f"{500 * k},1,2,3,4,5,6" for k in range(6)]
    path.write_text("\n".join(lines) + "\n")
    m = load_mapping(mapping_file(tmp_path, {"units": {"time_s": "ms"}, "time": {"column": "t_ms"}}))
    d = load_dataset(path, m, None)
    assert d.sample_period_s == 0.5 and d.time_s[3] == 1.5 and d.metadata["source_columns"]["time_s"] == "t_ms"
    m = load_mapping(mapping_file(tmp_path, {"units": {"time_s": "ms"},
                                             "time": {"column": "t_ms", "sample_period_s": 1}}))
    fails(path, "column 't_ms' (time_s): the sample period is 0.5 s", "says 1 s (key 'time.sample_period_s')",
          mapping=m)


def test_derived_sources_are_checked_one_by_one(tmp_path):
    mapping = load_mapping(mapping_file(tmp_path, IPMSM_MAPPING))

    def nan(k, row):
        if k == 5:
            row[4] = "nan"
    fails(ipmsm_file(tmp_path, edit=nan), "column 'stator_winding_2' (winding_C), data row 6 (line 7)", "NaN",
          mapping=mapping)

    def hot(k, row):
        if k == 2:
            row[2] = "600"   # K: 326.85 °C, out of range though the mean with the other sensor is not
    fails(ipmsm_file(tmp_path, edit=hot), "column 'stator_winding_1' (winding_C), data row 3 (line 4)",
          "outside the physical range", mapping=mapping)
    bad = {**IPMSM_MAPPING, "derived": {"winding_C": {"mean_of": ["stator_winding_1", "stator_winding_3"]}}}
    m = load_mapping(mapping_file(tmp_path, bad))
    fails(ipmsm_file(tmp_path), "column 'stator_winding_3' named in", m.origin,
          "(key 'derived.winding_C.mean_of') is not in the header", mapping=m)


def test_a_derived_column_the_file_also_has(tmp_path):
    def header_with_winding(path):
        text = path.read_text().replace("profile_id", "winding_C", 1)
        path.write_text(text)
        return path
    m = load_mapping(mapping_file(tmp_path, IPMSM_MAPPING))
    fails(header_with_winding(ipmsm_file(tmp_path)), "has a column 'winding_C'", "derives 'winding_C'",
          "key 'derived.winding_C'", mapping=m)


def test_currents_come_as_a_pair(tmp_path):
    columns = {k: v for k, v in IPMSM_MAPPING["columns"].items() if k != "i_q"}
    m = load_mapping(mapping_file(tmp_path, {**IPMSM_MAPPING, "columns": columns}))
    fails(ipmsm_file(tmp_path), "column 'i_d' (i_d_A) has no partner 'i_q_A'", "come as a pair", mapping=m)
    d = load_dataset(ipmsm_file(tmp_path), load_mapping(mapping_file(tmp_path, {
        **IPMSM_MAPPING, "columns": {k: v for k, v in columns.items() if k != "i_d"}})), None)
    assert not d.has_currents and d.i_d_A is None and d.metadata["ignored_columns"] == ["i_d", "i_q", "profile_id"]


SEMICOLON = ("time_s;torque_Nm;speed_rpm;coolant_C;ambient_C;winding_C;pm_C\n"
             "0,0;120,5;3000;40,1;24,0;60,25;50,0\n1,0;121,5;3010;40,2;24,0;60,5;50,0\n2,0;-1,5;3020;40,3;24;61;50\n")


def test_a_semicolon_file_with_decimal_commas(tmp_path):
    path = tmp_path / "de.csv"
    path.write_text(SEMICOLON)
    fails(path, "the header is one field 'time_s;torque_Nm;speed_rpm;", "looks semicolon-separated with decimal "
          "commas", "save it comma-separated with '.' decimals", '--mapping with "separator": ";", "decimal": ","')
    m = load_mapping(mapping_file(tmp_path, {"separator": ";", "decimal": ","}))
    d = load_dataset(path, m, None)
    assert d.sample_period_s == 1.0
    np.testing.assert_allclose(d.torque_Nm, [120.5, 121.5, -1.5])
    np.testing.assert_allclose(d.winding_C, [60.25, 60.5, 61.0])
    np.testing.assert_allclose(d.coolant_C, [40.1, 40.2, 40.3])
    # a mapping that sets only the separator: the values say what is wrong
    m = load_mapping(mapping_file(tmp_path, {"separator": ";"}))
    fails(path, "column time_s, data row 1 (line 2): value '0,0' is not a number (a decimal comma?", mapping=m)
    # decimal commas, but a '.' in a value (a thousands separator?) is refused, not misread
    path.write_text(SEMICOLON.replace("3010", "3.010"))
    m = load_mapping(mapping_file(tmp_path, {"separator": ";", "decimal": ","}))
    fails(path, "column speed_rpm, data row 2 (line 3): value '3.010' is not a number with the decimal mark ','",
          "key 'decimal'", mapping=m)


def test_a_tab_file_and_a_comma_file_read_as_semicolons(tmp_path):
    path = tmp_path / "tab.csv"
    path.write_text(SEMICOLON.replace(";", "\t").replace(",", "."))
    fails(path, "the header is one field 'time_s\\ttorque_Nm", "looks tab-separated with '.' decimals",
          '--mapping with "separator": "\\t")')
    assert load_dataset(path, load_mapping(mapping_file(tmp_path, '{"separator": "\\t"}')), None).rows == 3
    path = tmp_path / "plain.csv"
    path.write_text(SEMICOLON.replace(",", ".").replace(";", ","))
    m = load_mapping(mapping_file(tmp_path, {"separator": ";"}))
    fails(path, "the header is one field 'time_s,torque_Nm", "looks comma-separated with '.' decimals",
          f'set "separator": "," in {m.origin}', mapping=m)


def test_auto_period_inference(tmp_path):
    path = tmp_path / "slow.csv"
    lines = ["time_s,torque_Nm,speed_rpm,coolant_C,ambient_C,winding_C,pm_C"]
    lines += [f"{2.0 * k:g},1,2,3,4,5,6" for k in range(9)]
    path.write_text("\n".join(lines) + "\n")
    args = argparse.Namespace(mapping=None, sample_period=sample_period("auto"))
    mapping, period = data_options(args)
    assert (mapping, period) == (None, None)
    assert load_dataset(path, mapping, period).sample_period_s == 2.0
    lines[5] = "9,1,2,3,4,5,6"
    path.write_text("\n".join(lines) + "\n")
    fails(path, "data row 5 (line 6): irregular time step 3 s", "the sample period is 2 s")


@pytest.mark.parametrize(("content", "suffix", "fragments"), [
    ("{", ".json", ["is not valid JSON (Expecting property name"]),
    ("columns = [", ".toml", ["is not valid TOML ("]),
    ("[1, 2]", ".json", ["must hold a JSON object"]),
    ('{"column": {}}', ".json", ["key 'column': unknown key; the keys are columns, units, derived, time"]),
    ('{"columns": {"a": "b", "a": "c"}}', ".json", ["key 'a' appears twice"]),
    ('{"columns": ["x"]}', ".json", ["key 'columns': [\"x\"] is not an object"]),
    ('{"columns": {"n": 5}}', ".json", ["key 'columns.n': 5 is not a string (a schema column name)"]),
    ('{"columns": {"n": "speed"}}', ".json", ["key 'columns.n': 'speed' is not a schema column (time_s, "]),
    ('{"columns": {"a": "winding_C", "b": "winding_C"}}', ".json",
     ["key 'columns': more than one source column maps to 'winding_C' ('a', 'b')"]),
    ('{"units": {"speed_rpm": "mph"}}', ".json",
     ["key 'units.speed_rpm': unit 'mph' of 'speed_rpm' is not one of rpm, 1/min, krpm"]),
    ('{"units": {"speed": "rpm"}}', ".json", ["key 'units.speed': unit given for 'speed', which is not a schema"]),
    ('{"derived": {"winding_C": ["a", "b"]}}', ".json", ["key 'derived.winding_C': [\"a\", \"b\"] is not an obj"]),
    ('{"derived": {"winding_C": {"mean": ["a"]}}}', ".json",
     ["key 'derived.winding_C.mean': unknown key; the keys here are mean_of"]),
    ('{"derived": {"winding_C": {"mean_of": []}}}', ".json",
     ["key 'derived.winding_C.mean_of': []; give a list of one or more source column names"]),
    ('{"derived": {"winding_C": {"mean_of": "a"}}}', ".json", ["key 'derived.winding_C.mean_of': 'a'; give a"]),
    ('{"derived": {"winding_C": {"mean_of": ["a", "a"]}}}', ".json",
     ["key 'derived.winding_C.mean_of': column 'a' is listed twice"]),
    ('{"derived": {"wind": {"mean_of": ["a"]}}}', ".json", ["key 'derived.wind': 'wind' is not a schema column"]),
    ('{"derived": {"time_s": {"mean_of": ["a"]}}}', ".json", ["key 'derived.time_s': 'time_s' is not a schema"]),
    ('{"columns": {"w": "winding_C"}, "derived": {"winding_C": {"mean_of": ["a", "b"]}}}', ".json",
     ["key 'derived.winding_C': 'winding_C' is also mapped from 'w' in 'columns'; map it or derive it, not both"]),
    ('{"time": {"column": null, "period": 1}}', ".json", ["key 'time.period': unknown key; the keys here are "
                                                           "column, sample_period_s"]),
    ('{"time": {"column": 3}}', ".json", ["key 'time.column': 3 is not a column name"]),
    ('{"time": {"sample_period_s": 0}}', ".json", ["key 'time.sample_period_s': 0 is not a positive number"]),
    ('{"time": {"sample_period_s": "1"}}', ".json", ["key 'time.sample_period_s': '1' is not a positive number"]),
    ('{"time": {"sample_period_s": NaN}}', ".json", ["key 'time.sample_period_s': nan is not a positive number"]),
    ('{"time": {"sample_period_s": true}}', ".json", ["key 'time.sample_period_s': True is not a positive"]),
    ('{"time": {"column": null}, "columns": {"t": "time_s"}}', ".json",
     ["key 'time.column': null says the file has no time column, but 'columns' maps 't' to 'time_s'"]),
    ('{"time": {"column": "x"}, "columns": {"t": "time_s"}}', ".json",
     ["key 'time.column': 'x' disagrees with 'columns', which maps 't' to 'time_s'"]),
    ('{"time": {"column": "t"}, "columns": {"t": "torque_Nm"}}', ".json",
     ["key 'time.column': 't' is also mapped to 'torque_Nm' in 'columns'"]),
    ('{"separator": "|"}', ".json", ["key 'separator': '|' is not one of ',', ';', '\\t'"]),
    ('{"decimal": ","}', ".json", ["key 'decimal': the decimal mark ',' cannot also be the separator"]),
    ('{"decimal": 1}', ".json", ["key 'decimal': 1 is not a string"]),
    ('separator = ";"\ndecimal = "·"', ".toml", ["key 'decimal': '·' is not one of '.', ','"]),
    ('[time]\ncolumn = true', ".toml", ["key 'time.column': True is not a column name"]),
    ("{}", ".yaml", ["the name must end in .json or .toml"]),
])
def test_bad_mapping_files(tmp_path, content, suffix, fragments):
    path = mapping_file(tmp_path, content, suffix)
    with pytest.raises(DatasetError) as info:
        load_mapping(path)
    message = str(info.value)
    assert message.startswith(f"mapping file {path}"), message
    for fragment in fragments:
        assert fragment in message, message
    assert "\n" not in message


def test_unreadable_mapping_file(tmp_path):
    with pytest.raises(DatasetError, match=r"mapping file .*nope\.json cannot be read \(No such file"):
        load_mapping(tmp_path / "nope.json")


def test_a_mapped_column_missing_from_the_file_names_the_mapping_key(tmp_path):
    m = load_mapping(mapping_file(tmp_path, {**IPMSM_MAPPING, "columns": {**IPMSM_MAPPING["columns"], "T": "tooth_C"}}))
    fails(ipmsm_file(tmp_path), f"column 'T' named in {m.origin} (key 'columns.T') is not in the header", mapping=m)


@pytest.mark.parametrize(("text", "value"), [("auto", None), ("AUTO", None), ("1", 1.0), ("0.25", 0.25)])
def test_sample_period_option(text, value):
    assert sample_period(text) == value


@pytest.mark.parametrize(("text", "fragment"), [("fast", "'fast' is neither a number of seconds nor 'auto'"),
                                                ("0", "'0' must be a positive number"),
                                                ("-1", "'-1' must be a positive"), ("inf", "'inf' must be"),
                                                ("nan", "'nan' must be")])
def test_bad_sample_period_option(text, fragment):
    with pytest.raises(UsageError) as info:
        sample_period(text)
    assert str(info.value).startswith("--sample-period") and fragment in str(info.value)


def test_data_arguments(tmp_path):
    parser = argparse.ArgumentParser()
    add_data_arguments(parser)
    path = mapping_file(tmp_path, IPMSM_MAPPING)
    args = parser.parse_args([])
    assert args.mapping is None and data_options(args) == (None, None)
    mapping, period = data_options(parser.parse_args(["--mapping", str(path)]))
    assert period == 1.0 and mapping == load_mapping(path)            # auto: the mapping's period
    mapping, period = data_options(parser.parse_args(["--mapping", str(path), "--sample-period", "0.5"]))
    assert period == 0.5 and mapping.sample_period_s == 0.5           # the flag replaces the mapping's
    assert load_dataset(ipmsm_file(tmp_path), mapping, period).time_s[3] == 1.5
    no_period = mapping_file(tmp_path, {"time": {"column": None}})
    assert data_options(parser.parse_args(["--mapping", str(no_period)]))[1] is None
    with pytest.raises(UsageError, match="--sample-period 'x' is neither"):
        parser.parse_args(["--sample-period", "x"])
    with pytest.raises(DatasetError, match="mapping file .* cannot be read"):
        data_options(parser.parse_args(["--mapping", str(tmp_path / "missing.toml")]))
    assert math.isclose(data_options(argparse.Namespace(mapping=None, sample_period="2"))[1], 2.0)
