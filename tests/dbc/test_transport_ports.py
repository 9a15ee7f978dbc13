"""python-can's tools attach to a run: the udp_multicast port rule (a channel the user chose gets python-can's default
port; the bench's own group a port unique to the run) and the `python -m can.logger` line a run prints."""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter

import can
import can.util
import pytest

from dbc import transport
from dbc.transport import (
    AUTO,
    UDP_DEFAULT_PORT,
    BusConfig,
    add_bus_arguments,
    config_from_args,
    free_udp_port,
    logger_command,
    resolve,
)
from dbc.udp_listeners import udp_sockets

from helpers import ROOT, run_cli, subprocess_env

GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:7465"   # a group of this test's own (interface-local scope)


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_bus_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.fixture(autouse=True)
def clean_env(monkeypatch):
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(can.util, "CONFIG_FILES", [])


def test_python_can_users_settings_get_python_cans_default_port(monkeypatch):
    """Only CAN_INTERFACE/CAN_CHANNEL set, as for `python -m can.logger`: the run's port is 43113, where the
    logger listens (it was a random one, so the logger recorded nothing)."""
    monkeypatch.setenv("CAN_INTERFACE", "udp_multicast")
    monkeypatch.setenv("CAN_CHANNEL", GROUP)
    from bench.commands.args import bus_from_args

    bus = bus_from_args(parse())
    assert (bus.interface, bus.channel, bus.kwargs) == ("udp_multicast", GROUP, {"port": UDP_DEFAULT_PORT})


@pytest.mark.parametrize(("argv", "port"), [
    (("-i", "udp_multicast", "-c", GROUP), UDP_DEFAULT_PORT),            # channel chosen by flags
    (("-c", GROUP), UDP_DEFAULT_PORT),                                     # auto with a chosen group
    (("-i", "udp_multicast", "-c", GROUP, "--bus-kwargs", "port=45111"), 45111),   # a port given wins
    (("-i", "auto", "--bus-kwargs", "port=45112"), 45112),
])
def test_a_chosen_channel_keeps_python_cans_port_unless_one_is_given(monkeypatch, argv, port):
    monkeypatch.setattr(transport, "socketcan_usable", lambda channel="vcan0": False)
    bus = resolve(config_from_args(parse(*argv)), session_unique=True)
    assert bus.interface == "udp_multicast" and bus.kwargs["port"] == port


def test_a_channel_from_a_config_file_keeps_python_cans_port(tmp_path):
    conf = tmp_path / "can.ini"
    conf.write_text(f"[default]\ninterface = udp_multicast\nchannel = {GROUP}\n")
    bus = resolve(config_from_args(parse("--can-config", str(conf))), session_unique=True)
    assert (bus.channel, bus.kwargs["port"]) == (GROUP, UDP_DEFAULT_PORT)


def test_the_benchs_own_group_still_gets_a_port_unique_to_the_run(monkeypatch):
    monkeypatch.setattr(transport, "socketcan_usable", lambda channel="vcan0": False)
    ports = {resolve(config_from_args(parse()), session_unique=True).kwargs["port"] for _ in range(3)}
    ports |= {resolve(BusConfig("udp_multicast"), session_unique=True).kwargs["port"]}
    assert UDP_DEFAULT_PORT not in ports and len(ports) == 4
    assert resolve(BusConfig(AUTO)).kwargs["port"] == UDP_DEFAULT_PORT   # a node started by hand


def test_the_logger_line_is_python_cans_own_options():
    assert logger_command(BusConfig("udp_multicast", GROUP, kwargs={"port": 43113})) == (
        f"python -m can.logger -i udp_multicast -c {GROUP} -f bench-copy.blf")
    assert logger_command(BusConfig("udp_multicast", GROUP, kwargs={"port": 50123}), "x y.log") == (
        f"python -m can.logger -i udp_multicast -c {GROUP} -f 'x y.log' --bus-kwargs port=50123")
    assert logger_command(BusConfig("socketcan", "vcan0", bitrate=500000)) == (
        "python -m can.logger -i socketcan -c vcan0 -b 500000 -f bench-copy.blf")


def _frames(path) -> Counter:
    return Counter((m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(path)))


