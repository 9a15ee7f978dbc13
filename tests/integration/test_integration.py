"""Real target and host processes on a real cross-process bus (udp_multicast, a port unique to each test)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest

from bench.analysis.logdecode import decode_log
from bench.model.default import default_artifact_path
from bench.run.target import TargetProcess
from dbc.transport import BusConfig, free_udp_port
from target_sim.artifact import load_artifact
from target_sim.model import run_offline

from helpers import ROOT, run_cli, start_target

DBC = ROOT / "dbc" / "thermal_bench.dbc"


def bus_argv(bus: BusConfig) -> list[str]:
    return bus.to_argv()


def can_vs_float32(log: Path, artifact_path: Path) -> float:
    record = decode_log(log)
    rows, expected = run_offline(load_artifact(artifact_path), record.drive, record.initial)
    return float(np.max(np.abs(record.temps[rows] - expected)))


def test_target_and_host_processes_over_udp_multicast(tmp_path, small_dataset, udp_bus):
    stats = tmp_path / "target.json"
    log = tmp_path / "host.log"
    with start_target("--model", default_artifact_path(), "--stats", stats, *bus_argv(udp_bus),
                      stderr=subprocess.PIPE, text=True) as target:
        host = run_cli("-m", "bench", "host", "--data", str(small_dataset), "--rows", "300", "--log", str(log),
                       "--json", *bus_argv(udp_bus))
    target_err = target.stderr    # stopped with SIGTERM as the block ended
    assert host.returncode == 0, host.stderr
    result = json.loads(host.stdout)
    assert (result["rows_sent"], result["replies"], result["missing"], result["sequence_gaps"]) == (300, 300, 0, 0)
    assert result["clean"] and result["target_state"] == "STOPPED"
    assert target.returncode == 0, target_err
    counters = json.loads(stats.read_text())
    assert counters["rows_used"] == 300 and counters["model_steps"] == 120
    assert counters["errors"] == dict.fromkeys(counters["errors"], 0)
    # the candump log decodes with cantools' own command line
    decoded = subprocess.run([sys.executable, "-m", "cantools", "decode", str(DBC)], stdin=log.open(),
                             capture_output=True, text=True, timeout=60)
    assert decoded.returncode == 0, decoded.stderr
    assert decoded.stdout.count("Temperatures1(") == 300 and decoded.stdout.count("DriveInputs(") == 300
    assert "Status(" in decoded.stdout and "TargetInfo(" in decoded.stdout
    assert can_vs_float32(log, default_artifact_path()) <= 0.005 + 1e-9


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory, small_dataset):
    out = tmp_path_factory.mktemp("run")
    log, report = out / "bench.blf", out / "report"
    proc = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", "400", "--log", str(log),
                   "--report", str(report), "--json")
    return proc, log, report


def test_bench_run_answers_every_step_and_matches_float32(bench_run):
    proc, log, report = bench_run
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert (s["steps_sent"], s["replies"], s["missing"]) == (400, 400, 0)
    assert s["clean"] and s["problems"] == []
    assert set(s["max_abs_can_minus_float32_C"]) == {"yoke", "winding", "tooth", "magnet"}
    assert max(s["max_abs_can_minus_float32_C"].values()) <= 0.005 + 1e-9
    assert s["metrics"]["model_steps"] == 160
    assert s["rmse_C"]["winding"] is not None and s["metrics"]["rmse_reference"]["winding"] == "measured"
    # beside the RMSEs what each is against, beside `clean` the verdict in words
    assert s["rmse_reference"] == s["metrics"]["rmse_reference"] and s["rmse_reference"]["yoke"] == "float64 model"
    assert s["verdict"] == "clean"
    assert s["est_cycles"] > 0 and s["step_time_us"]["p50"] > 0 and s["throughput_steps_per_s"] > 50
    assert s["log"] == str(log)
    assert can_vs_float32(log, default_artifact_path()) <= 0.005 + 1e-9
    frames = list(can.LogReader(str(log)))
    assert sum(1 for m in frames if m.arbitration_id == 0x220) == 400
    for name in ("report.md", "temperatures.png", "float32_error.png", "step_time.png", "bus_load.png"):
        assert (report / name).stat().st_size > 1000, name
    assert "Result: clean" in (report / "report.md").read_text()


def test_bench_replay_reproduces_the_replies_exactly(bench_run, tmp_path, udp_bus):
    _, log, _ = bench_run
    new_log = tmp_path / "replay.asc"
    proc = run_cli("-m", "bench", "replay", str(log), "--log", str(new_log), "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["reproduced"] and s["identical"] == s["recorded_answered"] == 400 and s["different"] == 0
    fast = run_cli("-m", "bench", "replay", str(log), "--as-fast-as-possible", "--log", str(tmp_path / "r.log"),
                   "--json", *bus_argv(udp_bus))
    assert fast.returncode == 0, fast.stderr
    assert json.loads(fast.stdout)["identical"] == 400
    assert decode_log(new_log).rows == 400


@pytest.mark.slow
def test_bench_analyze_gives_the_run_s_numbers(bench_run, small_dataset, tmp_path):
    proc, log, _ = bench_run
    run = json.loads(proc.stdout)["metrics"]
    analyzed = run_cli("-m", "bench", "analyze", str(log), "--data", str(small_dataset), "--report",
                       str(tmp_path / "rep"), "--json")
    assert analyzed.returncode == 0, analyzed.stderr
    a = json.loads(analyzed.stdout)
    for key in ("steps_sent", "replies", "model_steps", "max_abs_can_minus_float32_C", "rmse_C", "step_time_us",
                "est_cycles", "max_abs_float32_minus_float64_C"):
        assert a[key] == run[key], key
    assert (tmp_path / "rep" / "report.md").is_file()
    assert a["verdict"] == "clean"
    # --no-report as `bench run --no-report`: the figures, no report written
    bare = run_cli("-m", "bench", "analyze", str(log), "--data", str(small_dataset), "--no-report", "--json")
    assert bare.returncode == 0, bare.stderr
    b = json.loads(bare.stdout)
    assert b["rmse_C"] == a["rmse_C"] and b["verdict"] == "clean" and "report" not in b
    assert not log.with_name(f"{log.stem}-report").exists()


@pytest.mark.slow
def test_every_kind_and_the_original_realization(artifacts, small_dataset, tmp_path):
    models = ",".join(str(artifacts[k]) for k in ("lti", "pv", "hammerstein", "original"))
    proc = run_cli("-m", "bench", "compare", "--data", str(small_dataset), "--rows", "600", "--models", models,
                   "--out", str(tmp_path), "--json", timeout=180)
    rows = {Path(r["model"]).stem: r for r in json.loads(proc.stdout)["models"]}
    for name in ("lti", "pv", "hammerstein"):
        r = rows[name]
        assert r["missing"] == 0 and r["problems"] == [], (name, r["problems"])
        assert r["max_abs_can_minus_float32_C"] <= 0.005 + 1e-9
        assert r["max_abs_float32_minus_float64_C"] < 0.05
    assert rows["hammerstein"]["est_cycles"] > rows["lti"]["est_cycles"]
    # the measured Cortex-M4F columns (firmware engine, the default; these artifacts' ELFs built into --out)
    for r in rows.values():
        assert r["engine"] == "firmware" and 300 < r["m4_cycles_p50"] <= r["m4_cycles_max"] < 3000
        assert r["m4_exec_us_90MHz"] == pytest.approx(r["m4_cycles_p50"] / 90, abs=0.06)
        assert 14_000 < r["m4_flash_bytes"] < 32_000 and 1024 < r["m4_ram_bytes"] < 4096   # model and CAN node
        assert r["est_flash_bytes"] > 0 and r["est_ram_bytes"] > 0 and r["est_cycles"] > r["m4_cycles_p50"]
    assert rows["hammerstein"]["m4_cycles_p50"] > rows["lti"]["m4_cycles_p50"]
    assert len(list((tmp_path / "firmware-cache").glob("*.elf"))) == 4
    assert rows["pv"]["kind"] == "pv-lptn" and rows["hammerstein"]["kind"] == "hammerstein"
    # the paper's polynomial realization does not survive float32 (Fig. 6): the report shows the divergence
    assert rows["original"]["max_abs_float32_minus_float64_C"] > 1.0
    assert any("does not survive single precision" in note for note in rows["original"]["notes"])
    assert rows["lti"]["notes"] == []
    assert rows["original"]["missing"] == 0
    # its estimate left the DBC range, so the target clamped it: that run is not clean, and neither is the comparison
    assert rows["original"]["problems"] and all(rows[k]["problems"] == [] for k in ("lti", "pv", "hammerstein"))
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1
    assert "bench: error: not clean: original.json (lti-lptn, original): " in proc.stderr and "SATURATED" in proc.stderr


@pytest.mark.slow        # real-time pacing is also the host tests'
def test_realtime_mode_at_speed_100(small_dataset, tmp_path):
    proc = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", "250", "--mode", "realtime",
                   "--speed", "100", "--log", str(tmp_path / "rt.csv"), "--no-report", "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["replies"] == 250 and s["missing"] == 0
    assert max(s["max_abs_can_minus_float32_C"].values()) <= 0.005 + 1e-9
    jitter = s["host"]["send_jitter_us"]
    assert jitter["p50"] is not None and 0 <= jitter["p50"] <= jitter["p99"] <= jitter["max"]
    assert s["host"]["wall_time_s"] == pytest.approx(250 * 0.002, rel=0.5)


@pytest.mark.slow
def test_user_errors_are_one_sentence(tmp_path, small_dataset, artifacts):
    bad = tmp_path / "bad.json"
    bad.write_text(artifacts["lti"].read_text().replace('"zoh"', '"tustin"'))
    target = run_cli("-m", "target_sim", "--model", str(bad), "-i", "udp_multicast", "--bus-kwargs",
                     f"port={free_udp_port()}")
    assert target.returncode == 1
    assert target.stderr.strip().count("\n") == 0 and "checksum" in target.stderr
    for argv, needle in (
        (["--model", str(bad)], "checksum"),
        (["--data", str(tmp_path / "missing.csv")], "cannot be read"),
        (["--data", str(small_dataset), "-i", "socketcan", "-c", "vcan9"], "cannot open the CAN bus"),
        (["--data", str(small_dataset), "--log", str(tmp_path / "x.txt")], "unsupported format"),
    ):
        proc = run_cli("-m", "bench", "run", *argv, "--quiet")
        assert proc.returncode != 0, argv
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("bench: error:") and needle in lines[0], proc.stderr
        assert "Traceback" not in proc.stderr
    assert not (tmp_path / "x.txt").exists()


def test_a_target_that_fails_to_start_is_reported_with_its_own_words(artifacts, tmp_path, udp_bus):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with TargetProcess(bad, udp_bus) as target:
        deadline = time.monotonic() + 30
        while target.exit_reason() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        reason = target.exit_reason()
    assert reason is not None and reason.startswith("the target process exited with status 1:")
    assert "not a model artifact" in reason


def test_the_host_reports_a_target_that_dies(small_dataset, udp_bus, tmp_path):
    from bench.drive.dataset import load_dataset
    from bench.model.runs import drive_matrix, initial_temperatures
    from host.procedure import run_dataset

    dataset = load_dataset(small_dataset)
    artifact = load_artifact(default_artifact_path())
    bus = udp_bus.open()
    log = tmp_path / "dies.blf"
    try:
        with TargetProcess(default_artifact_path(), udp_bus) as target:
            def kill_at_row_128(done, total):
                if done >= 128 and target.process.poll() is None:
                    target.process.kill()

            result = run_dataset(bus, drive_matrix(dataset), initial_temperatures(dataset),
                                 model_id=artifact.model_id, log_path=log, progress=kill_at_row_128,
                                 alive=target.exit_reason)
    except Exception:
        raise
    finally:
        bus.shutdown()
    assert result.rows_sent < 600 and result.missing >= 1
    assert result.aborted and "silent" in result.aborted
    problems = " ".join(result.problems())
    assert "aborted" in problems and "got no reply" in problems
    assert log.is_file()  # the log of what happened is kept
