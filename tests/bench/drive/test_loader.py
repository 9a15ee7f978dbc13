"""One clear DatasetError per problem, naming the file, the column and the row."""

from __future__ import annotations

import numpy as np
import pytest

from bench.drive.dataset import COLUMNS, ColumnMapping, DatasetError, load_dataset

HEADER = ",".join(COLUMNS)


def rows(n=12, period=0.2):
    out = []
    for k in range(n):
        out.append([f"{k * period:.1f}", "120.5", "3000", "40.1", "24.0", f"{60 + 0.1 * k:.1f}", "45.0", "50.0"])
    return out


def write(tmp_path, data, header=HEADER, name="user.csv"):
    path = tmp_path / name
    path.write_text(header + "\n" + "\n".join(",".join(r) for r in data) + "\n")
    return path


def fails(path, *fragments, **kwargs):
    with pytest.raises(DatasetError) as info:
        load_dataset(path, **kwargs)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, message
    assert "\n" not in message and "Traceback" not in message
    return message


def test_a_good_file_loads_without_sidecar(tmp_path):
    d = load_dataset(write(tmp_path, rows()))
    assert d.rows == 12 and d.sample_period_s == 0.2 and d.coolant_setpoint_C is None
    assert d.metadata["sidecar"] is None and d.winding_C[3] == pytest.approx(60.3)
    with pytest.raises(ValueError):
        d.winding_C[0] = 1.0  # read-only


def test_missing_column(tmp_path):
    data = [r[:5] + r[6:] for r in rows()]
    header = ",".join(c for c in COLUMNS if c != "winding_C")
    fails(write(tmp_path, data, header), "column 'winding_C' is missing")


def test_missing_pm_and_rotor_surface(tmp_path):
    data = [r[:6] for r in rows()]
    fails(write(tmp_path, data, ",".join(COLUMNS[:6])), "'pm_C' (or 'rotor_surface_C') is missing")


def test_nan_value(tmp_path):
    data = rows()
    data[6][5] = "NaN"
    fails(write(tmp_path, data), "column winding_C", "data row 7 (line 8)", "NaN")


def test_not_a_number_and_empty(tmp_path):
    data = rows()
    data[2][1] = "12;5"
    fails(write(tmp_path, data), "column torque_Nm", "data row 3 (line 4)", "'12;5' is not a number")
    data = rows()
    data[4][3] = ""
    fails(write(tmp_path, data), "column coolant_C", "data row 5 (line 6)", "empty")


def test_wrong_number_of_fields(tmp_path):
    data = rows()
    data[8] = data[8][:-1]
    fails(write(tmp_path, data), "data row 9 (line 10)", "7 fields, the header has 8")


def test_non_monotonic_time(tmp_path):
    data = rows()
    data[5][0], data[6][0] = data[6][0], data[5][0]
    fails(write(tmp_path, data), "column time_s", "data row 7 (line 8)", "does not increase")
    data = rows()
    data[6][0] = data[5][0]
    fails(write(tmp_path, data), "data row 7 (line 8)", "does not increase")


def test_irregular_time(tmp_path):
    data = rows()
    for k in range(7, 12):
        data[k][0] = f"{k * 0.2 + 0.2:.1f}"   # a missing sample
    fails(write(tmp_path, data), "column time_s", "data row 8 (line 9)", "irregular time step 0.4 s")


def test_wrong_sample_rate(tmp_path):
    path = write(tmp_path, rows(period=0.1))
    fails(path, "column time_s", "sample period is 0.1 s (10 Hz)", "needs 0.2 s (5 Hz)")
    assert load_dataset(path, sample_period_s=None).sample_period_s == pytest.approx(0.1)


@pytest.mark.parametrize(("col", "value", "name"), [(5, "400.0", "winding_C"), (2, "-5000", "speed_rpm"),
                                                    (1, "2500", "torque_Nm"), (3, "-60", "coolant_C")])
def test_values_outside_physical_range(tmp_path, col, value, name):
    data = rows()
    data[10][col] = value
    fails(write(tmp_path, data), f"column {name}", "data row 11 (line 12)", "outside the physical range")


def test_sidecar_checksum_mismatch(tmp_path, dataset_paths):
    path = tmp_path / "copy.csv"
    path.write_text(dataset_paths[40].read_text().replace("\n0.2,", "\n0.2,1", 1))
    (tmp_path / "copy.json").write_bytes(dataset_paths[40].with_suffix(".json").read_bytes())
    fails(path, "does not match the sha256 in its sidecar")


def test_unreadable_and_empty_files(tmp_path):
    fails(tmp_path / "nope.csv", "cannot be read")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    fails(empty, "is empty")
    fails(write(tmp_path, rows(1)), "1 data row(s)")