@pytest.mark.slow
def test_the_printed_logger_line_records_the_run(small_dataset, tmp_path):
    """With --json the line is on stderr at the start; pasted (with another file name) into a second process,
    python-can's logger records every frame of the run but those the run's summary says listeners dropped (none
    unless the logger was starved of CPU: a lockstep run sends thousands of frames a second, and a logger on a busy
    machine loses some at its full receive buffer; the kernel counts them, `dbc.udp_listeners`)."""
    port = free_udp_port()
    bus = ("-i", "udp_multicast", "-c", GROUP, "--bus-kwargs", f"port={port}")
    expected = logger_command(BusConfig("udp_multicast", GROUP, kwargs={"port": port}), str(tmp_path / "copy.log"))
    argv = expected.split()
    assert argv[:3] == ["python", "-m", "can.logger"]
    # The logger's stderr goes to a file, not a pipe nobody reads while it runs (a full pipe would block it).
    logger_err = tmp_path / "logger.stderr"
    with logger_err.open("wb") as err:
        logger = subprocess.Popen([sys.executable, *argv[1:]], cwd=ROOT, env=subprocess_env(can_settings=False),
                                  stdout=subprocess.DEVNULL, stderr=err)
    try:
        # Ready: python-can's logger creates its file after it has joined the group (start-up, imports: 1-2 s
        # alone, much longer on a machine running other tests in parallel), so wait for the file, generously.
        deadline = time.monotonic() + 120
        while not (tmp_path / "copy.log").exists() and time.monotonic() < deadline and logger.poll() is None:
            time.sleep(0.05)
        assert logger.poll() is None and (tmp_path / "copy.log").exists(), (
            f"python-can's logger did not start within 120 s: {logger_err.read_text(errors='replace')}")
        time.sleep(0.3)
        run = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", "200", "--no-report", "--json",
                      "--log", str(tmp_path / "run.log"), *bus, can_settings=False)
        # The run's last frames may still wait in the logger's socket; the SIGINT ends its loop only once it has
        # taken them all off (a loaded machine may need seconds).
        assert _drained(port, timeout_s=60), "python-can's logger did not read its socket empty within 60 s"
    finally:
        if logger.poll() is None:
            os.kill(logger.pid, signal.SIGINT)
        try:
            # SIGINT ends the logger's receive loop; it then shuts the bus down and flushes and closes copy.log.
            # Normally well under a second; up to 60 s allowed on a machine busy with other tests.
            logger.wait(60)
        except subprocess.TimeoutExpired:
            logger.kill()
            logger.wait()
            pytest.fail(f"python-can's logger did not exit within 60 s of SIGINT: "
                        f"{logger_err.read_text(errors='replace')}")
    assert run.returncode == 0, run.stderr
    printed = [line for line in run.stderr.splitlines() if "can.logger" in line]
    assert printed == [f"bench: to record this bus with python-can: python -m can.logger -i udp_multicast -c {GROUP} "
                       f"-f bench-copy.blf --bus-kwargs port={port}"], run.stderr
    recorded, copied = _frames(tmp_path / "run.log"), _frames(tmp_path / "copy.log")
    assert sum(recorded.values()) > 200 * 4
    dropped = json.loads(run.stdout)["bus"].get("listener_drops")
    assert dropped is not None, "the kernel's drop counts were not read"
    # The count is read a few milliseconds after the run's log closed: a target heartbeat (every 0.1 s) the logger
    # dropped in between is counted but is no frame of the log.
    missing = sum((recorded - copied).values())
    assert missing <= dropped <= missing + 2, f"the logger lost {missing} frames of the run, the run counted {dropped}"
    assert ("dropped" in run.stderr) == (dropped > 0), run.stderr


