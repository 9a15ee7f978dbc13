"""The innovation gate in the generated C (observergen: obs_variance_<k>, obs_gate) against the Python float32
reference, bit for bit over a run (`bench firmware check`: outputs, 1-sigma, innovations, checkpoints): the
winding sensor in the UD form and in the steady-state-gain form (re-admission after the flag), and the lagged
sensor with a heat bias and the magnet a consider state; each run rejects some readings and keeps others. On the bus
(DBC 1.8.0) the firmware node sends each step's Rejected flag (Innovations) and the Flagged flag (Uncertainty1) byte
for byte as the Python node, and as the float32 reference counts them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dbc import decode_any
from dbc.contract import FLAG_MESSAGE, FLAGGED_SIGNALS, INNOVATION_MESSAGE, INNOVATION_SIGNALS, REJECTED_SIGNALS
from dbc.database import frame_id
from target_sim.artifact import dumps, load_artifact, seal
from target_sim.firmware.node_engine import FirmwareNode
from target_sim.node import TargetNode
from target_sim.observer import run_observer_offline
from target_sim.observer.node import raw_channels, raw_sources

from ..test_node_firmware import comparable
from .test_node_observer_firmware import _bit_exact_over_a_run, _sensor_case, _session
from helpers import SESSION_INITIAL, built_observer, steady_form

GATE = {"sigma": 1.0, "flag_after": 3}     # tight: the test sensor (1.5 K warm, 0.3 K noise) is often rejected


def _gated(path, tmp_path_factory):
    content = json.loads(json.dumps(load_artifact(path).content))
    content["observer"]["gate"] = GATE
    out = tmp_path_factory.mktemp("observer-gated") / "gated.json"
    out.write_text(dumps(seal(content)), encoding="utf-8")
    return out


@pytest.fixture(scope="module")
def gated_consider(small_dataset, tmp_path_factory):
    out = built_observer(tmp_path_factory, small_dataset, "gate-consider", "--lag", "60", "--bias", "--consider",
                         "magnet")
    return _gated(out, tmp_path_factory)


# 3.5 s each: the forms beyond the sensor's are kept out of the 5-min default run
@pytest.fixture(params=["sensor", pytest.param("sensor-steady", marks=pytest.mark.slow),
                        pytest.param("consider", marks=pytest.mark.slow)])
def gated_case(request, observer_artifact, gated_consider, tmp_path_factory):
    if request.param == "consider":
        return _sensor_case(gated_consider)
    gated = _gated(observer_artifact, tmp_path_factory)
    return _sensor_case(steady_form(gated, tmp_path_factory) if request.param == "sensor-steady" else gated)


def test_the_gate_is_bit_exact_in_the_firmware(gated_case, firmware_elf):
    result = _bit_exact_over_a_run(gated_case, firmware_elf)
    # the reference over the same channels: some readings rejected, the others used as the firmware used them
    measured = gated_case.measured.copy()
    measured[50, 0] = np.nan
    raw = raw_channels(raw_sources(gated_case.artifact), gated_case.drive, measured)
    run = run_observer_offline(gated_case.artifact, gated_case.drive, raw, SESSION_INITIAL)
    assert run.rejected[:, 0].sum() > 0
    assert result["updates_per_measurement"][0] == int(np.isfinite(run.all_innovations[:, 0]).sum())
    assert result["rejected_per_measurement"][0] == int(run.rejected[:, 0].sum())
    assert result["flagged_per_measurement"][0] == bool(run.flagged[0])


def _signals(frames, name: str) -> list[dict]:
    return [decode_any(f).signals for f in frames if f.arbitration_id == frame_id(name)]


def test_the_gate_goes_on_the_bus_byte_for_byte_in_both_nodes(gated_case, firmware_elf):
    """Both nodes through the same session (a lost and a corrupted Measurements frame, lost rows): the same frames;
    each Innovations frame's SensorRejected is the reference's rejection of that step (never with SensorUsed), the
    Uncertainty1's SensorFlagged its latched flag, and the other slot's flags stay 0."""
    artifact = gated_case.artifact
    faults, lost = {40: "drop", 61: "corrupt"}, {110, 111, 112}
    python = _session(TargetNode(artifact, clock_ns=lambda: 0), gated_case.drive, gated_case.measured, faults,
                      set(lost))
    firmware = _session(FirmwareNode(artifact, firmware_elf(gated_case.path)), gated_case.drive,
                        gated_case.measured, faults, set(lost))
    info = {frame_id("TargetInfo")}
    assert comparable(firmware, info) == comparable(python, info)
    innovations, flags = _signals(python, INNOVATION_MESSAGE), _signals(python, FLAG_MESSAGE)
    rejected = [s[REJECTED_SIGNALS["sensor"]] for s in innovations]
    assert 0 < sum(rejected) < len(rejected)
    assert not any(s[REJECTED_SIGNALS["sensor"]] and s[INNOVATION_SIGNALS["sensor"][1]] for s in innovations)
    assert not any(s[REJECTED_SIGNALS["flux"]] for s in innovations)
    flagged = [s[FLAGGED_SIGNALS["sensor"]] for s in flags]
    assert any(flagged) and not any(s[FLAGGED_SIGNALS["flux"]] for s in flags)
    first = flagged.index(1)           # latched: flagged from its first flag on (no reset in this session)
    assert all(flagged[first:])
