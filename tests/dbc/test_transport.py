"""Bus options like python-can's tools: precedence of options, environment and config file; `auto`."""

from __future__ import annotations

import argparse
import os

import can
import can.util
import pytest

from dbc import transport
from dbc.transport import (
    AUTO,
    BusConfig,
    BusUnavailable,
    add_bus_arguments,
    config_from_args,
    resolve,
)


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_bus_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.fixture(autouse=True)
def clean_env(monkeypatch, tmp_path):
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(can.util, "CONFIG_FILES", [])  # no ~/.canrc or /etc/can.conf of the machine


def test_nothing_configured_means_auto():
    assert config_from_args(parse()) == BusConfig(AUTO)


def test_options_win_over_environment_which_wins_over_a_config_file(monkeypatch, tmp_path):
    conf = tmp_path / "can.ini"
    conf.write_text("[default]\ninterface = virtual\nchannel = from-file\nbitrate = 250000\n")
    assert config_from_args(parse("--can-config", str(conf))) == BusConfig("virtual", "from-file", 250000)
    monkeypatch.setenv("CAN_INTERFACE", "udp_multicast")
    monkeypatch.setenv("CAN_CHANNEL", "239.74.163.77")
    cfg = config_from_args(parse("--can-config", str(conf)))
    assert (cfg.interface, cfg.channel, cfg.bitrate) == ("udp_multicast", "239.74.163.77", 250000)
    cfg = config_from_args(parse("-i", "virtual", "-c", "x", "-b", "500000", "--can-config", str(conf)))
    assert (cfg.interface, cfg.channel, cfg.bitrate) == ("virtual", "x", 500000)
    assert config_from_args(parse("-i", "auto")).interface == AUTO  # explicit auto ignores the environment


def test_bus_kwargs_and_argv_round_trip():
    cfg = config_from_args(parse("-i", "udp_multicast", "-c", "239.74.163.9", "--bus-kwargs", "port=45123"))
    assert cfg.kwargs == {"port": 45123}
    assert config_from_args(parse(*cfg.to_argv())) == cfg
    assert cfg.describe() == "udp_multicast 239.74.163.9 port 45123"


def test_auto_multicast_never_leaves_the_machine(tmp_path):
    """The interface-local group: frames reach another socket here, and the network interfaces send nothing."""
    if not transport.ipv6_multicast_usable():
        pytest.skip("IPv6 is off: auto falls back to the IPv4 link-local-TTL group")
    from pathlib import Path

    def tx_packets() -> int:
        return sum(int(Path(f"/sys/class/net/{dev}/statistics/tx_packets").read_text())
                   for dev in os.listdir("/sys/class/net") if dev != "lo")

    cfg = resolve(BusConfig("udp_multicast"), session_unique=True)
    a, b = cfg.open(), cfg.open()
    try:
        before = tx_packets()
        for i in range(200):
            a.send(can.Message(arbitration_id=0x110, data=bytes([i]) * 8, is_extended_id=False))
        got = [b.recv(1.0) for _ in range(200)]
        after = tx_packets()
    finally:
        a.shutdown()
        b.shutdown()
    assert all(m is not None and m.arbitration_id == 0x110 for m in got)
    assert [m.data[0] for m in got] == list(range(200))
    assert after - before < 50  # nothing of ours (other traffic of the machine may add a few)


def test_auto_falls_back_to_udp_multicast_with_a_unique_port(monkeypatch):
    monkeypatch.setattr(transport, "socketcan_usable", lambda channel="vcan0": False)
    a = resolve(BusConfig(AUTO), session_unique=True)
    b = resolve(BusConfig(AUTO), session_unique=True)
    assert a.interface == b.interface == "udp_multicast"
    assert a.kwargs["port"] != b.kwargs["port"]
    by_hand = resolve(BusConfig(AUTO))
    assert by_hand.kwargs["port"] == 43113
    assert by_hand.channel == (transport.UDP_LOCAL_GROUP if transport.ipv6_multicast_usable()
                               else transport.UDP_IPV4_GROUP)
    monkeypatch.setattr(transport, "ipv6_multicast_usable", lambda: False)
    assert resolve(BusConfig(AUTO)).channel == "239.74.163.2"
    monkeypatch.setattr(transport, "socketcan_usable", lambda channel="vcan0": True)
    assert resolve(BusConfig(AUTO)) == BusConfig("socketcan", "vcan0")


def test_unusable_buses_are_one_sentence(monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "no-such-interface")
    with pytest.raises(BusUnavailable, match="no-such-interface"):
        config_from_args(parse())
    if not hasattr(__import__("socket"), "AF_CAN") or not transport.socketcan_usable("vcan7"):
        with pytest.raises(BusUnavailable, match=r"cannot open the CAN bus socketcan vcan7 \("):
            BusConfig("socketcan", "vcan7").open()


def test_spin_policy_polls_only_while_waits_are_short_and_cores_are_free(monkeypatch):
    """A lockstep node polls before blocking while its waits end within the spin time and the machine has no more
    runnable tasks than cores; long waits or a crowded machine make it block at once (polling then takes the CPU
    the partner needs)."""
    runnable = {"now": 1}
    monkeypatch.setattr(transport, "runnable_tasks", lambda: runnable["now"])
    monkeypatch.setattr(transport, "usable_cpus", lambda: 2)
    monkeypatch.setattr(transport.SpinPolicy, "SAMPLE_S", 0.0)   # a fresh sample at every budget()
    policy = transport.SpinPolicy(0.0003)
    assert policy.budget() == 0.0003
    for _ in range(40):                           # waits of 2 ms: polling for 0.3 ms never pays
        policy.waited(0.002, blocked=True)
    assert policy.budget() == 0.0
    for _ in range(40):                           # back to 0.1 ms answers (measured while blocking too)
        policy.waited(0.0001, blocked=True)
    assert policy.budget() == 0.0003
    runnable["now"] = 6                           # two CPU-bound processes and more beside it
    assert [policy.budget() for _ in range(20)][-1] == 0.0
    runnable["now"] = 1
    assert [policy.budget() for _ in range(20)][-1] == 0.0003
    assert (policy.spun, policy.blocked) == (0, 80)
    assert transport.SpinPolicy(0.0).budget() == 0.0
