"""Two hosts on one channel would both drive the target. A host's bus is a `dbc.transport.SenderGuard`: a host frame
it did not send (udp_multicast hands a node its own frames back: the guard sends from a socket whose copies the
kernel drops, or else counts what it sent until its copy returns) stops it in one sentence naming the channel, from
the pre-start listening of `bench run` to the end of a run.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from dbc import FrameCodec, transport
from dbc.database import host_frame_ids
from dbc.transport import UDP_LOCAL_GROUP, BusConfig, OtherSender, SenderGuard, free_udp_port

from helpers import ROOT, private_udp_bus, subprocess_env


def _drain(bus, quiet_s: float = 0.2) -> list[can.Message]:
    got = []
    while (msg := bus.recv(quiet_s)) is not None:
        got.append(msg)
    return got


@pytest.mark.parametrize("unechoed", [True, False], ids=["own-socket", "copies-counted"])
def test_guard_knows_its_own_frames_from_another_hosts(unechoed, monkeypatch):
    """Sending from its own socket (`UnechoedSender`: the kernel drops the copies) or through the bus (copies counted
    until they come back), the guard hears no frame of its own and stops at another host's."""
    monkeypatch.setattr(transport, "SEND_UNECHOED", unechoed)
    config = private_udp_bus()
    mine, other = config.open(), config.open()
    guard = SenderGuard(mine, config, host_frame_ids(), "host")
    assert (guard.unechoed is not None) == unechoed and guard.echoes != unechoed
    try:
        host, target = FrameCodec("HOST"), FrameCodec("TARGET")
        sent = [host.encode("Control", {"Command": 0, "Step": step % 16}) for step in range(40)]
        sent.append(can.Message(arbitration_id=sent[0].arbitration_id, data=sent[0].data, is_extended_id=False))
        for msg in sent + [sent[-1]]:          # the same bytes twice: two copies come back (or none), both ours
            guard.send(msg)
        echoes = _drain(guard)
        expected = [] if unechoed else sorted(bytes(m.data) for m in sent + [sent[-1]])
        assert sorted(bytes(m.data) for m in echoes) == expected
        heard = _drain(other)                  # every other node hears them all, as python-can sent them
        assert sorted((m.arbitration_id, bytes(m.data)) for m in heard) == \
            sorted((m.arbitration_id, bytes(m.data)) for m in sent + [sent[-1]])
        other.send(target.encode("RxErrors", dict.fromkeys(  # a target's frame: not a host's business here
            ["CounterError", "CrcError", "OutOfRange", "SequenceError", "UnknownId", "WrongLength"], 0)))
        assert [m.arbitration_id for m in _drain(guard)] == [0x231]
        other.send(can.Message(arbitration_id=sent[3].arbitration_id, data=sent[3].data, is_extended_id=False))
        with pytest.raises(OtherSender) as raised:   # bytes this host sent once, and whose copy came back already
            _drain(guard)
        assert str(raised.value) == (f"another host is sending on {config.describe()} (frame id 0x100, not sent by "
                                     "this host); stop it or pick another channel")
    finally:
        guard.shutdown()
        other.shutdown()


def test_guard_without_loopback_takes_every_host_frame_for_another_hosts():
    """SocketCAN and real interfaces do not hand a node its own frames: any host frame is another host's."""
    config = BusConfig("virtual", channel=f"guard-{os.getpid()}")
    guard = SenderGuard(config.open(), config, host_frame_ids(), "host")
    other = config.open()
    try:
        guard.send(FrameCodec("HOST").encode("Control", {"Command": 0, "Step": 0}))
        assert [m.arbitration_id for m in _drain(other)] == [0x100]
        other.send(can.Message(arbitration_id=0x110, data=bytes(8), is_extended_id=False))   # DriveInputs
        with pytest.raises(OtherSender, match=r"another host is sending on virtual guard-\d+ \(frame id 0x110, "):
            _drain(guard)
    finally:
        guard.shutdown()
        other.shutdown()


