"""Bus-load arithmetic and the float64 references of the report."""

from __future__ import annotations

import numpy as np
import pytest

from bench.analysis.busload import frame_bits
from bench.analysis.canmetrics import float64_reference
from target_sim.artifact import load_artifact
from target_sim.model import run_offline


def reference_bits(frame_id: int, data: bytes) -> int:
    """Bit by bit: SOF..CRC with stuffing after five equal bits, then the fixed 13-bit tail incl. IFS."""
    bits = [0] + [(frame_id >> i) & 1 for i in range(10, -1, -1)] + [0, 0, 0] + [1, 0, 0, 0]
    for byte in data:
        bits += [(byte >> i) & 1 for i in range(7, -1, -1)]
    crc = 0
    for bit in bits:
        feedback = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if feedback:
            crc ^= 0x4599
    bits += [(crc >> i) & 1 for i in range(14, -1, -1)]
    count, run, last = 0, 0, None
    for bit in bits:
        count += 1
        run = run + 1 if bit == last else 1
        last = bit
        if run == 5:
            count += 1
            last, run = 1 - bit, 1
    return count + 13


def test_frame_bits_with_stuffing():
    rng = np.random.default_rng(4)
    ids = rng.integers(0, 0x800, 400)
    data = rng.integers(0, 256, (400, 8)).astype(np.uint8)
    data[:20] = 0  # long runs: the most stuff bits
    data[20:40] = 0xFF
    got = frame_bits(ids, data)
    assert [reference_bits(int(i), bytes(d)) for i, d in zip(ids, data, strict=True)] == got.tolist()
    assert got.min() >= 111 and got.max() <= 111 + 24 + 3


def assert_float64_reference_tracks_float32(artifact) -> None:
    """On 1500 random rows: the same model in two precisions (and, for lti/hammerstein with a balanced block, two
    implementations) is close, not equal, and it did heat up."""
    rng = np.random.default_rng(9)
    n = 1500
    drive = np.column_stack([rng.uniform(-200, 500, n), rng.uniform(0, 8000, n), np.full(n, 40.0),
                             np.full(n, 25.0)])
    initial = [40.0, 45.0, 41.0, 50.0]
    _, f32 = run_offline(artifact, drive, initial)
    f64 = float64_reference(artifact, drive, initial)
    assert f64.shape == f32.shape == (600, 4)
    assert 0 < np.max(np.abs(f32 - f64)) < 0.02
    assert np.max(f64[:, 1]) > 50.0


@pytest.mark.parametrize("name", ["lti", "hammerstein", "pv"])
def test_float64_reference_tracks_float32(artifacts, name):
    assert_float64_reference_tracks_float32(load_artifact(artifacts[name]))


@pytest.mark.parametrize("kind", ["lti-lptn", "hammerstein"])
def test_float64_reference_of_the_delta_realization_tracks_float32(kind, tmp_path):
    """The delta realization steps x <- x + Δ·(A x + B ũ) about a reference temperature: its float64 reference must
    run that, not x <- A x + B u (which made the packaged model "depart from float64 by 104 °C")."""
    from helpers import artifact_text

    path = tmp_path / f"{kind}-delta.json"
    path.write_text(artifact_text(kind, "delta"), encoding="utf-8")
    assert_float64_reference_tracks_float32(load_artifact(path))
