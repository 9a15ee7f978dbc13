"""Bus logs by suffix: python-can writers, read back by can.LogReader, atomic, timestamps non-decreasing."""

from __future__ import annotations

import math
from datetime import datetime

import can
import pytest

from dbc import FrameCodec, decode_any
from host import canlog
from host.canlog import FrameLog, LogError, check_log_path, mf4_available, read_log

SUFFIXES = [".blf", ".asc", ".log", ".csv", pytest.param(".mf4", marks=pytest.mark.skipif(
    not mf4_available(), reason="asammdf is not installed"))]


def frames() -> list[can.Message]:
    host, target = FrameCodec("HOST"), FrameCodec("TARGET")
    out = []
    t0 = 1_700_000_000.0
    for step in range(20):
        out.append(host.encode("DriveInputs", {"Step": step, "MotorTorque": step * 1.5, "MotorSpeed": 100.0 * step},
                               timestamp=t0 + step * 0.01))
        out.append(target.encode("Temperatures1", {"Step": step, "WindingTemp": 40 + step / 100,
                                                   "MagnetTemp": 35.5}, timestamp=t0 + step * 0.01 + 0.0004))
    out[7].timestamp = out[6].timestamp - 0.002  # a frame stamped slightly before its predecessor
    return out


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_each_format_reads_back_with_logreader(tmp_path, suffix):
    path = tmp_path / f"bus{suffix}"
    written = frames()
    with FrameLog(path) as log:
        for msg in written:
            log.write(msg)
    assert path.is_file() and not list(tmp_path.glob(".*partial*"))
    back = list(can.LogReader(str(path)))
    assert len(back) == len(written)
    for a, b in zip(written, back, strict=True):
        assert a.arbitration_id == b.arbitration_id and bytes(a.data) == bytes(b.data)
        assert decode_any(b).signals == decode_any(a).signals
    stamps = [m.timestamp for m in back]
    assert all(later >= earlier for earlier, later in zip(stamps, stamps[1:], strict=False))
    assert list(read_log(path))[0].arbitration_id == 0x110


def test_a_failed_run_leaves_no_file(tmp_path):
    path = tmp_path / "bus.blf"
    with pytest.raises(RuntimeError), FrameLog(path) as log:
        log.write(frames()[0])
        raise RuntimeError("the run failed")
    assert list(tmp_path.iterdir()) == []


def test_unsupported_and_missing_logs_are_one_sentence(tmp_path):
    with pytest.raises(LogError, match=r"unsupported format \.txt; use one of \.blf"):
        check_log_path(tmp_path / "bus.txt")
    with pytest.raises(LogError, match="does not exist"):
        list(read_log(tmp_path / "none.blf"))
    broken = tmp_path / "broken.blf"
    broken.write_bytes(b"LOGG" + bytes(40))
    with pytest.raises(LogError):
        list(read_log(broken))


def test_monotonic_clamp_keeps_order(tmp_path):
    path = tmp_path / "bus.log"
    with FrameLog(path) as log:
        for msg in frames():
            log.write(msg)
    stamps = [m.timestamp for m in can.LogReader(str(path))]
    assert stamps == sorted(stamps) and not any(math.isnan(s) for s in stamps)


def _asc_date(stamp: float) -> str:
    """A time as an ASC header states it (local time, milliseconds), formatted independently of host.canlog."""
    dt = datetime.fromtimestamp(stamp)
    return dt.strftime("%a %b %d %H:%M:%S.") + f"{dt.microsecond // 1000} {dt.year}"


def test_an_asc_log_states_the_recordings_start_before_its_first_frame(tmp_path):
    """Through python-can's public API only: the `date` line and the measurement's start are the recording's start
    (here 2.25 s before the first frame, as an export of the host's frames only has it), not the time of writing,
    and every frame keeps its time."""
    path, written = tmp_path / "bus.asc", frames()
    start = written[0].timestamp - 2.25
    with FrameLog(path, start_time=start) as log:
        for msg in written:
            log.write(msg)
    lines = path.read_text().splitlines()
    assert lines[0] == f"date {_asc_date(start)}"
    assert f"Begin Triggerblock {_asc_date(start)}" in lines
    with can.ASCReader(str(path), relative_timestamp=False) as reader:    # times from the header's start
        back = [m.timestamp for m in reader]
    # the header's start has milliseconds, the frames' offsets from it microseconds (`write` clamped frame 7 to 6)
    assert back == pytest.approx([m.timestamp for m in written], abs=1e-3)
    assert back[0] == pytest.approx(start + 2.25, abs=1e-3)