def _targets(port: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0") if entry.name.isdigit() else []
        except OSError:
            continue
        if b"target_sim" in argv and f"port={port}".encode() in argv:
            found.append(int(entry.name))
    return found


def _sentence(port: int) -> str:
    return f"another host is sending on udp_multicast {UDP_LOCAL_GROUP} port {port} (frame id 0x1"


def test_run_on_a_channel_where_a_host_waits_for_its_target(cli, material, scratch):
    """A `bench host` waits (silently) for a target's heartbeat; `bench run` on its channel starts one. Both hear
    the other's RESET: the one that hears the other first stops in one sentence before it sends a frame, so no
    target is driven by two hosts (before, both ran and the target rejected half the frames of each)."""
    port = free_udp_port()
    out = scratch / "out"
    bus = ["-i", "udp_multicast", "-c", UDP_LOCAL_GROUP, "--bus-kwargs", f"port={port}"]
    host_err = scratch / "host.stderr"
    with open(host_err, "w+") as err:
        waiting = subprocess.Popen([sys.executable, "-m", "bench", "host", "--data", str(material.data), "--model",
                                    str(material.art), "--log", str(out / "h.blf"), "--connect-timeout", "60", *bus],
                                   cwd=scratch, env=subprocess_env(can_settings=False), stdin=subprocess.DEVNULL,
                                   stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        try:
            deadline = time.monotonic() + 60
            while "bench: host: " not in host_err.read_text() and time.monotonic() < deadline:
                assert waiting.poll() is None, host_err.read_text()
                time.sleep(0.05)
            time.sleep(0.5)   # past its own listening: it waits for a heartbeat now
            run = cli("bench", "run", "--data", material.data, "--model", material.art, "--log", out / "x.blf",
                      "--no-report", "--quiet", *bus, cwd=scratch, timeout=90)
            waiting.wait(60)
        finally:
            if waiting.poll() is None:
                waiting.kill()
                waiting.wait()
            left = _targets(port)
            for pid in left:
                os.kill(pid, signal.SIGKILL)
    host_lines = [line for line in host_err.read_text().splitlines() if not line.startswith("bench: host: ")]
    noticed = {"run": any(_sentence(port) in line for line in run.lines),
               "host": any(_sentence(port) in line for line in host_lines)}
    assert any(noticed.values()), f"{run}\n--- bench host ---\n{host_err.read_text()}"
    for name, rc, lines in (("run", run.rc, run.lines), ("host", waiting.returncode, host_lines)):
        if noticed[name]:
            assert rc == 1 and len(lines) == 1 and lines[0].startswith("bench: error: another host is sending on "), \
                (name, lines)
            assert lines[0].endswith("not sent by this host); stop it or pick another channel"), (name, lines)
    assert left == []
    partials = [p.name for p in out.rglob("*") if p.name.startswith(".")] if out.exists() else []
    assert partials == []


FOREIGN_HOST = """
import sys, time
import can
from dbc import FrameCodec
bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
codec = FrameCodec("HOST")
print("sending", flush=True)
try:
    while True:
        bus.send(codec.encode("Control", {"Command": 0, "Step": 0}))
        time.sleep(0.05)
finally:
    bus.shutdown()
"""


@pytest.mark.parametrize("command", ["run", "replay"])
def test_run_and_replay_refuse_a_channel_where_a_host_sends(cli, material, scratch, command):
    """A host already sending is heard while `bench run`/`bench replay` listen before they start their target."""
    port = free_udp_port()
    foreign = subprocess.Popen([sys.executable, "-c", FOREIGN_HOST, UDP_LOCAL_GROUP, str(port)], cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    out = scratch / "out"
    args = (["run", "--data", material.data, "--model", material.art, "--log", out / "x.blf", "--no-report"]
            if command == "run" else ["replay", material.log, "--model", material.art, "--log", out / "r.blf",
                                      "--as-fast-as-possible"])
    try:
        assert foreign.stdout.readline().strip() == "sending"
        result = cli("bench", *args, "--quiet", "-i", "udp_multicast", "-c", UDP_LOCAL_GROUP, "--bus-kwargs",
                     f"port={port}", cwd=scratch, timeout=60)
    finally:
        foreign.terminate()
        foreign.wait(60)   # its exit after SIGTERM: generous on a busy machine
        left = _targets(port)
        for pid in left:
            os.kill(pid, signal.SIGKILL)
    assert result.rc == 1, str(result)
    assert result.lines == [f"bench: error: another host is sending on udp_multicast {UDP_LOCAL_GROUP} port {port} "
                            "(frame id 0x100, not sent by this host); stop it or pick another channel"], str(result)
    assert left == []
    assert not out.exists() or list(out.rglob("*")) == []
