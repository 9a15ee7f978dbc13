"""The firmware engine through real processes: `bench run --engine firmware` answers exactly as the Python engine,
with measured Cortex-M4F cycles and the ELF's flash and RAM in the log, the JSON and the report; `bench replay`
and `bench analyze` read them back; `python -m target_sim --engine firmware` serves a host; a firmware that faults
ends the run in one sentence naming the fault, never a hang."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from bench.analysis.logdecode import decode_log
from bench.firmware.images import packaged_elf_path
from bench.model.default import default_artifact_path
from target_sim.firmware import memory_from_elf

from helpers import patched_elf, run_cli, start_target

ROWS = 400
# DWT-measured cycles of one Hammerstein step in the packaged ELF (delta realization): fw_step's 1414 plus the
# call and the counter reads; the emulated count is exact and the ELF is rebuilt byte for byte, so it cannot drift
# (1403 before the loss tables stored each distinct row once: fw_step 1391, 23 cycles for the row index loads)
# (1426 before the XCP slave: alpha_cu is now read from its RAM variable, fw_cal_alpha_cu)
STEP_CYCLES = 1422


@pytest.fixture(scope="module")
def runs(tmp_path_factory, small_dataset):
    """{engine: (json summary, log, report dir)} of `bench run` with each engine on the same rows."""
    out = {}
    for engine in ("python", "firmware"):
        directory = tmp_path_factory.mktemp(engine)
        log, report = directory / "bench.blf", directory / "report"
        proc = run_cli("-m", "bench", "run", "--engine", engine, "--data", str(small_dataset), "--rows", str(ROWS),
                       "--log", str(log), "--report", str(report), "--json")
        assert proc.returncode == 0, proc.stderr + proc.stdout[-3000:]   # the JSON's verdict says why not clean
        out[engine] = (json.loads(proc.stdout), log, report)
    return out


def test_bench_run_with_the_firmware_engine_answers_as_the_python_engine(runs):
    firmware, log, report = runs["firmware"]
    python, python_log, _ = runs["python"]
    assert (firmware["engine"], python["engine"]) == ("firmware", "python")
    assert firmware["firmware"] == str(packaged_elf_path("hammerstein")) and python["firmware"] is None
    assert firmware["clean"] and (firmware["steps_sent"], firmware["missing"]) == (ROWS, 0)
    assert np.array_equal(decode_log(log).temps, decode_log(python_log).temps)   # every reply, exactly
    # the measured Cortex-M4F cycles beside the C28x estimate; the ELF's flash and RAM instead of the estimate
    assert firmware["m4_cycles"] == {"p50": STEP_CYCLES, "max": STEP_CYCLES} and python["m4_cycles"] is None
    assert firmware["est_cycles"] == python["est_cycles"] > 0
    measured = memory_from_elf(packaged_elf_path("hammerstein"))
    assert (firmware["flash_bytes"], firmware["ram_bytes"]) == (measured["flash_bytes"], measured["ram_bytes"])
    assert firmware["memory_source"] == "firmware ELF" and python["memory_source"] == "C28x estimate"
    m = firmware["metrics"]
    assert (m["est_flash_bytes"], m["est_ram_bytes"]) == (python["flash_bytes"], python["ram_bytes"])
    assert m["m4_exec_time_us"]["p50"] == pytest.approx(STEP_CYCLES / 90, abs=0.05) and m["m4_clock_mhz"] == 90
    text = (report / "report.md").read_text()
    cycles_row = (f"| measured Cortex-M4F cycles p50 / max (emulated firmware) / time at 90 MHz | {STEP_CYCLES} / "
                  f"{STEP_CYCLES} / {m['m4_exec_time_us']['p50']:.1f} µs |")
    assert cycles_row in text
    assert f"| flash / RAM, Cortex-M4F ELF (measured) | {measured['flash_bytes']} B / {measured['ram_bytes']} B |" \
        in text
    assert "| target engine | firmware (default_model.elf, emulated Cortex-M4F) |" in text
    assert "measured Cortex-M4F cycles | – (the Python engine" in (runs["python"][2] / "report.md").read_text()


@pytest.mark.slow
def test_replay_and_analyze_of_a_firmware_log(runs, tmp_path, small_dataset):
    summary, log, _ = runs["firmware"]
    replay = run_cli("-m", "bench", "replay", str(log), "--as-fast-as-possible", "--log", str(tmp_path / "r.blf"),
                     "--json")
    assert replay.returncode == 0, replay.stderr
    r = json.loads(replay.stdout)
    assert r["reproduced"] and r["identical"] == ROWS and r["engine"] == "firmware"   # the log's engine
    assert r["m4_cycles"]["p50"] == STEP_CYCLES
    analyzed = run_cli("-m", "bench", "analyze", str(log), "--data", str(small_dataset), "--report",
                       str(tmp_path / "rep"), "--json")
    assert analyzed.returncode == 0, analyzed.stderr
    a = json.loads(analyzed.stdout)
    assert a["m4_cycles"] == summary["m4_cycles"] and a["engine"] == "firmware"


def test_target_sim_with_the_firmware_engine_serves_a_host(tmp_path, small_dataset, udp_bus):
    stats = tmp_path / "target.json"
    with start_target("--model", default_artifact_path(), "--engine", "firmware", "--firmware",
                      packaged_elf_path("hammerstein"), "--stats", stats, *udp_bus.to_argv(), stderr=subprocess.PIPE,
                      text=True) as target:
        host = run_cli("-m", "bench", "host", "--data", str(small_dataset), "--rows", "200", "--log",
                       str(tmp_path / "h.blf"), "--json", *udp_bus.to_argv())
    target_err = target.stderr    # stopped with SIGTERM as the block ended
    assert host.returncode == 0, host.stderr
    result = json.loads(host.stdout)
    assert result["replies"] == 200 and result["engine"] == "firmware" and result["m4_cycles"]["max"] == STEP_CYCLES
    assert target.returncode == 0, target_err
    assert f"firmware node {packaged_elf_path('hammerstein')}" in target_err
    counters = json.loads(stats.read_text())
    assert counters["engine"] == "firmware" and counters["m4_cycles"] == {"p50": STEP_CYCLES, "max": STEP_CYCLES}
    assert counters["memory"] == "measured from the firmware ELF"


def test_a_firmware_fault_ends_the_run_in_one_sentence_naming_it(tmp_path, small_dataset, udp_bus):
    """The emulated core hits an undefined instruction in fw_step: the target goes FAULT (INTERNAL) and keeps its
    heartbeat, the host stops at once instead of waiting out the rows, and the reason names the fault."""
    from bench.drive.dataset import load_dataset
    from bench.model.runs import drive_matrix, initial_temperatures
    from bench.run.execute import run_with_target
    from target_sim.artifact import load_artifact

    broken = tmp_path / "broken.elf"
    broken.write_bytes(patched_elf(packaged_elf_path("hammerstein"), "fw_step", b"\xfe\xde"))
    dataset = load_dataset(small_dataset)
    outcome = run_with_target(default_artifact_path(), load_artifact(default_artifact_path()), udp_bus,
                              drive_matrix(dataset)[:200], initial_temperatures(dataset),
                              log_path=tmp_path / "x.blf", firmware=broken)
    result = outcome.result
    assert result.aborted is not None and result.rows_sent < 10
    assert result.aborted.startswith("the target reported an internal fault at row 2 (state FAULT, fault bits "
                                     "INTERNAL)")
    assert "node_on_frame in " in result.aborted and "(in fw_step)" in result.aborted and \
        "undefined instruction" in result.aborted
    assert outcome.target_status == 0       # it kept serving until it was stopped
    assert result.problems()[0].startswith("the run was aborted: the target reported an internal fault")


@pytest.mark.slow
def test_bench_host_against_a_firmware_that_computes_something_else_is_not_clean(tmp_path, small_dataset, udp_bus):
    """Issue 23, item 2: the packaged firmware with its loss table scaled by 1.5 (its model id intact, so the host's
    heartbeat check passes) served to `bench host`: the replies are compared with the offline float32 reference as
    `bench run` compares them, so the run is not clean, and the rows off the reference reach no figure."""
    from elftools.elf.elffile import ELFFile

    elf = packaged_elf_path("hammerstein")
    with elf.open("rb") as handle:
        symbol = ELFFile(handle).get_section_by_name(".symtab").get_symbol_by_name("LOSS_TABLES_ROWS")[0]
    image = elf.read_bytes()
    with elf.open("rb") as handle:
        sections = list(ELFFile(handle).iter_sections())
        section = next(s for s in sections if s["sh_addr"] <= symbol["st_value"] < s["sh_addr"] + s["sh_size"]
                       and s["sh_type"] != "SHT_NOBITS")
        at = section["sh_offset"] + symbol["st_value"] - section["sh_addr"]
    values = np.frombuffer(image[at:at + symbol["st_size"]], dtype="<f4")
    altered = tmp_path / "altered.elf"
    altered.write_bytes(patched_elf(elf, "LOSS_TABLES_ROWS", (values * 1.5).astype("<f4").tobytes()))
    with start_target("--model", default_artifact_path(), "--engine", "firmware", "--firmware", altered,
                      *udp_bus.to_argv(), stderr=subprocess.PIPE, text=True):
        host = run_cli("-m", "bench", "host", "--data", str(small_dataset), "--rows", "200", "--log",
                       str(tmp_path / "h.blf"), "--json", *udp_bus.to_argv())
        text = run_cli("-m", "bench", "host", "--data", str(small_dataset), "--rows", "60", "--log",
                       str(tmp_path / "t.blf"), "--quiet", *udp_bus.to_argv())
    assert host.returncode == 1, host.stderr
    result = json.loads(host.stdout)
    assert (result["replies"], result["missing"], result["clean"]) == (200, 0, False)
    assert max(result["max_abs_can_minus_float32_C"].values()) > 0.1
    rows = result["figure_rows"]
    off = rows["excluded"]["off_reference"]
    assert off > 100 and rows["kept"] + off == 200 and rows["without_reply"] == 0
    assert result["verdict"].startswith("not clean: CAN temperatures differ from the offline float32 reference by up "
                                        "to ")
    assert result["verdict"].endswith(f"at {off} rows, which are left out of every figure")
    assert result["metrics"]["figure_rows"] == rows
    assert text.returncode == 1
    assert "bench: host: CAN temperatures differ from the offline float32 reference by up to " in text.stderr
