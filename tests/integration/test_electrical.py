"""A model with an electrical loss model over CAN, end to end: `bench run --model M --data F --mapping FILE` on a
user's own file with d/q current columns sends DriveCurrents, the target steps on complete rows, and the run's
verdict (CAN = offline float32 on the decoded currents) holds; `bench replay` and `bench analyze` of its log; the
firmware engine (the node and the electrical loss model compiled for the Cortex-M4F) answers exactly as the Python
engine; data without currents and data at another sample period are refused in one sentence before anything
starts."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.analysis.logdecode import decode_log
from target_sim.artifact import load_artifact
from target_sim.model import run_offline

from helpers import (
    electrical_artifact_text,
    refused_in_one_sentence,
    run_cli,
    synthetic_columns,
    with_currents,
    write_synthetic_dataset,
)

ROWS = 300
# the user's file: their own column names, speed in krpm
OWN_NAMES = {"t": "time_s", "T_Nm": "torque_Nm", "n": "speed_rpm", "coolant": "coolant_C", "ambient": "ambient_C",
             "winding": "winding_C", "rotor": "rotor_surface_C", "pm": "pm_C", "Id": "i_d_A", "Iq": "i_q_A"}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    out = tmp_path_factory.mktemp("electrical")
    model = out / "electrical.json"
    model.write_text(electrical_artifact_text(), encoding="utf-8")
    columns = with_currents(synthetic_columns(400, seed=21, torque_offset=150.0, speed_offset=2000.0))
    own = out / "own.csv"
    lines = [",".join(OWN_NAMES)]
    for row in range(400):
        values = [columns[name][row] for name in OWN_NAMES.values()]
        values[2] /= 1000.0                                                      # rpm -> krpm
        lines.append(",".join(f"{v:.3f}" if i == 2 else f"{v:.1f}" for i, v in enumerate(values)))
    own.write_text("\n".join(lines) + "\n", encoding="utf-8")
    mapping = out / "mapping.json"
    mapping.write_text(json.dumps({"columns": {k: v for k, v in OWN_NAMES.items() if k != v},
                                   "units": {"speed_rpm": "krpm"}}), encoding="utf-8")
    plain = write_synthetic_dataset(out / "plain.csv", synthetic_columns(400, seed=21), "no currents")
    return {"dir": out, "model": model, "own": own, "mapping": mapping, "plain": plain, "columns": columns}


@pytest.fixture(scope="module")
def run(files):
    log, report = files["dir"] / "run.blf", files["dir"] / "report"
    proc = run_cli("-m", "bench", "run", "--model", str(files["model"]), "--data", str(files["own"]), "--mapping",
                   str(files["mapping"]), "--rows", str(ROWS), "--log", str(log), "--report", str(report), "--json")
    return proc, log, report


def test_bench_run_of_an_electrical_model_on_mapped_data_is_clean(run, files):
    proc, log, report = run
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert (s["steps_sent"], s["replies"], s["missing"], s["problems"], s["clean"]) == (ROWS, ROWS, 0, [], True)
    assert s["metrics"]["model_steps"] == 120 and s["metrics"]["can_reference"] == "offline float32"
    assert all(0 <= v <= 0.005 + 1e-9 for v in s["max_abs_can_minus_float32_C"].values())
    assert (report / "report.md").is_file()
    # the log: every row's DriveCurrents, carrying the mapped file's currents; the target answered each row
    record = decode_log(log)
    assert record.drive.shape == (ROWS, 6) and np.isfinite(record.drive).all()
    columns = files["columns"]
    np.testing.assert_allclose(record.drive[:, 4], columns["i_d_A"][:ROWS], atol=0.05 + 1e-9)
    np.testing.assert_allclose(record.drive[:, 5], columns["i_q_A"][:ROWS], atol=0.05 + 1e-9)
    np.testing.assert_allclose(record.drive[:, 1], columns["speed_rpm"][:ROWS], atol=0.25 + 1e-9)
    assert int(np.count_nonzero(record.frame_ids == 0x112)) == ROWS
    artifact = load_artifact(files["model"])
    rows, expected = run_offline(artifact, record.drive, record.initial)
    assert np.max(np.abs(record.temps[rows] - expected)) <= 0.005 + 1e-9
    # the verdict needs the currents: without them the reference departs from what the target replied
    _, without = run_offline(artifact, record.drive * [1, 1, 1, 1, 0, 0], record.initial)
    assert np.max(np.abs(record.temps[rows] - without)) > 0.1


@pytest.mark.slow
def test_replay_and_analyze_of_an_electrical_log(run, files, tmp_path):
    _, log, _ = run
    replay = run_cli("-m", "bench", "replay", str(log), "--model", str(files["model"]), "--as-fast-as-possible",
                     "--log", str(tmp_path / "replay.blf"), "--json")
    assert replay.returncode == 0, replay.stderr
    r = json.loads(replay.stdout)
    assert (r["reproduced"], r["identical"], r["different"], r["engine"]) == (True, ROWS, 0, "python")
    analyzed = run_cli("-m", "bench", "analyze", str(log), "--model", str(files["model"]), "--data",
                       str(files["own"]), "--mapping", str(files["mapping"]), "--report", str(tmp_path / "report"),
                       "--json")
    assert analyzed.returncode == 0, analyzed.stderr
    a = json.loads(analyzed.stdout)
    assert (a["steps_sent"], a["replies"], a["clean"], a["rmse_reference"]["winding"]) == (ROWS, ROWS, True,
                                                                                          "measured")
    assert all(v <= 0.005 + 1e-9 for v in a["max_abs_can_minus_float32_C"].values())


def test_data_without_currents_is_refused_before_anything_starts(files, tmp_path, capsys):
    log, report = tmp_path / "run.blf", tmp_path / "report"
    model = load_artifact(files["model"])
    err = refused_in_one_sentence(capsys, ["run", "--model", str(files["model"]), "--data", str(files["plain"]),
                                           "--rows", "30", "--log", str(log), "--report", str(report)])
    assert f"model {model.model_id:08x} ({files['model']}) has an electrical loss model, which needs the d/q " \
           f"currents, and {files['plain']} has none (columns i_d_A, i_q_A)" in err
    assert not log.exists() and not report.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.slow        # the electrical C fragment's bit-exactness is bench firmware check's (tests/bench/firmware)
def test_bench_run_of_an_electrical_model_with_the_firmware_engine_answers_as_the_python_engine(run, files,
                                                                                                 tmp_path):
    """`bench run --engine firmware`: the artifact's firmware built once into the log's firmware cache, the emulated
    node steps on the three-frame rows, every reply equals the Python engine's, the run is clean."""
    _, python_log, _ = run
    log = tmp_path / "firmware.blf"
    proc = run_cli("-m", "bench", "run", "--engine", "firmware", "--model", str(files["model"]), "--data",
                   str(files["own"]), "--mapping", str(files["mapping"]), "--rows", str(ROWS), "--log", str(log),
                   "--no-report", "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert (s["steps_sent"], s["replies"], s["missing"], s["problems"], s["clean"]) == (ROWS, ROWS, 0, [], True)
    assert s["engine"] == "firmware" and s["firmware"].startswith(str(tmp_path / "firmware-cache" / "hammerstein-"))
    assert s["metrics"]["model_steps"] == 120 and s["memory_source"] == "firmware ELF"
    assert 500 < s["m4_cycles"]["p50"] <= s["m4_cycles"]["max"] < 3000
    assert all(0 <= v <= 0.005 + 1e-9 for v in s["max_abs_can_minus_float32_C"].values())
    record, python = decode_log(log), decode_log(python_log)
    assert int(np.count_nonzero(record.frame_ids == 0x112)) == ROWS
    assert np.array_equal(record.temps, python.temps)                # every reply, exactly


def test_data_at_another_sample_period_is_refused(files, tmp_path, capsys):
    model = load_artifact(files["model"])
    slow = tmp_path / "slow.json"    # the same file, read at 1 s per row (its time column says otherwise)
    slow.write_text(json.dumps({"columns": {k: v for k, v in OWN_NAMES.items() if k not in ("t", v)},
                                "units": {"speed_rpm": "krpm"}, "time": {"column": None, "sample_period_s": 1.0}}))
    err = refused_in_one_sentence(capsys, ["run", "--model", str(files["model"]), "--data", str(files["own"]),
                                           "--mapping", str(slow), "--log", str(tmp_path / "a.blf"), "--no-report"])
    assert f"is sampled every 1 s, but model {model.model_id:08x} ({files['model']}) runs on data sampled every " \
           "0.2 s" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["slow.json"]