def test_column_mapping_with_unit_conversion(tmp_path):
    header = "t,T_kNm,n_rads,cool_K,amb_F,wind_C,rotor_C,extra"
    data = []
    for k in range(10):
        data.append([f"{k * 0.2:.1f}", "0.1205", f"{3000 * 2 * np.pi / 60:.9f}", "313.25", "75.2", "60.0",
                     "45.0", "x"])
    mapping = ColumnMapping(
        {"t": "time_s", "T_kNm": "torque_Nm", "n_rads": "speed_rpm", "cool_K": "coolant_C", "amb_F": "ambient_C",
         "wind_C": "winding_C", "rotor_C": "rotor_surface_C"},
        {"torque_Nm": "kNm", "speed_rpm": "rad/s", "coolant_C": "K", "ambient_C": "°F"})
    d = load_dataset(write(tmp_path, data, header), mapping)
    assert d.torque_Nm[0] == pytest.approx(120.5)
    assert d.speed_rpm[0] == pytest.approx(3000.0)
    assert d.coolant_C[0] == pytest.approx(40.1)
    assert d.ambient_C[0] == pytest.approx(24.0)
    np.testing.assert_allclose(d.pm_C, 50.0)
    assert d.metadata["derived"] == ["pm_C = rotor_surface_C + 5"]
    assert d.metadata["ignored_columns"] == ["extra"]
    assert d.metadata["source_columns"]["torque_Nm"] == "T_kNm"


def test_mapped_column_errors_name_the_source_column(tmp_path):
    header = HEADER.replace("winding_C", "Twind")
    data = rows()
    data[3][5] = "nan"
    message = fails(write(tmp_path, data, header), "'Twind' (winding_C)", "data row 4 (line 5)",
                    mapping=ColumnMapping({"Twind": "winding_C"}))
    assert "NaN" in message


def test_bad_mappings(tmp_path):
    with pytest.raises(DatasetError, match="not a schema column"):
        ColumnMapping({"a": "winding_temp"})
    with pytest.raises(DatasetError, match="unit 'mph' of 'speed_rpm' is not one of"):
        ColumnMapping(units={"speed_rpm": "mph"})
    with pytest.raises(DatasetError, match="more than one source column maps to 'winding_C'"):
        ColumnMapping({"a": "winding_C", "b": "winding_C"})
    fails(write(tmp_path, rows()), "column 'Twind' named in the column mapping is not in the header",
          mapping=ColumnMapping({"Twind": "winding_C"}))


def test_krpm_derived_mean_and_no_time_column_in_code(tmp_path):
    header = "n_krpm,torque_Nm,coolant_C,ambient_C,w1,w2,pm_C"
    data = [[f"{1.5 + 0.5 * k:g}", "10", "40", "25", f"{60 + k}", f"{70 + k}", "50"] for k in range(5)]
    mapping = ColumnMapping({"n_krpm": "speed_rpm"}, {"speed_rpm": "krpm"}, derived={"winding_C": ["w1", "w2"]},
                            time_column=None, sample_period_s=2.0)
    d = load_dataset(write(tmp_path, data, header), mapping, None)
    np.testing.assert_allclose(d.speed_rpm, [1500, 2000, 2500, 3000, 3500])
    np.testing.assert_allclose(d.winding_C, [65, 66, 67, 68, 69])
    np.testing.assert_allclose(d.time_s, [0, 2, 4, 6, 8])
    assert d.sample_period_s == 2.0 and d.metadata["source_columns"]["winding_C"] == "mean(w1, w2)"
    assert d.metadata["ignored_columns"] == [] and "mapping" not in d.metadata


def test_a_semicolon_header_names_the_separator(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_text(";".join(COLUMNS) + "\n" + "\n".join(";".join(r).replace(".", ",") for r in rows()) + "\n")
    message = fails(path, "the header is one field 'time_s;torque_Nm;", "semicolon-separated with decimal commas")
    assert "fields, the header has" not in message
    d = load_dataset(path, ColumnMapping(separator=";", decimal=","))
    assert d.rows == 12 and d.torque_Nm[0] == 120.5 and d.winding_C[3] == pytest.approx(60.3)


def test_currents_without_their_partner(tmp_path):
    data = [r + ["12.5"] for r in rows()]
    fails(write(tmp_path, data, HEADER + ",i_q_A"), "column i_q_A has no partner 'i_d_A'")
    data = [r + ["12.5", "-3"] for r in rows()]
    d = load_dataset(write(tmp_path, data, HEADER + ",i_q_A,i_d_A"))
    assert d.has_currents and d.i_q_A[0] == 12.5 and d.i_d_A[0] == -3.0


def test_bad_mappings_in_code():
    with pytest.raises(DatasetError, match=r"key 'derived.winding_C.mean_of': give a list"):
        ColumnMapping(derived={"winding_C": "w1"})
    with pytest.raises(DatasetError, match=r"key 'decimal': the decimal mark ','"):
        ColumnMapping(decimal=",")
    with pytest.raises(DatasetError, match=r"key 'time.sample_period_s': -1 is not a positive number"):
        ColumnMapping(sample_period_s=-1)


def test_the_rows_identity_is_of_the_values_not_of_the_file(tmp_path):
    """A summary's data identity (`rows_sha256`): the same values in another file, separator and order of columns
    give the same identity; one changed value or fewer rows give another."""
    same = load_dataset(write(tmp_path, rows(), name="a.csv"))
    order = [COLUMNS.index(c) for c in reversed(COLUMNS)]
    reordered = write(tmp_path, [[r[i] for i in order] for r in rows()], ";".join(reversed(COLUMNS)), "b.csv")
    reordered.write_text(reordered.read_text().replace(",", ";"))
    again = load_dataset(reordered, ColumnMapping(separator=";"))
    assert same.sha256 != again.sha256 and same.rows_sha256() == again.rows_sha256()
    assert same.rows_sha256(12) == same.rows_sha256() != same.rows_sha256(11)
    changed = rows()
    changed[5][1] = "120.6"
    assert load_dataset(write(tmp_path, changed, name="c.csv")).rows_sha256() != same.rows_sha256()
