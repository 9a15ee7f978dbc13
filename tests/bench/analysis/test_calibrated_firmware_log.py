"""`bench analyze` of a firmware target calibrated over XCP during its run: the twin that replays the logged
DOWNLOADs lays out its cells by the target's ELF (the C slave's cells are its RAM variables), so the calibrated run
is clean and bit-exact against its calibrated reference; a calibration the log does not record, or records with
another value, is not clean, and neither is the twin laid out by the Python slave's pages (what analyze did before).

The firmware node runs in-process (the emulated Cortex-M4F, no bus): each host frame is logged, then the node's
replies, as a lockstep host's log holds them."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import can
import numpy as np
import pytest

from bench.analysis.canmetrics import compute
from bench.analysis.logdecode import decode_log
from bench.analysis.twin import twin_estimates
from bench.analysis.verdict import problems
from dbc.xcp import cmd_id, res_id
from target_sim.artifact import load_artifact
from target_sim.xcp.codes import Cmd

from helpers import ROOT, SESSION_INITIAL, calibrated_session, session_drive, write_frames

PACKAGED = ROOT / "bench" / "data" / "default_model.json"
PACKAGED_ELF = ROOT / "bench" / "data" / "firmware" / "default_model.elf"
ROWS = 200
CALIBRATE_AFTER = 100      # the row after which the master downloads the calibration
ALPHA_CU = 0.005           # 1/K: the copper coefficient downloaded (the packaged model's is 0.0039)


def xcp(data: bytes) -> can.Message:
    return can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=data)


def firmware_session(artifact_path: Path, elf: Path, cell: str | None, value: float,
                     measured: np.ndarray | None = None) -> list[can.Message]:
    """Every frame of a lockstep session of ROWS rows with the firmware node on `elf` (its startup frames and
    heartbeats too), and the DOWNLOAD of `value` into `cell` (by the ELF's address; None: no calibration) after row
    CALIBRATE_AFTER; every XCP reply positive."""
    from target_sim.firmware.node_engine import FirmwareNode
    from target_sim.node import TargetNode

    artifact = load_artifact(artifact_path)
    address = TargetNode(artifact, clock_ns=lambda: 0, xcp_elf=elf).xcp.memory.by_name[cell].address if cell else 0
    return calibrated_session(FirmwareNode(artifact, elf), ROWS, CALIBRATE_AFTER, cell, value, address, measured)


def relogged(frames: list[can.Message], value: float) -> list[can.Message]:
    """The frames with every logged DOWNLOAD's value replaced by `value` (a log that misstates the calibration)."""
    out = []
    for m in frames:
        if m.arbitration_id == cmd_id() and m.data[0] == Cmd.DOWNLOAD:
            m = xcp(bytes(m.data[:2]) + struct.pack("<f", value))
        out.append(m)
    return out


def judged(frames: list[can.Message], path: Path, artifact, xcp_elf: Path | None):
    """(record, results, problems) of `frames` logged at `path` and analysed with the twin laid out by `xcp_elf`."""
    record = decode_log(write_frames(path, frames))
    results, _ = compute(record, artifact, xcp_elf=xcp_elf)
    return record, results, problems(results)


def assert_clean_and_bit_exact(frames, path: Path, artifact_path: Path, elf: Path) -> None:
    """The calibrated log analysed with the target's ELF: clean, every row kept, the twin's replies the CAN ones
    exactly; the calibration moved the estimate off the uncalibrated offline reference after its row only."""
    artifact = load_artifact(artifact_path)
    record, results, found = judged(frames, path, artifact, elf)
    assert record.xcp_downloads == 1 and record.invalid == {} and record.complete
    assert found == [] and results.figure_rows.kept == ROWS
    assert results.agreement.can_reference == "target twin"
    assert results.timing.engine == "firmware"
    twin = twin_estimates(artifact, record, elf)
    assert record.answered.all() and np.array_equal(twin, record.temps)    # bit for bit at the CAN resolution
    stripped = [m for m in frames if m.arbitration_id not in (cmd_id(), res_id())]
    uncalibrated = twin_estimates(artifact, decode_log(write_frames(path.with_name("plain.blf"), stripped)))
    moved = np.abs(record.temps - uncalibrated).max(axis=1)
    assert moved[: CALIBRATE_AFTER + 1].max() == 0 and moved.max() >= 0.05, moved.max()


def assert_not_clean(frames, path: Path, artifact_path: Path, elf: Path, wrong_value: float) -> None:
    """The same run judged from a log without its calibration, with the calibration's value misstated, and with
    the twin laid out by the Python slave's pages: each is not clean, the rows after the calibration left out; the
    pages' twin refused the DOWNLOAD the target accepted, which the verdict names."""
    artifact = load_artifact(artifact_path)
    stripped = [m for m in frames if m.arbitration_id not in (cmd_id(), res_id())]
    for name, logged, layout in (("unrecorded", stripped, elf), ("misstated", relogged(frames, wrong_value), elf),
                                 ("pages", frames, None)):
        _, results, found = judged(logged, path.with_name(f"{name}.blf"), artifact, layout)
        assert found and "differ from the offline float32 reference" in found[0], name
        assert CALIBRATE_AFTER < results.figure_rows.kept < ROWS, (name, results.figure_rows.kept)
        # the pages' twin refused the DOWNLOAD the target accepted: said as such
        assert results.agreement.xcp_downloads_unlike_target == (name == "pages"), name
        assert any("twin answered 1 of the log's XCP DOWNLOADs otherwise" in f for f in found) == (name == "pages")


def assert_bench_analyze_lays_out_the_twin(frames, path: Path, capsys, monkeypatch) -> None:
    """`bench analyze` of the packaged model's calibrated firmware log: clean with the shipped ELF by default and
    with --xcp-elf; an ELF of another model refused in one sentence before the log is read; a firmware log of a
    model that ships no ELF refused in one sentence asking for --xcp-elf."""
    from bench.cli import main

    log = write_frames(path, frames)
    for extra in ([], ["--xcp-elf", str(PACKAGED_ELF)]):
        assert main(["analyze", str(log), "--no-report", "--json", *extra]) == 0, extra
        assert json.loads(capsys.readouterr().out)["clean"] is True
    other = ROOT / "bench" / "data" / "firmware" / "default_model-pv-lptn.elf"
    assert main(["analyze", str(log), "--no-report", "--xcp-elf", str(other)]) != 0
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "is the firmware of model" in err and "Traceback" not in err
    monkeypatch.setattr("bench.firmware.images.packaged_elf", lambda artifact: None)
    assert main(["analyze", str(log), "--no-report"]) != 0
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "firmware target calibrated over XCP" in err and "--xcp-elf" in err


def test_a_firmware_run_calibrated_mid_run_is_clean_against_its_calibrated_twin(tmp_path, capsys, monkeypatch):
    """The packaged model's firmware (the shipped ELF, about 0.2 s of emulation), alpha_cu downloaded after row 100
    of 200: clean and bit-exact against the twin laid out by the ELF, in `compute` and in `bench analyze`; not clean
    without the calibration in the log, with another value in it (0.0045), or with the twin in the Python slave's
    pages."""
    frames = firmware_session(PACKAGED, PACKAGED_ELF, "cal_alpha_cu", ALPHA_CU)
    assert_clean_and_bit_exact(frames, tmp_path / "calibrated.blf", PACKAGED, PACKAGED_ELF)
    assert_not_clean(frames, tmp_path / "calibrated.blf", PACKAGED, PACKAGED_ELF, 0.0045)
    assert_bench_analyze_lays_out_the_twin(frames, tmp_path / "cli.blf", capsys, monkeypatch)


OFFSET = 0.5               # K: the NTC offset downloaded (within the innovation gate: the filter keeps the sensor)


@pytest.mark.slow   # the observer's firmware is built (about a minute on a loaded machine, once per run)
def test_a_firmware_observer_with_its_ntc_offset_calibrated_mid_run_is_clean(observer_artifact, firmware_elf,
                                                                             tmp_path):
    """An observer model's firmware (built), its winding NTC's offset downloaded after row 100 of 200: clean and
    bit-exact against the twin laid out by the ELF, not clean unrecorded, misstated (0.25 K) or in the pages."""
    from target_sim.model import run_offline

    elf = firmware_elf(observer_artifact)
    artifact = load_artifact(observer_artifact)
    drive = session_drive(ROWS, 11)
    steps, open_loop = run_offline(artifact, drive, SESSION_INITIAL)
    sensor = np.round(np.interp(np.arange(ROWS), steps, open_loop[:, 1]) + 1.5, 2)
    measured = np.column_stack([sensor, np.full(ROWS, np.nan)])
    frames = firmware_session(observer_artifact, elf, "cal_sensor0_offset", OFFSET, measured)
    assert_clean_and_bit_exact(frames, tmp_path / "calibrated.blf", observer_artifact, elf)
    assert_not_clean(frames, tmp_path / "calibrated.blf", observer_artifact, elf, OFFSET / 2)


def analyzed(capsys, log: Path, *extra: str) -> tuple[int, str]:
    """`bench analyze LOG --no-report --json` with `extra`: (exit status, its last stderr line or its verdict)."""
    from bench.cli import main

    status = main(["analyze", str(log), "--no-report", "--json", *extra])
    out, err = capsys.readouterr()
    return status, json.loads(out)["verdict"] if status == 0 else err.strip().splitlines()[-1]


def test_bench_analyze_takes_the_elf_the_logs_note_names_and_refuses_it_gone_or_changed(tmp_path, capsys,
                                                                                       monkeypatch):
    """A calibrated firmware log with its note (`<log>.elf.json`, as `bench run --engine firmware` writes it) naming
    a copy of the ELF that ran: `bench analyze` lays out the twin by it without --xcp-elf (the packaged default
    taken away), clean; an --xcp-elf whose bytes are not the noted ELF's, the noted ELF changed, and the noted ELF
    gone: each refused in one sentence."""
    import shutil

    from bench.run.elfnote import note_path, note_target

    frames = firmware_session(PACKAGED, PACKAGED_ELF, "cal_alpha_cu", ALPHA_CU)
    log = write_frames(tmp_path / "noted.blf", frames)
    ran = shutil.copyfile(PACKAGED_ELF, tmp_path / "ran.elf")
    assert note_target(log, ran) == note_path(log)
    note = json.loads(note_path(log).read_text(encoding="utf-8"))
    assert note["elf"] == str(ran.resolve()) and len(note["sha256"]) == 64 and note["log"] == "noted.blf"
    monkeypatch.setattr("bench.firmware.images.packaged_elf", lambda artifact: None)
    assert analyzed(capsys, log) == (0, "clean")
    altered = tmp_path / "altered.elf"
    altered.write_bytes(PACKAGED_ELF.read_bytes() + b"\0")      # the same model's ELF, other bytes
    status, err = analyzed(capsys, log, "--xcp-elf", str(altered))
    not_ran = "is not the firmware ELF the run of log"
    assert status != 0 and err.startswith(f"bench: error: {altered} {not_ran} {log} ran on"), err
    ran.write_bytes(altered.read_bytes())
    status, err = analyzed(capsys, log)
    assert status != 0 and f"{ran} {not_ran} {log} ran on" in err and "Traceback" not in err, err
    ran.unlink()
    status, err = analyzed(capsys, log)
    assert status != 0 and f"ran on the firmware ELF {ran.resolve()}" in err and "not there any more" in err, err
    assert analyzed(capsys, log, "--xcp-elf", str(PACKAGED_ELF)) == (0, "clean")     # the same bytes elsewhere
    assert note_target(log, None) is None and not note_path(log).exists()      # a run of no known ELF: no note
