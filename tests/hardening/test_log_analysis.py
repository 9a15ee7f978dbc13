"""Issue 14, items 3, 5 and 8: the log analysis applies the host's checks (a frame the host rejected is never used,
replayed or forged frames are counted and shown, and none of their values reaches a reported temperature), the
report directory is written at once (a full disk or a Ctrl-C leaves the earlier report as it was, the sentence names
the file), and a partial log of a killed run is incomplete, not clean."""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
from dataclasses import replace

import can
import numpy as np
import pytest

from bench.analysis.canmetrics import compute
from bench.analysis.logdecode import decode_log
from bench.analysis.report import render_markdown, write_report
from bench.analysis.verdict import problems
from bench.errors import BenchError
from dbc import FrameValidator
from dbc.codec import apply_crc
from dbc.contract import FrameError
from dbc.database import frame_id
from target_sim.artifact import load_artifact

from helpers import ROOT, after_row, genuine_temps, replies_by_row, subprocess_env
from helpers import session_drive as drive
from helpers import session_frames as session
from helpers import write_frames as write

ROWS = 400


@pytest.fixture(scope="module")
def lti(artifacts):
    return load_artifact(artifacts["lti"])


# ---------------------------------------------------------------------------------------------- item 3
def test_replayed_replies_of_another_run_never_reach_a_reported_temperature(lti, tmp_path):
    values, other = drive(ROWS, 1), drive(ROWS, 2)
    genuine = genuine_temps(lti, values)
    frames = session(lti, values)
    foreign = replies_by_row(session(lti, other))     # valid CRC and the counters of that run
    late = list(range(20, 380, 9))                    # replayed a few rows later: their counters jump
    aligned = [55, 156, 255]                          # replayed right before the genuine reply: the same counter
    for row in sorted(late + aligned, reverse=True):
        at = after_row(frames, row + 3) if row in late else after_row(frames, row, "drive")
        frames[at:at] = [can.Message(arbitration_id=f.arbitration_id, is_extended_id=False, dlc=8, data=f.data)
                         for f in foreign[row]]
    record = decode_log(write(tmp_path / "replayed.blf", frames))

    reported = record.answered
    assert reported.sum() > ROWS - 3 * len(late) - len(aligned)           # most rows survive
    np.testing.assert_array_equal(record.temps[reported], genuine[reported])  # no foreign value anywhere
    assert np.flatnonzero(record.contested).tolist() == aligned           # one of two frames is not the target's
    assert record.invalid["counter"] >= 2 * len(late)
    assert record.rejected["Temperatures1"] >= len(late) and record.rejected["Temperatures2"] >= len(late)
    assert record.foreign == {"second reply with other temperatures": 2 * len(aligned)}
    results, _ = compute(record, lti)
    metrics = results.to_json()
    assert metrics["contested_rows"] == len(aligned) and metrics["can_agrees_with_float32"]
    found = problems(results)
    assert any(p.startswith(f"{len(aligned)} rows got a second reply with other temperatures") for p in found)
    assert any(p.startswith("the host's checks reject ") for p in found)
    text = render_markdown(results, found, None, {})
    assert "| invalid frames in the log (rejected by the host's checks" in text
    assert "counter " in text.split("| invalid frames in the log")[1].splitlines()[0]
    assert "Result: NOT clean" in text


def test_forged_frames_with_valid_crc_are_not_used_and_are_shown(lti, tmp_path):
    """Random content with a valid CRC on the target's Status, RxErrors and Temperatures ids: what the report shows
    of the target (receive errors, fault bits, temperatures) comes only from frames the host's checks accept."""
    values = drive(ROWS, 3)
    frames = session(lti, values)
    rng = np.random.default_rng(7)
    ids = [frame_id(name) for name in ("Status", "RxErrors", "Temperatures1", "Timing1")]
    for at in sorted(rng.choice(np.arange(10, len(frames)), 120, replace=False), reverse=True):
        fid = int(rng.choice(ids))
        data = apply_crc(fid, bytes(rng.integers(0, 256, 8, dtype=np.uint8)))
        frames.insert(int(at), can.Message(arbitration_id=fid, is_extended_id=False, dlc=8, data=data))
    path = write(tmp_path / "forged.asc", frames)
    record = decode_log(path)

    # what the host accepted, frame by frame: the last RxErrors, the fault bits of the session model's Status
    validator, rx, bits, model = FrameValidator("HOST"), None, 0, None
    for msg in can.LogReader(str(path)):
        if msg.arbitration_id not in ids + [frame_id(n) for n in ("Temperatures2", "Timing2", "Timing3",
                                                                   "TargetInfo", "StateCheckpoint")]:
            continue
        try:
            frame = validator.validate(msg)
        except FrameError:
            continue
        if frame.name == "RxErrors":
            rx = {k: int(v) for k, v in frame.signals.items()}
        elif frame.name == "Status":
            model = int(frame.signals["ModelId"]) if model is None else model
            if int(frame.signals["ModelId"]) == model:
                bits |= int(frame.signals["FaultBits"])
    assert sorted(record.rx_errors.values()) == sorted(rx.values())
    assert record.faults_seen == bits and record.model_id == lti.model_id
    assert record.rejected["Status"] > 0 and record.rejected["RxErrors"] > 0
    reported = record.answered
    np.testing.assert_array_equal(record.temps[reported], genuine_temps(lti, values)[reported])
    results, _ = compute(record, lti)
    text = render_markdown(results, problems(results), None, {})
    receive = next(line for line in text.splitlines() if line.startswith("| target receive errors"))
    assert f"{record.rejected['RxErrors']} failed them and are not used" in receive
    seen = next(line for line in text.splitlines() if line.startswith("| target faults seen"))
    assert f"{record.rejected['Status']} failed them and are not used" in seen


