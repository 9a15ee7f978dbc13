"""`bench firmware check`: a dataset through the emulated firmware and the Python float32 reference, bit for bit;
the packaged ELFs are what the compiler builds from the packaged artifacts, byte for byte."""

from __future__ import annotations

import json
import os
import sys

import pytest

from bench.cli import main
from bench.firmware.images import PACKAGED_KINDS, firmware_for, packaged_elf, packaged_elf_path
from bench.model.default import default_artifact_path
from target_sim.artifact import load_artifact

from helpers import patched_elf

REPORT_KEYS = {"kind", "realization", "dt", "steps", "mismatches", "first_mismatch", "cycles", "flash_bytes",
               "ram_bytes", "emulated_steps_per_s"}


def check(capsys, *argv: str) -> tuple[int, str, str]:
    status = main(["firmware", "check", *argv])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.mark.parametrize("kind", PACKAGED_KINDS)
def test_the_packaged_elf_is_what_the_compiler_builds_byte_for_byte(kind, firmware_builds):
    """The shipped ELF is what this run's compiler builds (a build of this run, shared by the firmware tests)."""
    from bench.firmware.codegen import generate

    artifact = load_artifact(default_artifact_path(kind))
    assert packaged_elf(artifact) == packaged_elf_path(kind)
    assert firmware_builds.build(generate(artifact)).elf == packaged_elf_path(kind).read_bytes(), \
        "regenerate the shipped ELFs: python -m bench.firmware.images"


@pytest.mark.parametrize("kind", PACKAGED_KINDS)
def test_check_of_a_packaged_artifact_is_bit_exact_with_cycles_and_sizes(kind, capsys, small_dataset):
    status, out, err = check(capsys, "--model", str(default_artifact_path(kind)), "--data", str(small_dataset),
                             "--json")
    assert status == 0, err
    report = json.loads(out)
    assert REPORT_KEYS <= set(report)
    assert report["kind"] == kind and report["dt"] == 0.5 and report["steps"] == 600 * 0.2 / 0.5
    assert report["mismatches"] == 0 and report["first_mismatch"] is None
    assert 500 < report["cycles"]["p50"] <= report["cycles"]["max"] < 3000
    assert 14_000 < report["flash_bytes"] < 32_000 and 1024 < report["ram_bytes"] < 4096   # model and CAN node
    assert report["emulated_steps_per_s"] > 0     # its speed is a benchmark's figure (a loaded machine is slow)
    assert report["firmware"] == str(packaged_elf_path(kind))


def test_check_of_another_artifact_builds_its_firmware(capsys, small_dataset, artifacts):
    status, out, err = check(capsys, "--model", str(artifacts["modal"]), "--data", str(small_dataset), "--rows",
                             "101", "--quiet")
    assert status == 0, err
    assert "mismatches 0" in out and "40 model steps" in out


def test_a_firmware_that_computes_otherwise_is_a_mismatch_and_exit_1(capsys, small_dataset, tmp_path):
    elf = tmp_path / "off.elf"    # one bit of one sigmoid gain changed: the same model id, other outputs
    gain = packaged_elf_path("hammerstein").read_bytes()
    elf.write_bytes(patched_elf(packaged_elf_path("hammerstein"), "SIG_GAIN", b"\x01", offset=4))
    assert elf.read_bytes() != gain
    status, out, err = check(capsys, "--data", str(small_dataset), "--firmware", str(elf), "--json")
    report = json.loads(out)
    assert status == 1 and report["mismatches"] > 0
    first = report["first_mismatch"]
    assert first["firmware_hex"] != first["reference_hex"] and (first["step"], first["row"]) in ((0, 2), (1, 4))
    line = err.strip()
    assert "\n" not in line and line.startswith("bench: error: the firmware differs from the Python float32 "
                                                f"reference in {report['mismatches']} of {report['steps']} model "
                                                f"steps, first at step {first['step']} (row {first['row']})")


def test_an_elf_for_another_core_or_model_is_one_sentence(capsys, small_dataset):
    status, _, err = check(capsys, "--data", str(small_dataset), "--firmware", os.path.realpath(sys.executable))
    assert status == 1 and err.count("\n") == 1 and "not for an ARM Cortex-M4F" in err
    status, _, err = check(capsys, "--data", str(small_dataset), "--firmware",
                           str(packaged_elf_path("lti-lptn")))
    assert status == 1 and err.count("\n") == 1 and "is the firmware of model" in err


