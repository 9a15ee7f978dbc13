"""`bench replay` of a log calibrated over XCP during its run: the replay re-sends the master's commands in their
place among the rows (each waiting for its answer, as the master did), its target's cells laid out as the recorded
target's were (the Python slave's pages, or the ELF the log's note names / a firmware log's packaged ELF), so the
calibrated run is reproduced; a Python target's calibrated log on the firmware engine is refused in one sentence,
and a replay whose cells are elsewhere says that its target answered the DOWNLOADs otherwise.
`bench run --engine firmware` notes its ELF beside its log (`<log>.elf.json`); a Python run of the same log name
removes an earlier note."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bench.analysis.logdecode import decode_log
from bench.analysis.twin import twin_estimates
from bench.commands.replay import download_answers
from bench.run.elfnote import file_sha256, note_path, note_target
from dbc.xcp import cmd_id, res_id
from target_sim.artifact import load_artifact
from target_sim.node import TargetNode

from helpers import ROOT, calibrated_session, run_cli, write_frames

PACKAGED = ROOT / "bench" / "data" / "default_model.json"
PACKAGED_ELF = ROOT / "bench" / "data" / "firmware" / "default_model.elf"
ROWS, CALIBRATE_AFTER, ALPHA_CU = 120, 60, 0.005


def python_log(path: Path) -> Path:
    """A Python target's lockstep log (cells in the slave's pages), alpha_cu downloaded after row CALIBRATE_AFTER;
    the calibration moved its replies off the uncalibrated run's after that row."""
    artifact = load_artifact(PACKAGED)
    node = TargetNode(artifact, clock_ns=lambda: 0)
    address = node.xcp.memory.by_name["cal_alpha_cu"].address
    frames = calibrated_session(node, ROWS, CALIBRATE_AFTER, "cal_alpha_cu", ALPHA_CU, address)
    log = write_frames(path, frames)
    plain = [m for m in frames if m.arbitration_id not in (cmd_id(), res_id())]
    uncalibrated = twin_estimates(artifact, decode_log(write_frames(path.with_name("plain.blf"), plain)))
    moved = np.abs(decode_log(log).temps - uncalibrated).max(axis=1)
    assert moved[: CALIBRATE_AFTER + 1].max() == 0 and moved.max() > 0.05
    return log


def replay(log: Path, new_log: Path, *options: str) -> tuple[int, dict | str]:
    """`bench replay LOG --as-fast-as-possible --json`: (exit status, its summary or its last stderr line)."""
    proc = run_cli("-m", "bench", "replay", str(log), "--as-fast-as-possible", "--log", str(new_log), "--json",
                   *options, timeout=300)
    if proc.stdout.strip():
        return proc.returncode, json.loads(proc.stdout)
    return proc.returncode, proc.stderr.strip().splitlines()[-1]


def assert_reproduced(status: int, summary, new_log: Path) -> None:
    """Every row identical, and the replay's DOWNLOAD accepted as the recorded one was, in the new log."""
    assert status == 0 and summary["reproduced"], summary
    assert summary["identical"] == summary["compared"] == ROWS and summary["problems"] == [], summary
    assert download_answers(decode_log(new_log)) == [0xFF]


def test_a_calibrated_python_log_replays_calibrated_and_the_firmware_engine_is_refused(tmp_path, capsys):
    """The Python target's calibrated log: reproduced row for row (the DOWNLOAD re-sent after row 60); on the
    firmware engine, whose cells are not in the Python slave's pages, refused in one sentence before a target
    starts."""
    log = python_log(tmp_path / "calibrated.blf")
    new_log = tmp_path / "replayed.blf"
    assert_reproduced(*replay(log, new_log), new_log)
    assert not note_path(new_log).exists()                   # a Python target without --xcp-elf: no ELF to note
    from bench.cli import main

    assert main(["replay", str(log), "--log", str(tmp_path / "firmware.blf"), "--engine", "firmware"]) != 0
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "calibrated a Python target over XCP" in err and "--engine python" in err, err
    assert not (tmp_path / "firmware.blf").exists()


@pytest.mark.slow     # three replays, two of them on the firmware engine (about 10 s)
def test_a_calibrated_firmware_log_replays_calibrated_on_either_engine(tmp_path):
    """The packaged firmware's calibrated log, its note naming a copy of the ELF that ran: reproduced on the
    firmware engine (the noted ELF runs, and the replay's log notes it) and on the Python engine (its cells laid out
    by the noted ELF); the Python log replayed with an ELF's layout is not reproduced, its DOWNLOAD answered
    otherwise, said in one sentence."""
    from target_sim.firmware.node_engine import FirmwareNode

    artifact = load_artifact(PACKAGED)
    ran = shutil.copyfile(PACKAGED_ELF, tmp_path / "ran.elf")
    address = TargetNode(artifact, clock_ns=lambda: 0, xcp_elf=ran).xcp.memory.by_name["cal_alpha_cu"].address
    frames = calibrated_session(FirmwareNode(artifact, ran), ROWS, CALIBRATE_AFTER, "cal_alpha_cu", ALPHA_CU,
                                address)
    log = write_frames(tmp_path / "firmware.blf", frames)
    note_target(log, ran)
    for engine in ("firmware", "python"):
        new_log = tmp_path / f"on-{engine}.blf"
        status, summary = replay(log, new_log, "--engine", engine)
        assert_reproduced(status, summary, new_log)
        assert summary["engine"] == engine
        note = json.loads(note_path(new_log).read_text(encoding="utf-8"))
        assert (note["elf"], note["sha256"]) == (str(ran.resolve()), file_sha256(PACKAGED_ELF))
    status, summary = replay(python_log(tmp_path / "python.blf"), tmp_path / "elsewhere.blf", "--xcp-elf", str(ran))
    assert status == 1 and not summary["reproduced"]
    assert "the replay's target answered 1 of the log's 1 XCP DOWNLOADs otherwise" in summary["problems"][0]


@pytest.mark.slow     # two bench runs, one on the firmware engine (about 8 s)
def test_bench_run_on_the_firmware_engine_notes_its_elf_and_a_python_run_removes_the_note(tmp_path):
    log = tmp_path / "run.blf"
    for engine in ("firmware", "python"):
        proc = run_cli("-m", "bench", "run", "--engine", engine, "--rows", "30", "--log", str(log), "--no-report",
                       "--json", timeout=300)
        assert proc.returncode == 0, proc.stderr
        if engine == "firmware":
            note = json.loads(note_path(log).read_text(encoding="utf-8"))
            assert note["log"] == "run.blf" and note["sha256"] == file_sha256(note["elf"])
            assert note["sha256"] == file_sha256(PACKAGED_ELF)
    assert not note_path(log).exists()
