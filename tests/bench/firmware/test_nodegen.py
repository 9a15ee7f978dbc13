"""The firmware node's arithmetic equals the Python codec's: every drive, current, reset and measurement (the
observer's Measurements and DriveVoltages values) raw value decodes to the same float32, every temperature encodes
to the same raw value (including the exact ties the codec rounds half to even), and the generated range checks
accept exactly what the Python validator accepts; the data row of each loss model comes from the contract."""

from __future__ import annotations

import re
from fractions import Fraction

import numpy as np
import pytest

from bench.firmware.nodegen import _divisor, packers
from dbc.contract import CURRENT_SIGNALS, DRIVE_SIGNALS, MEASUREMENT_CHANNELS, RESET_SIGNALS
from dbc.database import contract, layout_named

RECEIVED = [(m.name, s) for m in contract().by_id.values() if m.sender == "HOST" for s in m.signals]


@pytest.mark.parametrize("message,signal", [*DRIVE_SIGNALS, *CURRENT_SIGNALS,
                                            *[(m, s) for m, pairs in RESET_SIGNALS.items() for s, _ in pairs],
                                            *[(m, s) for m, s, _ in MEASUREMENT_CHANNELS.values()]])
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


def _python_accepts(signal) -> tuple[np.ndarray, np.ndarray]:
    """Every raw value of an integer signal, and whether the Python validator accepts each (its scaled range)."""
    bits = signal.length
    raw = np.arange(-(1 << (bits - 1)), 1 << (bits - 1)) if signal.signed else np.arange(0, 1 << bits)
    return raw, np.array([signal.low <= signal.conversion.raw_to_scaled(int(r), False) <= signal.high for r in raw])


def _generated_accepts(raw: np.ndarray, low, high) -> np.ndarray:
    """Whether a generated check with raw limits `low`, `high` (None: no limit on that side) accepts each raw value."""
    accepted = np.ones(raw.size, bool)
    if low is not None:
        accepted &= raw >= low
    if high is not None:
        accepted &= raw <= high
    return accepted


@pytest.mark.parametrize("message,signal", RECEIVED, ids=[f"{m}.{s.name}" for m, s in RECEIVED])
def test_the_generated_range_checks_accept_what_the_python_validator_accepts(message, signal):
    source = packers()["thermal_bench.c"]
    low, high = _cantools_bounds(source, message, signal.dbc_name)
    if signal.ieee is not None:      # a float signal: compared as float
        assert (low, high) == (signal.minimum, signal.maximum)
        return
    raw, python = _python_accepts(signal)
    assert np.array_equal(python, _generated_accepts(raw, low, high))


def test_the_row_of_each_loss_model_is_generated_from_the_contract():
    """A loss-map model's row is DriveInputs + DriveTemps (DriveCurrents validated, otherwise ignored); an electrical
    model's adds DriveCurrents, whose currents go to places 4 and 5 of the row: `dbc.contract.row_signals`, decoded
    with one float32 division each (above)."""
    import json

    from bench.firmware.nodegen import node_config
    from dbc.contract import row_signals
    from target_sim.artifact import load_artifact, verify

    from helpers import ROOT, electrical_artifact_text

    assert "thermal_bench_drive_currents_current_d_is_in_range" in packers()["thermal_bench.c"]
    maps = node_config(load_artifact(ROOT / "bench" / "data" / "default_model.json"))
    electrical = node_config(verify(json.loads(electrical_artifact_text())))
    for config, width in ((maps, 4), (electrical, 6)):
        signals = row_signals(width)
        messages = list(dict.fromkeys(message for message, _ in signals))
        assert f"#define NODE_ROW_WIDTH {width}u" in config
        assert f"#define NODE_ROW_MESSAGES {len(messages)}u" in config
        for index, message in enumerate(messages):
            snake = re.sub(r"(?<!^)(?=[A-Z])", "_", message).upper()
            assert f"#define NODE_ROW_INDEX_{snake} {index}u" in config
            decode = re.search(rf"#define NODE_DECODE_{snake}\(sample, m\) do {{ (.*) }} while", config).group(1)
            places = [int(place) for place in re.findall(r"\(sample\)\[(\d)\]", decode)]
            assert places == [place for place, (owner, _) in enumerate(signals) if owner == message]
    assert "NODE_ROW_INDEX_DRIVE_CURRENTS" not in maps and "NODE_DECODE_DRIVE_CURRENTS" not in maps


# ------------------------------------------------------------------------------------------------ receive side
def _config() -> str:
    from bench.firmware.nodegen import node_config
    from target_sim.artifact import load_artifact

    from helpers import ROOT

    return node_config(load_artifact(ROOT / "bench" / "data" / "default_model.json"))


