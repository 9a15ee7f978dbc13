from __future__ import annotations

import json

from bench.cli import main
from bench.drive.dataset import dataset_sha256


def test_bench_data_writes_reports_and_plots(tmp_path, capsys, dataset_paths):
    status = main(["data", "--out", str(tmp_path), "--coolant", "40", "--plot", "--json", "--quiet"])
    assert status == 0
    report = json.loads(capsys.readouterr().out)
    (entry,) = report["datasets"]
    assert entry["rows"] == 36371 and entry["role"] == "validation"
    assert entry["sha256"] == dataset_sha256(tmp_path / "cycle_coolant40.csv") == dataset_sha256(dataset_paths[40])
    assert (tmp_path / "cycle_coolant40.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert 30 < entry["max_rise_above_coolant_K"]["winding"] < 80
    assert report["sequence"]["duration_s"] == 7274.0


def test_bench_data_rejects_bad_arguments(capsys):
    assert main(["data", "--coolant", "20,abc"]) == 2
    assert "--coolant" in capsys.readouterr().err
    assert main(["data", "--seed", "-3"]) == 2
    assert main(["data", "--coolant", "20,20"]) == 2


def test_bench_data_reports_an_unwritable_directory(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["data", "--out", str(blocker / "sub"), "--coolant", "20", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("bench: error: cannot write") and "Traceback" not in err
