"""`bench export`: a run's log for other CAN tools: host frames only (what `python -m can.player` should send to a
new target), drive-time timestamps, any format python-can writes."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from datetime import datetime

import can
import pytest

from bench.commands.export import drive_times, infer_sample_period
from dbc import decode_any
from dbc.database import frame_id, host_frame_ids, target_frame_ids
from dbc.transport import BusConfig
from host.canlog import mf4_available
from target_sim.model import InputAccumulator

from helpers import ROOT, private_udp_bus, run_cli, start_target, subprocess_env

ROWS = 300
PERIOD = 0.2       # the synthetic dataset's sample period (5 Hz); the packaged model steps at 0.5 s


@pytest.fixture(scope="module")
def run_log(small_dataset, tmp_path_factory):
    """A short real run's log: target process, host, udp_multicast."""
    log = tmp_path_factory.mktemp("export") / "run.blf"
    proc = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", str(ROWS), "--no-report",
                   "--quiet", "--log", str(log), *private_udp_bus().to_argv(), can_settings=False)
    assert proc.returncode == 0, proc.stderr
    return log


def export(*argv: str) -> subprocess.CompletedProcess:
    return run_cli("-m", "bench", "export", *map(str, argv), can_settings=False)


def frames(path) -> list[can.Message]:
    return list(can.LogReader(str(path)))


@pytest.mark.parametrize("suffix", [".asc", ".log", ".csv", ".blf"])
def test_host_only_keeps_exactly_the_hosts_frames(run_log, tmp_path, suffix):
    out = tmp_path / f"host{suffix}"
    proc = export(run_log, "--out", out, "--host-only", "--json")
    assert proc.returncode == 0, proc.stderr
    recorded = frames(run_log)
    expected = [(m.arbitration_id, bytes(m.data)) for m in recorded if m.arbitration_id in host_frame_ids()]
    written = frames(out)
    assert [(m.arbitration_id, bytes(m.data)) for m in written] == expected
    assert not {m.arbitration_id for m in written} & target_frame_ids()
    assert len(expected) >= 2 * ROWS + 5 and len(expected) < len(recorded) / 2
    s = json.loads(proc.stdout)
    assert (s["frames_read"], s["frames_written"], s["host_only"]) == (len(recorded), len(expected), True)
    assert not list(tmp_path.glob(".*"))   # written under a temporary name and renamed


