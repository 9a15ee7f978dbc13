from __future__ import annotations

import hashlib
from importlib import resources

import numpy as np
import pytest

from bench.drive.cycles import CycleError, SpeedTrace, load_trace, provenance, verify


@pytest.mark.parametrize(("name", "points", "duration", "km", "vmax"), [
    ("ftp75", 1875, 1874.0, 17.77, 91.25),
    ("wltc3b", 1801, 1800.0, 23.27, 131.3),
])
def test_trace_length_distance_and_top_speed(name, points, duration, km, vmax):
    trace = load_trace(name)
    assert len(trace.time_s) == points
    assert trace.duration_s == duration
    assert trace.distance_km == pytest.approx(km, abs=0.005)
    assert trace.max_speed_kmh == pytest.approx(vmax, abs=0.001)


def test_wltc_speed_sum_is_the_gtr_checksum():
    assert load_trace("wltc3b").speed_kmh.sum() == pytest.approx(83758.6, abs=1e-6)


def test_traces_are_shipped_in_the_package_with_their_provenance():
    note = provenance()
    for name in ("ftp75", "wltc3b"):
        data = resources.files("bench").joinpath("data", f"{name}.csv").read_bytes()
        digest = hashlib.sha256(data).hexdigest()
        assert f"{name}.csv {digest[:8]}…{digest[-8:]}" in note


def test_a_damaged_trace_is_refused():
    good = load_trace("ftp75")
    short = SpeedTrace("ftp75", good.time_s[:-1].copy(), good.speed_kmh[:-1].copy())
    with pytest.raises(CycleError, match="1874 points, expected 1875"):
        verify(short)
    slow = SpeedTrace("ftp75", good.time_s.copy(), good.speed_kmh * 0.9)
    with pytest.raises(CycleError, match="km, expected 17.769 km"):
        verify(slow)


def test_loaded_traces_are_read_only():
    with pytest.raises(ValueError):
        load_trace("wltc3b").speed_kmh[0] = 1.0
    assert np.all(load_trace("wltc3b").speed_kmh >= 0)
