"""The DBC works with cantools' own command line tools (what an engineer reaches for first)."""

import subprocess
import sys

from dbc import DBC_PATH, FrameCodec, frame_ids


def run_cantools(*args, stdin=""):
    return subprocess.run(
        [sys.executable, "-m", "cantools", *args],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def candump_line(msg, timestamp):
    return f"({timestamp:.6f}) vcan0 {msg.arbitration_id:03X}#{msg.data.hex().upper()}"


def test_cantools_dump_lists_every_message():
    result = run_cantools("dump", str(DBC_PATH))
    assert result.returncode == 0, result.stderr
    for name, frame_id in frame_ids().items():
        assert f"Name:           {name}\n" in result.stdout
        assert f"Id:             0x{frame_id:x}\n" in result.stdout


def test_cantools_decode_reads_candump_lines():
    drive = FrameCodec("HOST").encode("DriveInputs", {"Step": 4321, "MotorTorque": -123.4, "MotorSpeed": 1500})
    status = FrameCodec("TARGET").encode(
        "Status",
        {"State": "RUNNING", "FaultBits": 5, "ModelId": 0xDEADBEEF, "DbcVersionMajor": 1, "DbcVersionMinor": 2},
    )
    lines = [candump_line(drive, 1.0), candump_line(status, 1.1)]
    result = run_cantools("decode", "--single-line", str(DBC_PATH), stdin="\n".join(lines) + "\n")
    assert result.returncode == 0, result.stderr
    out = result.stdout.splitlines()
    assert len(out) == 2
    assert out[0] == (
        f"{lines[0]} :: DriveInputs(DriveInputs_CRC: {drive.data[0]}, DriveInputs_Counter: 0, "
        "DriveInputs_Step: 4321 step, MotorTorque: -123.4 Nm, MotorSpeed: 1500.0 rpm)"
    )
    assert out[1] == (
        f"{lines[1]} :: Status(Status_CRC: {status.data[0]}, Status_Counter: 0, State: RUNNING, FaultBits: 5, "
        "ModelId: 3735928559, DbcVersionMajor: 1, DbcVersionMinor: 2)"
    )
