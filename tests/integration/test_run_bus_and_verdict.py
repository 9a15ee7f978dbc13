"""`bench run`'s bus in its JSON summary, the runner's check for a target already on the channel, and the exit
rule `bench run` and `bench analyze` share (`bench.commands.common.verdict`)."""

from __future__ import annotations

import json
import time

import can
import pytest

from bench.analysis.verdict import verdict
from bench.errors import BenchError
from bench.run.execute import refuse_foreign_target
from dbc import FrameCodec, dbc_version_info
from dbc.transport import IN_USE_LISTEN_S, UDP_IPV4_GROUP, UDP_LOCAL_GROUP, BusConfig

from helpers import run_cli

MODEL_ID = 0x1A2B3C4D


def test_bench_run_json_names_the_udp_multicast_bus(small_dataset, tmp_path):
    log = tmp_path / "x.blf"
    proc = run_cli("-m", "bench", "run", "--data", str(small_dataset), "--rows", "60", "--json", "-i",
                   "udp_multicast", "--no-report", "--log", str(log))
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    bus = s["bus"]
    assert set(bus) == {"interface", "channel", "port", "listener_drops"}, bus
    assert bus["listener_drops"] == 0, bus   # nobody else listens on the run's own port
    assert bus["interface"] == "udp_multicast" and bus["channel"] in (UDP_LOCAL_GROUP, UDP_IPV4_GROUP)
    assert isinstance(bus["port"], int) and 0 < bus["port"] < 65536 and bus["port"] != 43113  # run-unique
    assert (s["steps_sent"], s["replies"], s["missing"]) == (60, 60, 0)


def _status(model_id: int) -> can.Message:
    return FrameCodec("TARGET").encode("Status", {"State": 0, "FaultBits": 0, "ModelId": model_id,
                                                  "DbcVersionMajor": dbc_version_info()[0],
                                                  "DbcVersionMinor": dbc_version_info()[1]})


class _Artifact:
    model_id = MODEL_ID


@pytest.fixture
def virtual_pair():
    """Two ends of one in-process virtual channel: the run's host bus and a 'foreign target'."""
    channel = f"foreign-{time.perf_counter_ns()}"
    host, other = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
    yield host, other
    host.shutdown()
    other.shutdown()


@pytest.mark.parametrize(("model_id", "fragment"), [
    (MODEL_ID, "runs model 1a2b3c4d, the same as this run's"),
    (0x0BADF00D, "runs model 0badf00d, not 1a2b3c4d of the artifact given"),
])
def test_a_target_already_on_the_channel_is_refused_in_one_sentence(virtual_pair, model_id, fragment):
    host, other = virtual_pair
    other.send(_status(model_id))
    bus = BusConfig("socketcan", "vcan0")
    with pytest.raises(BenchError) as caught:
        refuse_foreign_target(host, bus, _Artifact())
    message = str(caught.value)
    assert message.startswith("channel vcan0 on socketcan already has a target sending heartbeats"), message
    assert fragment in message and message.endswith("stop it or pick another channel")


def test_a_reply_without_a_heartbeat_is_a_target_too(virtual_pair):
    host, other = virtual_pair
    other.send(FrameCodec("TARGET").encode("Temperatures1", {"Step": 3, "WindingTemp": 50.0, "MagnetTemp": 45.0}))
    bus = BusConfig("udp_multicast", UDP_LOCAL_GROUP, kwargs={"port": 5000})
    with pytest.raises(BenchError, match=r"port 5000 on udp_multicast already has a target sending frames "
                                         r"\(id 0x220\)"):
        refuse_foreign_target(host, bus, _Artifact())


@pytest.mark.timing
def test_a_quiet_channel_costs_the_listening_time_only(virtual_pair):
    host, other = virtual_pair
    other.send(FrameCodec("HOST").encode("Control", {"Command": 0, "Step": 0}))  # another host: not a target
    started = time.perf_counter()
    refuse_foreign_target(host, BusConfig("socketcan", "vcan0"), _Artifact())
    assert IN_USE_LISTEN_S <= time.perf_counter() - started < IN_USE_LISTEN_S + 0.2


NOTE = "3 fault(s) were injected (drop 3), all detected; pass --tolerate-faults to accept a run with injected faults"


@pytest.mark.parametrize(("problems", "note", "faulted", "tolerate_faults", "tolerate_gaps", "expected"), [
    ([], None, False, False, False, ([], 0)),
    (["gap"], None, False, False, True, (["gap"], 0)),              # --tolerate-gaps: reported, exit 0
    (["gap", "gap"], None, False, False, False, (["gap"], 1)),
    ([], NOTE, True, False, False, ([NOTE], 1)),                    # faults injected: 1 unless tolerated
    ([], NOTE, True, True, False, ([], 0)),
    (["undetected"], NOTE, True, True, True, (["undetected"], 1)),  # neither option forgives an undetected fault
])
def test_verdict(problems, note, faulted, tolerate_faults, tolerate_gaps, expected):
    outcome = verdict(problems, note, faulted=faulted, tolerate_faults=tolerate_faults, tolerate_gaps=tolerate_gaps)
    assert (outcome.problems, outcome.status) == expected
