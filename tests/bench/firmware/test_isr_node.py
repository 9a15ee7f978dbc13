"""The firmware node beside the current loop's interrupt (`bench run --engine firmware --isr-rate`): the replies
stay the run without it bit for bit, Timing5 carries each step's response time and the interrupt's load as the
firmware measures them, consistent with the emulated core's own account; the model's flash (fw_model.o) under the
paper's 10.13 kB with each distinct loss-table row stored once, the same bits either way; the refusals of
--isr-rate before any work."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from dbc.codec import FrameValidator
from dbc.contract import FIRMWARE_TIMING_MESSAGE, M4_CLOCK_HZ, RESPONSE_TIMING_MESSAGE
from dbc.database import frame_id

from helpers import ROOT, subprocess_env

PAPER_MODEL_FLASH_BYTES = 10_130          # the paper's 10.13 kB of model code and coefficients
TEMPERATURES = {frame_id("Temperatures1"), frame_id("Temperatures2")}


@pytest.fixture(scope="module")
def isr_image(firmware_builds):
    """(packaged hammerstein artifact, its timing image with the current loop), built once per run."""
    from bench.firmware.codegen import generate
    from bench.model.default import default_artifact_path
    from target_sim.artifact import load_artifact
    from target_sim.firmware import read_elf

    artifact = load_artifact(default_artifact_path("hammerstein"))
    return artifact, read_elf(firmware_builds.build(generate(artifact), isr=True).elf)


def _run(artifact, image, rate: int, rows: int = 40):
    """The drive's frames through a FirmwareNode at `rate` (0: no interrupt), released on a fake clock: each row
    200 ms after the last, its frames 250 µs apart plus a phase that walks across the PWM period."""
    from bench.firmware.timing import _frames
    from target_sim.firmware.node_engine import FirmwareNode

    rng = np.random.default_rng(5)
    drive = np.column_stack([rng.uniform(-300, 300, rows), rng.uniform(0, 7000, rows), np.full(rows, 65.0),
                             np.full(rows, 25.0)])
    clock = [0.0]
    node = FirmwareNode(artifact, image, isr_rate_hz=rate, clock_s=lambda: clock[0])
    replies, jobs = [], []
    for index, group in enumerate(_frames(artifact, drive, [60.0] * 4)):
        for position, frame in enumerate(group):
            clock[0] = 0.2 * index + 250e-6 * position + 13e-6 * (index % 11)
            out = node.handle(frame)
            replies += out
            if rate and any(reply.arbitration_id == frame_id(RESPONSE_TIMING_MESSAGE) for reply in out):
                jobs.append(node.fw.jobs[-1])
    return node, replies, jobs


def _decoded(replies, name: str) -> list[dict]:
    validator = FrameValidator("HOST")
    return [dict(validator.validate(r).signals) for r in replies if r.arbitration_id == frame_id(name)]


def test_the_interrupt_leaves_every_reply_bit_for_bit_and_timing5_measures_the_response(isr_image):
    from bench.firmware.images import packaged_elf_path

    artifact, image = isr_image
    _, shipped, _ = _run(artifact, packaged_elf_path("hammerstein"), 0)
    assert not _decoded(shipped, RESPONSE_TIMING_MESSAGE)          # the shipped image sends no Timing5
    for rate in (10_000, 20_000):
        node, replies, jobs = _run(artifact, image, rate)
        assert [bytes(r.data) for r in replies if r.arbitration_id in TEMPERATURES] == \
            [bytes(r.data) for r in shipped if r.arbitration_id in TEMPERATURES]
        names = [r.arbitration_id for r in replies]
        timing4, timing5 = _decoded(replies, FIRMWARE_TIMING_MESSAGE), _decoded(replies, RESPONSE_TIMING_MESSAGE)
        assert len(timing5) == len(timing4) == node.counters()["model_steps"] > 10
        assert names.index(frame_id(RESPONSE_TIMING_MESSAGE)) == names.index(frame_id(FIRMWARE_TIMING_MESSAGE)) + 1
        figures = node.stats()["isr"]
        assert figures["period_cycles"] == M4_CLOCK_HZ // rate and figures["interrupts"] > len(timing5)
        us = 1e6 / M4_CLOCK_HZ
        for t4, t5, job in zip(timing4, timing5, jobs, strict=True):
            assert t5["Step"] == t4["Step"]
            # reception -> result: at least the step itself, at most the whole job (the node's work after the step)
            assert t4["M4ExecTime"] <= t5["ResponseTime"] <= job.response * us + 0.05
        preempted = [job for job in jobs if job.preemptions]
        assert preempted, "the interrupt never preempted a step's job: the phases do not walk across the period"
        # the firmware's own load figure sees the handler from its first DWT read to its last plus entry and return:
        # below the core's account (prologue, epilogue and the FP context's unstacking are outside), not far below
        loads = [t5["IsrLoad"] for t5 in timing5[1:]]
        assert 0.6 * figures["cpu_load_percent"] < np.mean(loads) <= figures["cpu_load_percent"]


def test_the_handler_reads_the_timeline_on_dwt(isr_image):
    """DWT_CYCCNT inside the handler counts on the core's timeline from the handler's first instruction: what it
    adds to foc_busy_cycles per interrupt (its DWT window + 22) is most of its own counted cycles (its prologue and
    epilogue, ~60 cycles of register saves, lie outside the window) and never more than all it took from the core;
    a DWT frozen during the handler would give 22."""
    from target_sim.firmware.motor_control import motor_control_core, start_motor_control

    _, image = isr_image
    fw = motor_control_core(image, rate_hz=10_000)
    fw.call("node_init", 0)                        # the DWT on, as the node does
    start_motor_control(fw, rate_hz=10_000)
    busy = fw.address("foc_busy_cycles")
    previous = 0
    for release in range(1, 8):
        fw.idle_until(fw.now + 9000)
        total = int(fw.read_i32(busy, 1).view(np.uint32)[0])
        event = fw.isr_events[-1]
        assert 0.75 * event.handler_cycles <= total - previous <= event.busy, (release, event)
        previous = total


@pytest.mark.parametrize("kind", ["hammerstein", pytest.param("lti-lptn", marks=pytest.mark.slow),
                                  pytest.param("pv-lptn", marks=pytest.mark.slow)])
def test_model_flash_is_under_the_papers_figure_for_every_packaged_kind(kind, firmware_builds):
    """fw_model.o in the map: each distinct loss-table row once (the maps are symmetric in torque: 55 of 105
    rows are distinct) takes the Hammerstein model from 11 454 to 8 403 bytes."""
    from bench.firmware.codegen import generate
    from bench.model.default import default_artifact_path
    from target_sim.artifact import load_artifact

    build = firmware_builds.build(generate(load_artifact(default_artifact_path(kind))))
    flash = build.model_flash
    assert flash["bytes"] == flash["code"] + flash["constants"] < PAPER_MODEL_FLASH_BYTES, flash
    assert flash["constants"] < 5 * 21 * 16 * 4           # below the five whole 21 x 16 float32 tables
    assert "LOSS_TABLES_ROWS" in build.sources["fw_model.c"] and "[55][16]" in build.sources["fw_model.c"]
    assert "double" not in build.sources["fw_model.c"]


def test_shared_rows_only_when_they_save_flash():
    from bench.firmware.codegen import _c_shared_rows

    rows = np.array([[f"0x{i}p+0f" for i in range(1, 4)], [f"0x{i}p+1f" for i in range(1, 4)]], dtype=object)
    mirrored = np.stack([np.stack([rows[0], rows[1], rows[0]])] * 2)     # 2 tables of 3 rows, 2 distinct rows
    text = _c_shared_rows("T", mirrored, "t")
    assert "static const float T_ROWS[2][3]" in text and "static const uint8_t T_ROW_INDEX[2][3]" in text
    assert "{0u, 1u, 0u}" in text and "#define T_ROW(k, r) (T_ROWS[T_ROW_INDEX[k][r]])" in text
    distinct = np.array([[[f"0x{i + 3 * r + 9 * k}p+0f" for i in range(3)] for r in range(3)] for k in range(2)],
                        dtype=object)
    text = _c_shared_rows("T", distinct, "t")
    assert "static const float T[2][3][3]" in text and "T_ROW_INDEX" not in text
    assert "#define T_ROW(k, r) (T[k][r])" in text


def test_a_table_without_repeated_rows_runs_the_whole_array_bit_for_bit():
    """An artifact whose loss tables share no row (each row nudged): the whole-array layout, the same outputs as
    the Python float32 reference."""
    from bench.firmware.check import check_firmware
    from bench.firmware.codegen import generate
    from bench.firmware.toolchain import build_firmware
    from bench.model.default import default_artifact_path
    from target_sim.artifact import encode_array, seal, verify

    content = json.loads(default_artifact_path("hammerstein").read_text())
    for name, entry in content["losses"]["tables"].items():
        table = np.array(entry["f64"], dtype=float).reshape(entry["shape"])
        table += np.arange(table.shape[0])[:, None] * 1e-3 + (1.0 if name == "current" else 0.0)
        content["losses"]["tables"][name] = encode_array(table)
    artifact = verify(seal(content))
    generated = generate(artifact)
    assert "LOSS_TABLES_ROWS" not in generated.source and "LOSS_TABLES_ROW(k, r) (LOSS_TABLES[k][r])" in \
        generated.source
    rng = np.random.default_rng(2)
    drive = np.column_stack([rng.uniform(-700, 700, 300), rng.uniform(-200, 9800, 300), np.full(300, 60.0),
                             np.full(300, 25.0)])
    result = check_firmware(artifact, build_firmware(generated).elf, drive, [60.0] * 4)
    assert result["mismatches"] == 0 and result["steps"] > 100


@pytest.mark.parametrize(("argv", "sentence"), [
    (["--isr-rate", "10000"], "--isr-rate runs the motor-control interrupt in the emulated core of the firmware "
                              "engine, not the python engine"),
    (["--engine", "firmware", "--isr-rate", "900000"], "--isr-rate 900000 is not a current-loop rate"),
    (["--engine", "firmware", "--isr-rate", "-5"], "'-5' must be a whole number, 0 or more"),
])
def test_bench_run_refuses_isr_rate_before_any_work(tmp_path, capsys, argv, sentence):
    from bench.cli import main

    log = tmp_path / "run" / "bench.blf"
    with pytest.raises(SystemExit) as exited:       # argparse's own exit for a bad type, else the status
        raise SystemExit(main(["run", "--rows", "5", "--log", str(log), "--no-report",
                               "--data", str(tmp_path / "absent.csv"), *argv]))
    err = capsys.readouterr().err
    assert exited.value.code == 2 and sentence in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and not log.parent.exists()


def test_the_target_refuses_isr_rate_without_the_firmware_engine(capsys):
    from bench.model.default import default_artifact_path
    from target_sim.__main__ import main

    with pytest.raises(SystemExit) as exited:
        main(["--model", str(default_artifact_path()), "--isr-rate", "10000", "-i", "udp_multicast"])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and "--isr-rate runs the motor-control interrupt in the firmware engine" in err


@pytest.mark.slow
def test_bench_run_with_the_interrupt_is_clean_and_reports_the_response_time(tmp_path):
    """The whole loop: the host, the bus, the target with the timing image at 20 kHz (waits for the run, which
    compiles the image once: up to 10 minutes on a loaded machine)."""
    done = subprocess.run([sys.executable, "-m", "bench", "run", "--engine", "firmware", "--isr-rate", "20000",
                           "--rows", "150", "--log", str(tmp_path / "bench.blf"), "--report", str(tmp_path / "r"),
                           "--json"], cwd=ROOT, env=subprocess_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    metrics = summary["metrics"]
    assert summary["clean"] and summary["firmware"].endswith(".elf") and "-isr-" in summary["firmware"]
    response = metrics["response_time_us"]
    assert metrics["m4_exec_time_us"]["p50"] <= response["p50"] <= response["p99"] <= response["max"] < 100
    assert 2.0 < metrics["isr_load_percent"] < 20.0
    report = (tmp_path / "r" / "report.md").read_text(encoding="utf-8")
    assert "model step response time p50 / p99 / max, beside the current loop's interrupt" in report
    assert "current loop interrupt at 20000 Hz" in report
