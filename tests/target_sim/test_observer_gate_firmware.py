"""The innovation gate in the generated C (observergen: obs_variance_<k>, obs_gate) against the Python float32
reference, bit for bit over a run (`bench firmware check`: outputs, 1-sigma, innovations, checkpoints): the
winding sensor in the UD form and in the steady-state-gain form (re-admission after the flag), and the lagged
sensor with a heat bias and the magnet a consider state; each run rejects some readings and keeps others."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.cli import main
from target_sim.artifact import dumps, load_artifact, seal
from target_sim.observer import run_observer_offline
from target_sim.observer_node import raw_channels, raw_sources

from .test_node_observer_firmware import _bit_exact_over_a_run, _sensor_case, _steady
from helpers import SESSION_INITIAL

GATE = {"sigma": 1.0, "flag_after": 3}     # tight: the test sensor (1.5 K warm, 0.3 K noise) is often rejected


def _gated(path, tmp_path_factory):
    content = json.loads(json.dumps(load_artifact(path).content))
    content["observer"]["gate"] = GATE
    out = tmp_path_factory.mktemp("observer-gated") / "gated.json"
    out.write_text(dumps(seal(content)), encoding="utf-8")
    return out


@pytest.fixture(scope="module")
def gated_consider(small_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("observer-gate-consider") / "consider.json"
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--lag", "60", "--bias",
                 "--consider", "magnet", "--out", str(out), "--quiet"]) == 0
    return _gated(out, tmp_path_factory)


@pytest.fixture(params=["sensor", "sensor-steady", "consider"])
def gated_case(request, observer_artifact, gated_consider, tmp_path_factory):
    if request.param == "consider":
        return _sensor_case(gated_consider)
    gated = _gated(observer_artifact, tmp_path_factory)
    return _sensor_case(_steady(gated, tmp_path_factory) if request.param == "sensor-steady" else gated)


def test_the_gate_is_bit_exact_in_the_firmware(gated_case, firmware_elf):
    result = _bit_exact_over_a_run(gated_case, firmware_elf)
    # the reference over the same channels: some readings rejected, the others used as the firmware used them
    measured = gated_case.measured.copy()
    measured[50, 0] = np.nan
    raw = raw_channels(raw_sources(gated_case.artifact), gated_case.drive, measured)
    run = run_observer_offline(gated_case.artifact, gated_case.drive, raw, SESSION_INITIAL)
    assert run.rejected[:, 0].sum() > 0
    assert result["updates_per_measurement"][0] == int(np.isfinite(run.all_innovations[:, 0]).sum())
