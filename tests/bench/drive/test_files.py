"""Data arguments: paths and globs expanded to files, in order, each once; several files loaded."""

from __future__ import annotations

import pytest

from bench.drive.dataset import COLUMNS, ColumnMapping, DatasetError
from bench.drive.files import expand_data_paths, load_datasets
from bench.errors import BenchError


def write(path, period=1.0, rows=4):
    lines = [",".join(COLUMNS)] + [f"{k * period:g},1,2,3,4,5,6,7" for k in range(rows)]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def tree(tmp_path):
    (tmp_path / "runs").mkdir()
    for name in ("p10.csv", "p2.csv", "p1.csv"):
        write(tmp_path / "runs" / name)
    (tmp_path / "runs" / "notes.txt").write_text("x")
    (tmp_path / "runs" / "sub.csv").mkdir()   # a directory that a glob matches: not a file, left out
    write(tmp_path / "other.csv", period=0.5)
    write(tmp_path / "odd[1].csv")
    return tmp_path


def test_globs_sorted_and_arguments_in_order(tree):
    runs = tree / "runs"
    got = expand_data_paths([str(tree / "other.csv"), str(runs / "p*.csv")], "--data")
    assert [p.name for p in got] == ["other.csv", "p1.csv", "p10.csv", "p2.csv"]
    got = expand_data_paths([str(runs / "p?.csv"), str(tree / "**" / "p10.csv")], "--data")
    assert [p.name for p in got] == ["p1.csv", "p2.csv", "p10.csv"]
    assert [p.name for p in expand_data_paths([str(runs / "p[12].csv")], "--data")] == ["p1.csv", "p2.csv"]
    # an existing file whose name has glob characters is that file
    assert expand_data_paths([str(tree / "odd[1].csv")], "--data") == [tree / "odd[1].csv"]


@pytest.mark.parametrize(("args", "fragments"), [
    (["runs/*.parquet"], ["--data runs/*.parquet: the pattern matches no file"]),
    (["runs/sub*"], ["--data runs/sub*: the pattern matches no file"]),
    (["runs/p3.csv"], ["--data runs/p3.csv: no such file; check the path"]),
    (["runs"], ["--data runs is a directory; name the files, e.g. --data 'runs/*.csv'"]),
    (["runs/p1.csv", "runs/*.csv"], ["--data runs/*.csv: runs/p1.csv is given twice (already given by runs/p1.csv)"]),
    (["runs/p1.csv", "runs/../runs/p1.csv"], ["--data runs/../runs/p1.csv: runs/../runs/p1.csv is given twice ("]),
    (["runs/p2.csv", "runs/p2.csv"], ["--data runs/p2.csv: runs/p2.csv is given twice; name each file once"]),
])
def test_bad_data_arguments(tree, monkeypatch, args, fragments):
    monkeypatch.chdir(tree)
    with pytest.raises(BenchError) as info:
        expand_data_paths(args, "--data")
    for fragment in fragments:
        assert fragment in str(info.value), str(info.value)
    assert "\n" not in str(info.value)


def test_load_datasets(tree):
    paths = expand_data_paths([str(tree / "runs" / "p*.csv"), str(tree / "other.csv")], "--data")
    loaded = load_datasets(paths, None, None)
    assert [d.name for d in loaded] == ["p1", "p10", "p2", "other"]
    assert [d.sample_period_s for d in loaded] == [1.0, 1.0, 1.0, 0.5]
    assert loaded[0].winding_C[0] == 5.0 and loaded[3].time_s[3] == 1.5
    with pytest.raises(DatasetError, match=r"other\.csv, column time_s: the sample period is 0.5 s"):
        load_datasets(paths, ColumnMapping(), 1.0)
    mapped = load_datasets(paths[:1], ColumnMapping({"winding_C": "tooth_C", "pm_C": "winding_C"}), None)
    assert mapped[0].tooth_C[0] == 5.0 and mapped[0].winding_C[0] == 7.0 and mapped[0].pm_C[0] == 11.0