def test_an_asc_log_without_a_given_start_starts_at_its_first_frame(tmp_path):
    path, written = tmp_path / "bus.asc", frames()
    with FrameLog(path) as log:
        for msg in written:
            log.write(msg)
    text = path.read_text()
    assert text.startswith(f"date {_asc_date(written[0].timestamp)}\n")
    assert "Start of the recording" not in text     # the first frame starts the measurement: no event before it


def _mf4_start_and_times(path) -> tuple[float, list[float], list[int]]:
    """What asammdf reads from an .mf4: the header's start (s since the epoch), each data frame's time and id."""
    from asammdf import MDF

    mdf = MDF(str(path))
    try:
        ids = mdf.get("CAN_DataFrame.ID")
        return mdf.header.start_time.timestamp(), ids.timestamps.tolist(), [int(v) for v in ids.samples]
    finally:
        mdf.close()


@pytest.mark.skipif(not mf4_available(), reason="asammdf is not installed")
@pytest.mark.parametrize("given", ["first frame", "before", "drive time"])
def test_an_mf4_log_states_its_start_and_keeps_every_frames_time(tmp_path, given):
    """python-can's writer states the time of writing and counts from it (times of -120 s, -1.8e9 s in drive time):
    the header now states the recording's start, asammdf's times count from it and python-can's reader reads the
    recorded times back. Public behaviour only: this fails on any python-can or asammdf release that breaks it."""
    written = frames()
    if given == "drive time":
        for msg in written:
            msg.timestamp -= 1_700_000_000.0
    start = {"first frame": None, "before": written[0].timestamp - 1.25, "drive time": 0.0}[given]
    path = tmp_path / "bus.mf4"
    with FrameLog(path, start_time=start) as log:
        for msg in written:
            log.write(msg)
    expected_start = written[0].timestamp if start is None else start
    header_start, times, ids = _mf4_start_and_times(path)
    assert header_start == pytest.approx(expected_start, abs=1e-6)
    assert ids == [m.arbitration_id for m in written]
    # float64 offsets from an epoch time: 0.24 µs resolution
    assert times == pytest.approx([m.timestamp - expected_start for m in written], abs=1e-6)
    assert times[0] >= 0 and (start is not None or times[0] == 0)
    back = list(can.LogReader(str(path)))
    assert [m.timestamp for m in back] == pytest.approx([m.timestamp for m in written], abs=1e-6)
    assert [bytes(m.data) for m in back] == [bytes(m.data) for m in written]


@pytest.mark.skipif(not mf4_available(), reason="asammdf is not installed")
def test_an_mf4_log_without_frames_states_its_given_start(tmp_path):
    path = tmp_path / "empty.mf4"
    with FrameLog(path, start_time=1_600_000_000.0):
        pass
    header_start, times, _ = _mf4_start_and_times(path)
    assert header_start == 1_600_000_000.0 and times == []


@pytest.mark.skipif(not mf4_available(), reason="asammdf is not installed")
def test_an_mf4_log_that_cannot_be_retimed_is_refused_and_leaves_no_file(tmp_path, monkeypatch):
    def refuse(path, start):
        raise ValueError("no such channel group")

    monkeypatch.setattr(canlog, "_restart_mf4", refuse)
    path = tmp_path / "bus.mf4"
    with pytest.raises(LogError, match=r"cannot write the log .*bus\.mf4 \(ValueError: no such channel group\)"):
        with FrameLog(path) as log:
            log.write(frames()[0])
    assert list(tmp_path.iterdir()) == []