@pytest.mark.slow        # the drive-time stamps are also checked by the dated .asc export
def test_drive_time_spans_the_rows_at_the_sample_period(run_log, tmp_path):
    """The packaged model's TargetInfo (Δt 0.5 s) and its Timing1 rows give 0.2 s: the last row, ROWS - 1, is at
    59.8 s (the run itself took a fraction of a second)."""
    out = tmp_path / "drive.log"
    proc = export(run_log, "--out", out, "--drive-time", "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["sample_period_s"] == PERIOD and s["sample_period_source"].startswith("the log")
    written = frames(out)
    assert len(written) == len(frames(run_log))
    stamps = [m.timestamp for m in written]
    assert stamps[0] == 0.0 and stamps[-1] == pytest.approx((ROWS - 1) * PERIOD, abs=1e-6)
    assert all(b >= a for a, b in zip(stamps, stamps[1:], strict=False))
    inputs = [m for m in written if m.arbitration_id == frame_id("DriveInputs")]
    assert len(inputs) == ROWS
    for msg in inputs:   # each DriveInputs at its own row's time
        assert msg.timestamp == pytest.approx(decode_any(msg).signals["Step"] * PERIOD, abs=1e-6)
    given = export(run_log, "--out", tmp_path / "given.csv", "--drive-time", "--sample-period", "1", "--json")
    assert json.loads(given.stdout)["last_timestamp"] == pytest.approx(ROWS - 1)


@pytest.mark.slow   # 5 s: kept out of the 5-min default run
def test_the_host_only_export_replays_with_can_player_and_every_row_is_answered(run_log, tmp_path):
    """The recipe of the README: `python -m can.player` sends the exported host frames to a new target (paced with
    --ignore-timestamps -g: udp_multicast loses frames in the bursts of the recorded lockstep timing; 3 ms, not the
    recipe's 1 ms, so that a target starved of CPU for half a second on a loaded machine still finds every frame in
    its socket)."""
    out = tmp_path / "host.blf"
    assert export(run_log, "--out", out, "--host-only").returncode == 0
    bus: BusConfig = private_udp_bus()
    from bench.model.default import default_artifact_path

    stats = tmp_path / "stats.json"
    env = subprocess_env(can_settings=False)
    with start_target("--model", default_artifact_path(), *bus.to_argv(), "--quiet", "--stats", stats, env=env):
        listener = bus.open()
        try:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:   # the target's heartbeat: it is on the bus
                msg = listener.recv(0.5)
                if msg is not None and msg.arbitration_id == frame_id("Status"):
                    break
            else:
                pytest.fail("the target sent no heartbeat")
        finally:
            listener.shutdown()
        player = subprocess.run([sys.executable, "-m", "can.player", "-i", "udp_multicast", "-c", bus.channel,
                                 "--bus-kwargs", f"port={bus.kwargs['port']}", "--ignore-timestamps", "-g", "0.003",
                                 str(out)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
        assert player.returncode == 0, player.stderr
        time.sleep(0.5)
    # stopped with SIGTERM as the block ended (it writes its stats then)
    s = json.loads(stats.read_text())
    assert s["rows_used"] == ROWS
    assert s["frames_received"] == len([m for m in frames(run_log) if m.arbitration_id in host_frame_ids()])
    assert not any(s["errors"].values()), s["errors"]


def _interval_ends(rows: int, period: float, dt: float) -> list[int]:
    rule = InputAccumulator(period, dt)
    return [n for n in range(rows) if rule.ends_interval(n)]


@pytest.mark.parametrize(("period", "dt"), [(0.2, 0.5), (0.1, 0.5), (0.5, 0.5), (0.2, 1.0), (0.25, 4.0),
                                            (0.01, 0.5)])
def test_the_sample_period_is_read_from_the_rows_the_model_stepped_on(period, dt):
    ends = _interval_ends(3000, period, dt)
    assert infer_sample_period(ends, dt) == period
    assert infer_sample_period(ends[:3] + ends[4:], dt) == period   # a Timing1 frame lost
    assert infer_sample_period(ends[:1], dt) is None


def test_rows_that_fit_no_period_give_none():
    assert infer_sample_period([0, 1, 5, 6, 30, 31, 200], 0.5) is None


def test_drive_times_keep_order_and_the_previous_rows_time():
    rows = [None, 0, None, 1, 2, None, 1, 3, None]   # a row sent again (1 after 2) keeps the latest time
    assert drive_times(rows, 0.5) == [0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.5, 1.5]
    assert drive_times([None, 5, 6], 0.2) == pytest.approx([1.0, 1.0, 1.2])


@pytest.mark.slow
def test_bad_input_is_one_sentence(run_log, tmp_path):
    cases = [
        ((run_log, "--out", tmp_path / "x.txt"), 1, "unsupported format .txt"),
        ((tmp_path / "none.blf", "--out", tmp_path / "y.blf"), 1, "does not exist"),
        ((run_log, "--out", tmp_path / "z.blf", "--sample-period", "0.2"), 2, "pass --drive-time too"),
        ((run_log, "--out", run_log, "--host-only"), 2, "is the same file as LOG"),
        ((run_log, "--out", tmp_path / "dir.blf", "--host-only"), 1, "is a directory"),
    ]
    (tmp_path / "dir.blf").mkdir()
    for argv, status, needle in cases:
        proc = export(*argv, "--quiet")
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == status and len(lines) == 1 and needle in lines[0], (argv, proc.stderr)
        assert lines[0].startswith("bench: error: ") and "Traceback" not in proc.stderr
    # a log without TargetInfo/Timing1 (only the host's frames) has no sample period to read: say how to give it
    host_only = tmp_path / "h.blf"
    assert export(run_log, "--out", host_only, "--host-only").returncode == 0
    proc = export(host_only, "--out", tmp_path / "d.blf", "--drive-time")
    assert proc.returncode == 1 and "pass --sample-period S with --drive-time" in proc.stderr, proc.stderr
    assert not (tmp_path / "d.blf").exists() and not (tmp_path / "x.txt").exists()


def _mf4_times(path) -> tuple[float, list[float], list[int]]:
    """What asammdf reads from an .mf4 export: the measurement's start (s since the epoch), and each data frame's
    time (relative to it) and id."""
    from asammdf import MDF

    mdf = MDF(str(path))
    try:
        ids = mdf.get("CAN_DataFrame.ID")
        return mdf.header.start_time.timestamp(), ids.timestamps.tolist(), [int(v) for v in ids.samples]
    finally:
        mdf.close()


@pytest.mark.skipif(not mf4_available(), reason="asammdf is not installed")
@pytest.mark.parametrize("host_only", [False, True])
def test_the_mf4_export_starts_when_the_recording_started(run_log, tmp_path, host_only):
    """asammdf's times were relative to the time of the export (-120 s for a log made two minutes before): the
    measurement now starts at the recording's first frame and each frame is at its recorded offset from it."""
    out = tmp_path / "run.mf4"
    proc = export(run_log, "--out", out, *(("--host-only",) if host_only else ()))
    assert proc.returncode == 0, proc.stderr
    recorded = frames(run_log)
    start, stamps, ids = _mf4_times(out)
    kept = [m for m in recorded if not host_only or m.arbitration_id in host_frame_ids()]
    assert start == pytest.approx(recorded[0].timestamp, abs=1e-6)
    assert ids == [m.arbitration_id for m in kept]
    assert stamps == pytest.approx([m.timestamp - recorded[0].timestamp for m in kept], abs=1e-5)
    assert stamps[0] >= 0 and (host_only or stamps[0] == 0)
    back = frames(out)   # python-can's reader: the recorded times again
    assert [m.timestamp for m in back] == pytest.approx([m.timestamp for m in kept], abs=1e-5)


@pytest.mark.slow        # the mf4 export itself is tested in the default run
@pytest.mark.skipif(not mf4_available(), reason="asammdf is not installed")
def test_the_mf4_export_in_drive_time_counts_from_zero(run_log, tmp_path):
    """With --drive-time asammdf's times were -1.8e9 s (drive time minus the export's wall clock): the start is
    now the epoch and each frame's time its drive time, the first row's 0."""
    out, plain = tmp_path / "drive.mf4", tmp_path / "drive.log"
    assert export(run_log, "--out", out, "--drive-time").returncode == 0
    assert export(run_log, "--out", plain, "--drive-time").returncode == 0
    start, stamps, _ = _mf4_times(out)
    assert start == 0.0
    expected = [m.timestamp for m in frames(plain)]   # the drive times the candump export writes as they are
    assert stamps[0] == 0.0 and stamps[-1] == pytest.approx((ROWS - 1) * PERIOD, abs=1e-6)
    assert stamps == pytest.approx(expected, abs=1e-6)


def _asc_date(path) -> str:
    with open(path) as fh:
        line = fh.readline()
    assert line.startswith("date "), line
    return line[len("date "):].strip()


def _asc_format(stamp: float) -> str:
    """A time as python-can's ASC writer formats a header date (local time, milliseconds unpadded)."""
    dt = datetime.fromtimestamp(stamp)
    return dt.strftime(f"%a %b %d %H:%M:%S.{dt.microsecond // 1000} %Y")


def test_the_asc_export_is_dated_when_the_recording_started(run_log, tmp_path):
    """The ASC header's date was the time of the export: it is the recording's first frame's (and the epoch in
    drive time, whose frame times count from 0)."""
    out, drive = tmp_path / "run.asc", tmp_path / "drive.asc"
    assert export(run_log, "--out", out, "--host-only").returncode == 0
    assert export(run_log, "--out", drive, "--drive-time").returncode == 0
    first = frames(run_log)[0].timestamp
    assert _asc_date(out) == _asc_format(first)
    assert f"Begin Triggerblock {_asc_format(first)}" in out.read_text()
    assert _asc_date(drive) == _asc_format(0.0)
    stamps = [m.timestamp for m in frames(drive)]
    assert stamps[0] == 0.0 and stamps[-1] == pytest.approx((ROWS - 1) * PERIOD, abs=1e-6)