def test_a_clean_session_has_nothing_rejected_or_foreign(lti, tmp_path):
    values = drive(ROWS, 4)
    record = decode_log(write(tmp_path / "clean.blf", session(lti, values)))
    assert (record.invalid, record.rejected, record.foreign, record.complete) == ({}, {}, {}, True)
    np.testing.assert_array_equal(record.temps, genuine_temps(lti, values))
    results, _ = compute(record, lti)
    metrics = results.to_json()
    assert problems(results) == [] and metrics["null_values"] == {}


# ---------------------------------------------------------------------------------------------- item 8
def test_a_partial_blf_of_a_killed_run_is_incomplete(lti, tmp_path):
    frames = session(lti, drive(ROWS, 5), stop=False)          # killed: no STOP ...
    path, partial = tmp_path / "run.blf", tmp_path / "partial.blf"
    writer = can.BLFWriter(str(path), max_container_size=4096)
    for i, frame in enumerate(frames):
        frame.timestamp = 1000.0 + i * 1e-4
        writer.on_message_received(frame)
    writer.file.flush()
    shutil.copyfile(path, partial)                             # ... and the file never closed by its writer
    writer.stop()
    record = decode_log(partial)
    assert record.rows > 100 and record.answered.all()        # every row in the file was answered
    assert (record.stopped, record.unclosed, record.complete) == (False, True, False)
    results, _ = compute(record, lti)
    metrics = results.to_json()
    assert metrics["log_complete"] is False
    assert problems(results)[0] == (f"the log is incomplete (its .blf was never closed by its writer: a run that was "
                                    f"killed, or a partial file); its last row is {record.rows - 1} and what came "
                                    "after it is missing")


def test_a_log_without_stop_is_incomplete(lti, tmp_path):
    record = decode_log(write(tmp_path / "nostop.asc", session(lti, drive(60, 6), stop=False)))
    assert (record.stopped, record.unclosed, record.complete) == (False, False, False)
    results, _ = compute(record, lti)
    assert any(p.startswith("the log is incomplete (it ends without the host's Control STOP") for p in
               problems(results))


# ---------------------------------------------------------------------------------------------- item 5
@pytest.fixture
def analyzed(lti, tmp_path):
    """(record, metrics, refs, problems) of a clean 200-row session, and an earlier report in tmp/report."""
    record = decode_log(write(tmp_path / "run.blf", session(lti, drive(200, 8))))
    results, refs = compute(record, lti)
    report = tmp_path / "report"
    write_report(report, results, problems(results), record, refs, None, {})
    return record, results, refs, report


def snapshot(directory) -> tuple[list[str], dict[str, bytes]]:
    """What sits beside the report directory (a temporary left behind shows), and the report's files."""
    return (sorted(os.listdir(directory.parent)),
            {p.name: p.read_bytes() for p in sorted(directory.iterdir())})


def test_ctrl_c_while_the_report_is_written_leaves_the_earlier_report(analyzed, monkeypatch):
    import matplotlib.figure

    record, results, refs, report = analyzed
    before = snapshot(report)
    saved = matplotlib.figure.Figure.savefig
    calls = []

    def interrupted(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return saved(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_report(report, replace(results, model=replace(results.model, id="0badf00d")), [], record, refs,
                     None, {})
    assert snapshot(report) == before                     # no new figure beside the old report.md, no temporary


def test_a_full_disk_while_the_report_is_written_names_the_file_and_changes_nothing(analyzed, lti, tmp_path):
    """`bench analyze` with a file-size limit (EFBIG, as a full disk's ENOSPC): one sentence naming the figure it
    could not write, exit 1, the earlier report as it was and no temporary left beside it."""
    record, results, refs, report = analyzed
    artifact = tmp_path / "lti.json"
    artifact.write_text(json.dumps(lti.content), encoding="utf-8")
    before = snapshot(report)

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (40_000, 40_000))

    done = subprocess.run([sys.executable, "-m", "bench", "analyze", str(record.path), "--model",
                           str(artifact), "--report", str(report), "--quiet"], cwd=tmp_path, capture_output=True,
                          text=True, env=subprocess_env(PYTHONPATH=str(ROOT)), preexec_fn=limit, timeout=120)
    assert done.returncode == 1, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert lines[0].startswith(f"bench: error: cannot write the report {report} (File too large while writing "
                               f"{report}/temperatures.png); nothing of it was written")
    assert snapshot(report) == before


def test_a_report_directory_with_other_files_is_refused_before_anything(analyzed, tmp_path):
    record, results, refs, _ = analyzed
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine\n")
    with pytest.raises(BenchError) as info:
        write_report(busy, results, [], record, refs, None, {})
    assert str(info.value) == (f"--report {busy} holds notes.txt, which is not a report this bench wrote; choose an "
                               "empty or new directory for --report")
    assert sorted(os.listdir(busy)) == ["notes.txt"]