def _drained(port: int, timeout_s: float) -> bool:
    """True once no socket on udp `port` has bytes waiting (the run's own are closed: only listeners remain)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not any(s.waiting_bytes for s in udp_sockets(port) or ()):
            return True
        time.sleep(0.05)
    return False


@pytest.mark.slow
@pytest.mark.skipif(udp_sockets(UDP_DEFAULT_PORT) is None, reason="the kernel does not list UDP sockets (not Linux)")
def test_frames_a_listener_lost_at_its_full_buffer_are_counted_and_named(small_dataset, tmp_path):
    """A listener on the run's bus that does not read (a socket joined to the group with the smallest receive
    buffer): the run names the frames it lost, the kernel's count for that socket while the run's host sent, and still
    exits 0 (its own log is whole)."""
    port = free_udp_port()
    with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as deaf:
        deaf.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        deaf.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)   # as python-can's sockets, to share the port
        deaf.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)      # the kernel's minimum: a few datagrams
        deaf.bind(("", port))
        deaf.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_JOIN_GROUP,
                        socket.inet_pton(socket.AF_INET6, GROUP) + (0).to_bytes(4, "little"))
        run = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", "200", "--no-report", "--json",
                      "--log", str(tmp_path / "run.log"), "-i", "udp_multicast", "-c", GROUP, "--bus-kwargs",
                      f"port={port}", can_settings=False)
        inode = os.fstat(deaf.fileno()).st_ino
        lost = next(s.drops for s in udp_sockets(port) or () if s.inode == inode)
    assert run.returncode == 0, run.stderr
    assert lost > 200, f"the deaf listener dropped only {lost} frames"
    # the run counts until its host is done; the socket kept dropping the target's heartbeats until it stopped
    counted = json.loads(run.stdout)["bus"]["listener_drops"]
    assert 200 < counted <= lost
    assert f"dropped {counted} frames of the run" in run.stderr, run.stderr


LISTENER_WAIT_S = 20   # generous: python-can's logger imports and opens the bus in 1-3 s, many more under load


@pytest.mark.slow
def test_a_logger_started_during_the_wait_for_listener_records_the_whole_run(small_dataset, tmp_path):
    """The logger line names the run's own udp port, which exists only once `bench run` has started: with
    --wait-for-listener the line comes first (with --quiet too) and the run waits before its target starts, so a
    logger started from the line during the wait records every frame of the run (but those the run counted as
    lost at its full receive buffer)."""
    env = subprocess_env(can_settings=False)
    run = subprocess.Popen([sys.executable, "-m", "bench", "run", "--data", str(small_dataset), "--rows", "200",
                            "--no-report", "--json", "--quiet", "--log", str(tmp_path / "run.log"),
                            "--wait-for-listener", str(LISTENER_WAIT_S)],
                           cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stderr: list[str] = []
    announced = threading.Event()

    def drain() -> None:
        for line in run.stderr:
            stderr.append(line)
            if "python -m can.logger" in line:
                announced.set()

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    logger = None
    copy = tmp_path / "copy.log"
    try:
        assert announced.wait(60), f"no logger line within 60 s of the start: {''.join(stderr)}"
        started_wait = time.monotonic()
        line = next(s for s in stderr if "python -m can.logger" in s)
        argv = shlex.split(line.split("to record this bus with python-can: ", 1)[1])
        argv[argv.index("-f") + 1] = str(copy)
        logger = subprocess.Popen([sys.executable, *argv[1:]], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE)
        while not copy.exists() and logger.poll() is None and time.monotonic() - started_wait < LISTENER_WAIT_S:
            time.sleep(0.05)   # the logger creates its file once its bus is open
        ready_after = time.monotonic() - started_wait
        assert copy.exists(), f"python-can's logger did not open the bus during the {LISTENER_WAIT_S} s wait"
        out, _ = run.communicate(timeout=240)
        reader.join(10)
        port = json.loads(out)["bus"]["port"]
        assert _drained(port, timeout_s=60), "python-can's logger did not read its socket empty within 60 s"
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
        if logger is not None and logger.poll() is None:
            os.kill(logger.pid, signal.SIGINT)
            try:
                logger.wait(60)   # under load python-can's logger took more than 20 s to stop after SIGINT
            except subprocess.TimeoutExpired:
                logger.kill()
                logger.wait()
                pytest.fail("python-can's logger did not exit within 60 s of SIGINT (its file may be incomplete)")
    assert run.returncode == 0, "".join(stderr)
    assert any(f"waiting {LISTENER_WAIT_S} s for a listener" in line for line in stderr), "".join(stderr)
    assert json.loads(out)["verdict"] == "clean"
    recorded, copied = _frames(tmp_path / "run.log"), _frames(copy)
    assert sum(recorded.values()) > 200 * 4
    # all but those the run counted as lost at the logger's full buffer (a busy machine; see the test above)
    missing, dropped = sum((recorded - copied).values()), json.loads(out)["bus"]["listener_drops"]
    assert missing <= dropped <= missing + 2, (f"the logger (ready {ready_after:.1f} s into the {LISTENER_WAIT_S} s "
                                               f"wait) lost {missing} frames of the run, the run counted {dropped}")
