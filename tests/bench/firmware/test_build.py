"""`bench firmware export` and `build`: the generated C (exact literals, no double, warning-free for every kind and
realization), deterministic ELFs, the JSON sizes, and one-sentence errors for a missing toolchain and for
artifacts the generator cannot express."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest

from bench.cli import main
from bench.firmware import codegen, toolchain
from bench.firmware.codegen import FirmwareGenerationError, c_float, generate
from target_sim.artifact import ModelArtifact, dumps, seal
from target_sim.firmware import Firmware, memory_from_elf

# what export writes (and build beside the ELF and map): the generated model and node files, the shipped ones
SOURCES = ["fw_model.c", "fw_model.h", "fw_node_config.h", "thermal_bench.c", "thermal_bench.h", "node.c", "node.h",
           "xcp.c", "string.h", "startup.c", "firmware.ld"]

# each compiles a firmware (5-25 s on a loaded machine): the default run keeps one per kind, the other realizations
# run under `-m slow` (as .ci/run does; the default run has a 5-minute budget)
DEFAULT_RUN_BUILDS = (("lti-lptn", "physical"), ("hammerstein", "balanced"), ("pv-lptn", "physical"))
KIND_REALIZATIONS = [("lti-lptn", r) for r in ("physical", "original", "balanced", "modal")]
KIND_REALIZATIONS += [("hammerstein", r) for r in ("physical", "original", "balanced", "modal")]
KIND_REALIZATIONS += [("pv-lptn", "physical")]
KIND_REALIZATION_CASES = [pair if pair in DEFAULT_RUN_BUILDS else pytest.param(*pair, marks=pytest.mark.slow)
                          for pair in KIND_REALIZATIONS]
HEX_FLOAT = re.compile(r"-?0x[0-9a-f]+(?:\.[0-9a-f]*)?p[+-]\d+f?")


def test_c_float_is_exact_hex_with_the_f_suffix():
    assert c_float(12.0) == "0x1.8p+3f"
    assert c_float(-0.0) == "-0x0p+0f"
    assert c_float(1.0) == "0x1p+0f"
    assert c_float(np.float32(0.1)) == "0x1.99999ap-4f"
    tiny = float(np.float32(1e-40))                   # a float32 subnormal: still exact
    assert float.fromhex(c_float(tiny)[:-1]) == tiny
    with pytest.raises(FirmwareGenerationError, match="not a finite float32"):
        c_float(0.1)                                  # a double that float32 cannot hold
    with pytest.raises(FirmwareGenerationError):
        c_float(float("inf"))


@pytest.mark.parametrize(("kind", "realization"), KIND_REALIZATION_CASES)
def test_generated_c_is_float_only_and_compiles_warning_free(firmware_of, kind, realization):
    artifact, build = firmware_of(kind, realization, 0.5)    # the build compiles with -Werror and more warnings
    source = build.sources[codegen.SOURCE_NAME]
    assert "-Werror" in toolchain.WARNING_FLAGS and "-Wdouble-promotion" in toolchain.WARNING_FLAGS
    assert not re.search(r"\bdouble\b", re.sub(r"/\*.*?\*/", "", source, flags=re.S))
    literals = HEX_FLOAT.findall(source)
    assert literals and all(lit.endswith("f") for lit in literals)
    assert not re.search(r"(?<![\w.])\d+\.\d*(?![\w.])", re.sub(r"/\*.*?\*/", "", source, flags=re.S))  # 1.0 sans f
    # every coefficient is the artifact's f32_hex, exactly
    values = {float.fromhex(lit[:-1]) for lit in literals}
    content = artifact.content
    tables = [content["losses"]["tables"][name]["f32_hex"] for name in content["losses"]["tables"]]
    matrices = [] if kind == "pv-lptn" else [content["linear_block"][m]["f32_hex"] for m in ("A", "B", "C", "C_inv")]
    for entry in tables + matrices:
        assert {float.fromhex(h) for h in entry} <= values
    assert ("input_nonlinearity" in source) == (kind == "hammerstein")
    assert ("pv_network" in source) == (kind == "pv-lptn")
    assert f"0x{artifact.model_id:08x}u" in source
    elf = Firmware.load(build.elf, count_cycles=False)
    for name in ("fw_reset", "fw_restore", "fw_state", "fw_output", "fw_step", "fw_accumulate", "fw_mean",
                 "fw_clear", "fw_exp", "fw_model_id", "Reset_Handler", "_estack"):
        assert name in elf.symbols
    assert elf.read_i32(elf.address("fw_model_id"), 1).view(np.uint32)[0] == artifact.model_id


# pv-lptn kept out of the 5-min default run
@pytest.mark.slow   # 13 s loaded; test_export_and_build_of_an_electrical_model builds one in the default run
@pytest.mark.parametrize("kind", ["hammerstein", "pv-lptn"])
def test_an_electrical_loss_model_is_generated_float_only_without_tables_or_libm(electrical_of, kind):
    """The electrical loss model's C: its coefficients as the artifact's f32_hex, no loss tables, six inputs per
    row in the API, sqrt and |x| by the builtins (VSQRT.F32, VABS.F32 with -fno-math-errno), nothing to link."""
    from target_sim.losses.electrical import COEFFICIENTS as ELECTRICAL_COEFFICIENTS

    artifact, build = electrical_of(kind, "physical" if kind == "pv-lptn" else "balanced", 0.5)
    source, header = build.sources[codegen.SOURCE_NAME], build.sources[codegen.HEADER_NAME]
    code = re.sub(r"/\*.*?\*/", "", source, flags=re.S)
    assert not re.search(r"\bdouble\b", code) and not re.search(r"(?<![\w.])\d+\.\d*(?![\w.])", code)
    assert "electrical_losses" in code and "LOSS_TABLES" not in code and "loss_lookup" not in code
    assert "__builtin_sqrtf" in code and "__builtin_fabsf" in code and "-fno-math-errno" in toolchain.CODE_FLAGS
    values = {float.fromhex(lit[:-1]) for lit in HEX_FLOAT.findall(source)}
    for name in ("current_max_A", *ELECTRICAL_COEFFICIENTS):
        assert {float.fromhex(h) for h in artifact.content["losses"][name]["f32_hex"]} <= values, name
    for declaration in ("#define FW_INPUTS 6", '#define FW_LOSS_MODEL "electrical"',
                        "void fw_step(const float u[6], float y[4]);", "void fw_accumulate(const float sample[6]);",
                        "unsigned int fw_mean(float u[6]);"):
        assert declaration in header
    assert "static float acc_sum[6];" in source
    config = build.sources["fw_node_config.h"]
    assert "#define NODE_ROW_WIDTH 6u" in config and "#define NODE_ROW_INDEX_DRIVE_CURRENTS 2u" in config
    elf = Firmware.load(build.elf, count_cycles=False)
    assert elf.read_i32(elf.address("fw_model_id"), 1).view(np.uint32)[0] == artifact.model_id
    assert "node_on_frame" in elf.symbols and not [n for n in elf.symbols if "sqrt" in n]


def test_a_loss_map_model_keeps_its_four_inputs(firmware_of):
    _, build = firmware_of("lti-lptn", "balanced", 0.5)
    assert "#define FW_INPUTS 4" in build.sources[codegen.HEADER_NAME]
    assert "electrical_losses" not in build.sources[codegen.SOURCE_NAME]
    config = build.sources["fw_node_config.h"]
    assert "#define NODE_ROW_MESSAGES 2u" in config and "NODE_ROW_INDEX_DRIVE_CURRENTS" not in config


@pytest.mark.slow   # two builds: kept out of the 5-min default run
def test_build_is_deterministic_and_holds_no_path(firmware_of):
    artifact, first = firmware_of("hammerstein", "balanced", 0.5)
    second = toolchain.build_firmware(generate(artifact))
    assert second.elf == first.elf
    assert second.map_text == first.map_text
    for needle in (b"/tmp", b"bench-firmware-", b"/root", b"/home"):
        assert needle not in first.elf
        assert needle.decode() not in first.map_text
    assert firmware_of("hammerstein", "modal", 0.5)[1].elf != first.elf     # another model, other bytes


def test_memory_map_and_vector_table(firmware_of):
    _, build = firmware_of("lti-lptn", "balanced", 0.5)
    fw = Firmware.load(build.elf, count_cycles=False)
    sections = build.memory["sections"]
    assert set(sections) >= {".isr_vector", ".text", ".rodata", ".bss", ".stack"}
    assert ".ARM.exidx" not in sections
    assert build.memory["stack_bytes"] == sections[".stack"] == 1024
    # vector table at the start of flash: initial SP = _estack, reset vector = Reset_Handler (Thumb bit set)
    sp, reset = np.frombuffer(fw.read_bytes(0x0800_0000, 8), "<u4")
    ram = sections.get(".data", 0) + sections[".bss"]      # .data: the calibratable alpha_cu (XCP)
    assert sp == fw.address("_estack") == 0x2000_0000 + ram + (-ram % 8) + 1024
    assert reset == fw.address("Reset_Handler") | 1
    assert "fw_step" in build.map_text and "fw_model.o" in build.map_text


def run(capsys, *argv: str) -> tuple[int, str, str]:
    status = main(["firmware", *argv])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.mark.slow   # 26 s loaded: a build of its own
def test_build_json_gives_the_elf_section_sizes(tmp_path, capsys, artifacts):
    out = tmp_path / "fw"
    status, stdout, stderr = run(capsys, "build", "--model", str(artifacts["pv"]), "--out", str(out), "--json")
    assert status == 0, stderr
    report = json.loads(stdout)
    assert sorted(p.name for p in out.iterdir()) == sorted([*SOURCES, "firmware.elf", "firmware.map"])
    elf = out / "firmware.elf"
    assert report["elf"] == str(elf) and report["kind"] == "pv-lptn" and report["realization"] == "physical"
    assert report["toolchain"].startswith("zig ")
    measured = memory_from_elf(elf)
    sections = report["sections"]
    assert report["flash_bytes"] == measured["flash_bytes"] == sum(
        sections[name] for name in (".isr_vector", ".text", ".rodata", ".data") if name in sections)
    assert report["ram_bytes"] == measured["ram_bytes"] == sum(
        sections[name] for name in (".data", ".bss", ".stack") if name in sections)
    assert 2_000 < report["flash_bytes"] < 64_000 and 1024 < report["ram_bytes"] < 4096
    # a second build into the same directory replaces the earlier output
    status, stdout2, _ = run(capsys, "build", "--model", str(artifacts["pv"]), "--out", str(out), "--json")
    assert status == 0 and json.loads(stdout2)["elf_sha256"] == report["elf_sha256"]


def test_export_writes_the_header_and_source(tmp_path, capsys, artifacts):
    out = tmp_path / "c"
    status, stdout, _ = run(capsys, "export", "--model", str(artifacts["hammerstein"]), "--out", str(out))
    assert status == 0 and "fw_model.c" in stdout
    assert sorted(p.name for p in out.iterdir()) == sorted(SOURCES)
    header = (out / "fw_model.h").read_text()
    for declaration in ("void fw_reset(const float y0[4]);", "void fw_step(const float u[4], float y[4]);",
                        "unsigned int fw_mean(float u[4]);", "float fw_exp(float x);"):
        assert declaration in header
    status, _, _ = run(capsys, "export", "--model", str(artifacts["hammerstein"]), "--out", str(out), "--quiet")
    assert status == 0


def one_sentence(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bench: error: "), err
    assert "Traceback" not in err
    return lines[0]


def test_missing_toolchain_is_one_sentence_and_writes_nothing(tmp_path, capsys, artifacts, monkeypatch):
    monkeypatch.setattr(toolchain, "COMPILER", [sys.executable, "-m", "no_such_compiler_module_here"])
    out = tmp_path / "fw"
    status, _, err = run(capsys, "build", "--model", str(artifacts["lti"]), "--out", str(out), "--quiet")
    line = one_sentence(err)
    assert status == 1 and "cross-compiler" in line and "not available" in line and "pip install" in line
    assert not out.exists()
    monkeypatch.setattr(toolchain, "COMPILER", [str(tmp_path / "no-such-program")])
    status, _, err = run(capsys, "build", "--model", str(artifacts["lti"]), "--out", str(out), "--quiet")
    assert status == 1 and "cannot be started" in one_sentence(err)
    assert not out.exists()


@pytest.mark.slow   # kept out of the 5-min default run
def test_the_compiler_is_asked_its_version_once_per_process_and_compiler(monkeypatch):
    """Each build names its toolchain; asking `python -m ziglang version` again for every build of a process cost a
    process start each (88 in one test run). A missing compiler is still asked, and still refused."""
    asked = []
    real = toolchain._run

    def counting(args, cwd, what):
        asked.append(tuple(toolchain.COMPILER))
        return real(args, cwd, what)

    monkeypatch.setattr(toolchain, "_run", counting)
    monkeypatch.setattr(toolchain, "_VERSIONS", {})
    first = toolchain.toolchain_version()
    assert toolchain.toolchain_version() == first and first.startswith("zig ") and len(asked) == 1
    monkeypatch.setattr(toolchain, "COMPILER", [sys.executable, "-m", "no_such_compiler_module_here"])
    for _ in range(2):
        with pytest.raises(toolchain.ToolchainError, match="not available"):
            toolchain.toolchain_version()
    assert len(asked) == 3


def test_a_failing_compile_is_one_sentence(monkeypatch, artifacts):
    from target_sim.artifact import load_artifact

    generated = generate(load_artifact(artifacts["lti"]))
    broken = codegen.GeneratedSource(generated.header, generated.source + "\nstatic double unused_double;\n",
                                     generated.node)
    with pytest.raises(toolchain.ToolchainError, match=r"^compiling fw_model\.c for the Cortex-M4F failed: .*error"):
        toolchain.build_firmware(broken)


def resealed(path, **changes) -> dict:
    content = json.loads(path.read_text())
    content.update(changes)
    return seal(content)


def test_an_artifact_the_generator_cannot_express_is_refused(tmp_path, capsys, artifacts):
    bad = tmp_path / "bad.json"
    bad.write_text(dumps(resealed(artifacts["lti"], realization="jordan")))
    status, _, err = run(capsys, "export", "--model", str(bad), "--out", str(tmp_path / "out"))
    assert status == 1 and "realization" in one_sentence(err) and "jordan" in err
    assert not (tmp_path / "out").exists()
    # the generator's own check, for an artifact that bypassed the loader's
    for changes, words in (({"realization": "jordan"}, "realization 'jordan' cannot be generated"),
                           ({"model_kind": "neural"}, "model kind 'neural' cannot be generated")):
        with pytest.raises(FirmwareGenerationError, match=words):
            generate(ModelArtifact(resealed(artifacts["lti"], **changes), None))


def test_export_and_build_of_an_electrical_model(tmp_path, capsys):
    from helpers import electrical_artifact_text

    model = tmp_path / "electrical.json"
    model.write_text(electrical_artifact_text(), encoding="utf-8")
    status, stdout, err = run(capsys, "export", "--model", str(model), "--out", str(tmp_path / "c"))
    assert status == 0, err
    assert "void fw_step(const float u[6], float y[4]);" in (tmp_path / "c" / "fw_model.h").read_text()
    status, stdout, err = run(capsys, "build", "--model", str(model), "--out", str(tmp_path / "fw"), "--json")
    assert status == 0, err
    report = json.loads(stdout)
    assert report["kind"] == "hammerstein" and memory_from_elf(tmp_path / "fw" / "firmware.elf")["flash_bytes"] == \
        report["flash_bytes"]
    assert 2_000 < report["flash_bytes"] < 32_000 and 1024 < report["ram_bytes"] < 4096


def test_a_directory_with_other_files_is_not_replaced(tmp_path, capsys, artifacts):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    status, _, err = run(capsys, "export", "--model", str(artifacts["lti"]), "--out", str(out))
    assert status == 1 and "notes.txt" in one_sentence(err)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    status, _, err = run(capsys)
    assert status == 2 and "export, build" in one_sentence(err)