def _target_received() -> list:
    """The messages the DBC (as cantools reads it) gives receiver TARGET, by frame id."""
    return sorted((m for m in contract().database.messages if "TARGET" in m.receivers), key=lambda m: m.frame_id)


def test_the_generated_receive_list_is_every_message_the_dbc_gives_receiver_target():
    from cantools.database.can.c_source import camel_to_snake_case

    config = _config()
    listed = re.search(r"#define NODE_RX_LIST\(X\) (.*)", config).group(1)
    entries = re.findall(r"X\((\w+), (\w+), 0x([0-9A-F]{3})u\)", listed)
    assert len(entries) == listed.count("X(")
    expected = [(camel_to_snake_case(m.name).upper(), camel_to_snake_case(m.name), m.frame_id)
                for m in _target_received()]
    assert [(name, snake, int(fid, 16)) for name, snake, fid in entries] == expected
    assert {m.frame_id for m in _target_received()} == contract().frame_ids("HOST")     # the host sends them all
    stepped = {m.frame_id for m in _target_received() if "Step" in contract().by_id[m.frame_id].signal_names}
    for name, snake, fid in entries:
        # every message with a Step has its accessor (1.7.0's RestoreObserver names its row by StepLow: none)
        assert bool(re.search(rf"#define NODE_STEP_{name}\(m\) \(\(m\)\.{snake}_step\)", config)) == \
            (int(fid, 16) in stepped), name
        assert f"#define NODE_OUT_OF_RANGE_{name}(m) (" in config


def _generated_checks(config: str, message: str) -> dict[str, tuple[int, float | None, float | None]]:
    """NODE_OUT_OF_RANGE_<message>'s checks: {field: (returned index, lower limit, upper limit)}, in macro order."""
    from cantools.database.can.c_source import camel_to_snake_case

    body = re.search(rf"#define NODE_OUT_OF_RANGE_{camel_to_snake_case(message).upper()}\(m\) \((.*)\)$", config,
                     re.M).group(1)
    checks = {}
    for condition, index in re.findall(r"!(\(.*?\)\)?) \? (\d+) : ", body):
        field = set(re.findall(r"\(m\)\.(\w+)", condition))
        assert len(field) == 1, condition
        low = re.search(r">= (-?[\w.+]+?)u?\)", condition)
        high = re.search(r"<= (-?[\w.+]+?)u?\)", condition)
        checks[field.pop()] = (int(index), *(None if m is None else float.fromhex(m.group(1).rstrip("f"))
                                             if "0x" in m.group(1) else float(m.group(1)) for m in (low, high)))
    assert body.endswith("-1")
    return checks


@pytest.mark.parametrize("message", [m.name for m in _target_received()])
def test_the_generated_range_limits_are_what_the_python_validator_accepts(message):
    """Every signal of a received message: its generated raw (or float32) limits accept exactly the raw values the
    Python validator accepts, checked in DBC order, returning the signal's index in the DBC message; a signal whose
    every raw value is in range has no check."""
    from cantools.database.can.c_source import camel_to_snake_case

    checks = _generated_checks(_config(), message)
    layout = layout_named(message)
    order = [s.name for s in layout.message.signals]
    indexes = [index for index, _, _ in checks.values()]
    assert indexes == sorted(indexes)
    for signal in layout.signals:
        field = camel_to_snake_case(signal.dbc_name)
        if signal.ieee is not None:
            index, low, high = checks[field]
            assert (low, high) == (signal.minimum, signal.maximum)       # exact in float32: no value between
            assert np.float32(low) == low and np.float32(high) == high
            assert index == order.index(signal.dbc_name)
            continue
        raw, python = _python_accepts(signal)
        if python.all():
            assert field not in checks
            continue
        index, low, high = checks[field]
        assert index == order.index(signal.dbc_name)
        assert np.array_equal(python, _generated_accepts(raw, low, high))


def test_node_c_spells_out_no_received_message_nor_frame_id_of_the_dbc():
    """node.c keeps the rules; which messages it receives, their ids, unpacking and ranges come from the DBC through
    fw_node_config.h. So no frame id of the DBC as a number, and no cantools name of a received message."""
    from cantools.database.can.c_source import camel_to_snake_case

    from helpers import ROOT

    source = (ROOT / "bench" / "firmware" / "node.c").read_text(encoding="utf-8")
    numbers = {int(token, 16) for token in re.findall(r"\b0[xX]([0-9a-fA-F]+)[uUlL]*\b", source)}
    assert not numbers & set(contract().by_id), "a frame id of the DBC is spelled out in node.c"
    for m in _target_received():
        snake = camel_to_snake_case(m.name)
        assert f"THERMAL_BENCH_{snake.upper()}_" not in source and f"thermal_bench_{snake}_" not in source, m.name
