"""Bus logs by suffix: python-can writers, read back by can.LogReader, atomic, timestamps non-decreasing."""

from __future__ import annotations

import math

import can
import pytest

from dbc import FrameCodec, decode_any
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