def test_check_of_an_electrical_model_on_data_with_currents(tmp_path):
    """check_firmware (what `bench firmware check` runs) on an electrical loss model's firmware: a drive with the d/q
    currents, bit for bit; a drive without them is one sentence."""
    import numpy as np

    from bench.errors import BenchError
    from bench.firmware.check import check_firmware

    from helpers import electrical_artifact_text, synthetic_columns, with_currents

    model = tmp_path / "electrical.json"
    model.write_text(electrical_artifact_text(), encoding="utf-8")
    artifact = load_artifact(model)
    elf = firmware_for(artifact, tmp_path / "cache")
    c = with_currents(synthetic_columns(600, seed=21, torque_offset=150.0, speed_offset=2000.0))
    drive = np.column_stack([c[name] for name in ("torque_Nm", "speed_rpm", "coolant_C", "ambient_C", "i_d_A",
                                                  "i_q_A")])
    report = check_firmware(artifact, elf, drive, [40.0, 41.0, 40.0, 45.0])
    assert (report["steps"], report["mismatches"], report["first_mismatch"]) == (240, 0, None)
    assert 500 < report["cycles"]["p50"] <= report["cycles"]["max"] < 3000
    with pytest.raises(BenchError) as info:
        check_firmware(artifact, elf, drive[:, :4], [40.0, 41.0, 40.0, 45.0])
    assert str(info.value) == (f"model {artifact.model_id:08x} ({model}) runs on 6 drive values per row (torque_Nm, "
                               "speed_rpm, coolant_C, ambient_C, i_d_A, i_q_A), the data gives 4; its electrical "
                               "loss model needs the d/q currents (data columns i_d_A, i_q_A)")


@pytest.mark.slow   # 7-10 s: the default run keeps its 5-minute budget; .ci/run runs it
def test_a_damaged_cached_image_is_built_again_and_said(tmp_path, artifacts, capsys):
    """A cached image that is text, or an ELF without the functions the engine calls, made every later run fail
    naming a file the user never gave; it is rebuilt in its place, with one line saying so."""
    from target_sim.firmware import read_elf

    artifact = load_artifact(artifacts["lti"])
    first = firmware_for(artifact, tmp_path)
    good = first.read_bytes()
    first.write_text("not an image\n")
    assert firmware_for(artifact, tmp_path) == first and first.read_bytes() == good
    said = capsys.readouterr().err
    assert said.startswith(f"bench: the cached firmware {first} is not a usable image (") and said.count("\n") == 1
    first.write_bytes(packaged_elf_path("hammerstein").read_bytes().replace(b"node_on_frame", b"node_on_fraMe"))
    assert firmware_for(artifact, tmp_path) == first and "fw_step" in read_elf(first).symbols
    assert "lacks node_on_frame; building it again" in capsys.readouterr().err


@pytest.mark.slow   # 12 s loaded: builds twice; kept out of the 5-minute default run
def test_firmware_for_caches_a_build_under_a_key_of_its_sources(tmp_path, artifacts, monkeypatch):
    from bench.firmware import toolchain

    artifact = load_artifact(artifacts["lti"])
    first = firmware_for(artifact, tmp_path)
    assert first.parent == tmp_path and first.name.startswith("lti-lptn-") and first.suffix == ".elf"
    calls = []
    monkeypatch.setattr(toolchain, "build_firmware", lambda generated: calls.append(generated))
    assert firmware_for(artifact, tmp_path) == first and calls == []       # cached: not built again
    # the packaged artifacts need no compiler at all
    monkeypatch.setattr(toolchain, "COMPILER", [str(tmp_path / "no-such-compiler")])
    assert firmware_for(load_artifact(default_artifact_path()), tmp_path) == packaged_elf_path("hammerstein")
    from bench.errors import BenchError

    with pytest.raises(BenchError, match="not packaged and must be built, but the C cross-compiler cannot be "
                                         "started .*reinstall the project"):
        firmware_for(load_artifact(artifacts["modal"]), tmp_path / "other")


def test_the_check_reports_its_progress_through_every_row(small_dataset):
    """The emulated core is the slow part of a check: its bar is told the rows done, up to all of them."""
    from bench.firmware.check import PROGRESS_EVERY, check_firmware
    from bench.model.runs import initial_temperatures
    from bench.run.inputs import drive_for, load_data

    artifact = load_artifact(default_artifact_path("hammerstein"))
    dataset = load_data(small_dataset, artifact, None, quiet=True)
    drive = drive_for(dataset, artifact)[:600]
    calls: list[tuple[int, int]] = []
    result = check_firmware(artifact, packaged_elf_path("hammerstein"), drive, initial_temperatures(dataset),
                            progress=lambda done, total: calls.append((done, total)))
    assert result["mismatches"] == 0
    assert calls[0] == (0, 600) and calls[-1] == (600, 600)
    assert [done for done, _ in calls[1:-1]] == list(range(PROGRESS_EVERY, 600, PROGRESS_EVERY))
