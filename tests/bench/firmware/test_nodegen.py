"""The firmware node's arithmetic equals the Python codec's: every drive and reset raw value decodes to the same
float32, every temperature encodes to the same raw value (including the exact ties the codec rounds half to even),
and the generated range checks accept exactly what the Python validator accepts."""

from __future__ import annotations

import re
from fractions import Fraction

import numpy as np
import pytest

from bench.firmware.nodegen import _divisor, packers
from dbc.contract import DRIVE_SIGNALS, RESET_SIGNALS
from dbc.database import contract, layout_named

RECEIVED = [(m.name, s) for m in contract().by_id.values() if m.sender == "HOST" for s in m.signals]


@pytest.mark.parametrize("message,signal", [*DRIVE_SIGNALS, *[(m, s) for m, pairs in RESET_SIGNALS.items()
                                                               for s, _ in pairs]])
def test_every_raw_value_decodes_to_the_codecs_float32(message, signal):
    layout = layout_named(message).signal(signal)
    n, k = _divisor(message, signal)
    raw = np.arange(-(1 << (layout.length - 1)) if layout.signed else 0, 1 << (layout.length - 1 if layout.signed
                                                                             else layout.length), dtype=np.int64)
    codec = np.array([layout.conversion.raw_to_scaled(int(r), False) for r in raw], dtype=np.float64)
    node = (raw + k).astype(np.float32) / np.float32(n)      # NODE_DECODE: one float32 division
    assert np.array_equal(codec.astype(np.float32).view(np.uint32), node.view(np.uint32))


def _node_temperature_raw(value: np.float32, n: int, offset_raw: int) -> int:
    """node_temperature_raw in Python integers: round half to even of value * n + offset_raw, exactly."""
    return round(Fraction(float(value)) * n + offset_raw)


def test_temperatures_encode_to_the_codecs_raw_values_ties_included():
    layout = layout_named("Temperatures1").signal("WindingTemp")
    n, k = _divisor("Temperatures1", "WindingTemp")
    rng = np.random.default_rng(3)
    values = np.concatenate([rng.uniform(-50, 600, 20_000), np.arange(-400, 4800) / 8,      # k + 0.5 ties
                             np.arange(-50, 600, 0.005), [-50.0, 600.0, 0.0, -0.0, 1e-30, -1e-30]]).astype(np.float32)
    values = values[(values >= -50) & (values <= 600)]
    codec = [round((float(v) - layout.offset) / layout.scale) for v in values]
    assert codec == [_node_temperature_raw(v, n, -k) for v in values]
    assert any(abs(float(v) * n - round(float(v) * n)) == 0.5 for v in values)        # ties were among them


def _cantools_bounds(source: str, message: str, signal: str) -> tuple[float | None, float | None]:
    """The bounds of the generated `<message>_<signal>_is_in_range` (None where it checks no bound)."""
    from cantools.database.can.c_source import camel_to_snake_case

    name = f"thermal_bench_{camel_to_snake_case(message)}_{camel_to_snake_case(signal)}_is_in_range"
    body = re.search(name + r"\([^)]*\)\s*\{(.*?)\}", source, re.S).group(1)
    low = re.search(r"value >= (-?[\d.e+]+)", body)
    high = re.search(r"value <= (-?[\d.e+]+)", body)
    return tuple(float(m.group(1).rstrip("uf")) if m else None for m in (low, high))


@pytest.mark.parametrize("message,signal", RECEIVED, ids=[f"{m}.{s.name}" for m, s in RECEIVED])
def test_the_generated_range_checks_accept_what_the_python_validator_accepts(message, signal):
    source = packers()["thermal_bench.c"]
    low, high = _cantools_bounds(source, message, signal.name)
    if signal.ieee is not None:      # a float signal: compared as float
        assert (low, high) == (signal.minimum, signal.maximum)
        return
    bits = signal.length
    raw = np.arange(-(1 << (bits - 1)), 1 << (bits - 1)) if signal.signed else np.arange(0, 1 << bits)
    python = np.array([signal.low <= signal.conversion.raw_to_scaled(int(r), False) <= signal.high for r in raw])
    generated = np.ones(raw.size, bool)
    if low is not None:
        generated &= raw >= low
    if high is not None:
        generated &= raw <= high
    assert np.array_equal(python, generated)


def test_the_node_is_generated_for_loss_map_models_only():
    """The firmware node validates and ignores DriveCurrents (its range checks are generated, above); a model with
    an electrical loss model, which needs the currents, is refused in one sentence."""
    import json

    from bench.firmware.literals import FirmwareGenerationError
    from bench.firmware.nodegen import node_config
    from target_sim.artifact import verify

    from helpers import electrical_artifact_text

    assert "thermal_bench_drive_currents_current_d_is_in_range" in packers()["thermal_bench.c"]
    artifact = verify(json.loads(electrical_artifact_text()))
    with pytest.raises(FirmwareGenerationError) as info:
        node_config(artifact)
    assert str(info.value) == (f"the firmware engine runs loss-map models only; model {artifact.model_id:08x} has an "
                               "electrical loss model: use --engine python")
