"""Property-based hardening: random frames into the decoders and the target node, random and mutated JSON into
the artifact loader, random bytes into the dataset and log readers, broken DBCs into the DBC loader.

What must hold for every input: only the documented error type comes out (FrameError, ArtifactError,
DatasetError, LogError, DbcError), and a rejected input changes no state (the validator's counters, apart from
the documented resynchronization after a counter error; the node's model state, estimate and session).
"""

from __future__ import annotations

import copy
import json
import math
import tempfile
import warnings
from pathlib import Path

import can
import numpy as np
import pytest
from cantools.autosar import end_to_end
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import dbc.database
from dbc import (
    FRAME_ERROR_KINDS,
    FaultBit,
    FrameCodec,
    FrameError,
    FrameValidator,
    apply_crc,
    decode_any,
    frame_id,
    frame_ids,
    load_database,
    signal_ranges,
)
from target_sim.artifact import ArtifactError, encode_array, load_artifact, seal, verify

PROPERTY = settings(derandomize=True, database=None, deadline=None, max_examples=200,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
SENDERS = {msg.name: msg.senders[0] for msg in load_database().messages}
HOST_MESSAGES = sorted(name for name, sender in SENDERS.items() if sender == "HOST")
ALL_MESSAGES = sorted(SENDERS)
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
SOMETIMES = st.sampled_from([False, False, False, False, True])


# ---------------------------------------------------------------- frames


@st.composite
def raw_frames(draw) -> can.Message:
    """Anything a bus can deliver: any id (standard or extended), DLC 0-8 or an FD length up to 64 (also
    disagreeing with the data), random payloads, remote, error and FD frames."""
    extended = draw(SOMETIMES)
    fid = draw(st.one_of(st.sampled_from(sorted(frame_ids().values())), st.integers(0, 0x7FF),
                         st.integers(0, 0x1FFFFFFF if extended else 0x7FF)))
    is_fd = draw(SOMETIMES)
    length = draw(st.sampled_from(FD_LENGTHS if is_fd else (*FD_LENGTHS[:9], 8, 8, 8)))
    data = draw(st.binary(min_size=length, max_size=length))
    dlc = draw(st.one_of(st.just(length), st.just(length), st.integers(0, 64)))
    return can.Message(arbitration_id=fid, is_extended_id=extended, is_fd=is_fd, dlc=dlc, data=data,
                       is_remote_frame=draw(SOMETIMES), is_error_frame=draw(SOMETIMES), check=False, timestamp=1.0)


@st.composite
def crc_valid_frames(draw, names=tuple(ALL_MESSAGES)) -> can.Message:
    """A known id, 8 random bytes and the right CRC: passes id, length and CRC, then meets ranges and counters."""
    name = draw(st.sampled_from(names))
    fid = frame_id(name)
    data = apply_crc(fid, draw(st.binary(min_size=8, max_size=8)))
    return can.Message(arbitration_id=fid, is_extended_id=False, dlc=8, data=data, check=False, timestamp=1.0)


def signal_value(low: float, high: float):
    """In range mostly; out of range, non-finite and huge sometimes."""
    return st.one_of(st.floats(low, high), st.floats(low, high), st.integers(math.ceil(low), math.floor(high)),
                     st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**40), 2**40),
                     st.sampled_from([low, high, low - 1, high + 1, -0.0]))


@st.composite
def signal_sets(draw, names=tuple(HOST_MESSAGES)) -> tuple[str, dict]:
    name = draw(st.sampled_from(names))
    values = {}
    for signal, (low, high) in signal_ranges(name).items():
        values[signal] = draw(signal_value(low, high))
    if draw(st.integers(0, 9)) == 0 and values:  # sometimes an enum given by a (maybe wrong) name
        signal = draw(st.sampled_from(sorted(values)))
        values[signal] = draw(st.sampled_from(["RESET", "START", "NOP", "STOP", "nonsense", ""]))
    return name, values


def _outcome(fn, msg):
    try:
        frame = fn(msg)
    except FrameError as exc:
        return ("error", exc.kind, exc.message)
    return ("ok", frame.name, frame.frame_id, frame.signals, frame.counter)


def _within_ranges(name: str, signals: dict) -> bool:
    for signal, (low, high) in signal_ranges(name).items():
        tolerance = 1e-6 * max(1.0, abs(low), abs(high))
        if not low - tolerance <= float(signals[signal]) <= high + tolerance:
            return False
    return True


@PROPERTY
@given(frames=st.lists(st.one_of(raw_frames(), crc_valid_frames()), min_size=1, max_size=20),
       receiver=st.sampled_from(["TARGET", "HOST", None]))
def test_validators_reject_only_with_frame_error_and_change_no_state(frames, receiver):
    validator = FrameValidator(receiver)
    for msg in frames:
        counters = dict(validator._last_counter)
        outcome = _outcome(validator.validate, msg)
        if outcome[0] == "error":
            assert outcome[1] in FRAME_ERROR_KINDS and outcome[2] and "\n" not in outcome[2]
            if outcome[1] == "counter":  # the documented resync: the expected counter follows the frame
                assert validator._last_counter == {**counters, msg.arbitration_id: msg.data[1] & 0x0F}
            else:
                assert validator._last_counter == counters
        else:
            assert _within_ranges(outcome[1], outcome[3])
            assert outcome[3] == _cantools_signals(msg)
        stateless = _outcome(decode_any, msg)
        assert stateless[0] == "ok" or stateless[1] != "counter"
        if outcome[0] == "ok" or outcome[1] == "counter":  # everything but the counter passed
            assert stateless[0] == "ok" and stateless[3] == (outcome[3] if outcome[0] == "ok" else stateless[3])


def _cantools_signals(msg: can.Message) -> dict:
    """cantools' decoding of a frame the codec accepted: the same values and types."""
    message = load_database().get_message_by_frame_id(msg.arbitration_id)
    decoded = message.decode(bytes(msg.data), decode_choices=False, scaling=True)
    return {dbc.database.role_name(message.name, k): v for k, v in decoded.items()
            if k not in (f"{message.name}_CRC", f"{message.name}_Counter")}


@PROPERTY
@given(frames=st.lists(raw_frames(), min_size=1, max_size=10))
def test_decode_any_of_random_frames(frames):
    for msg in frames:
        outcome = _outcome(decode_any, msg)
        if outcome[0] == "ok":
            assert outcome[3] == _cantools_signals(msg) and _within_ranges(outcome[1], outcome[3])
        else:
            assert outcome[1] in FRAME_ERROR_KINDS and outcome[1] != "counter"


@PROPERTY
@given(case=signal_sets(tuple(ALL_MESSAGES)), counter=st.integers(0, 15))
def test_codecs_refuse_with_frame_error_and_keep_the_counter(case, counter):
    name, values = case
    sender = SENDERS[name]
    codec = FrameCodec(sender)
    codec._next_counter[frame_id(name)] = counter
    try:
        msg = codec.encode(name, values, timestamp=1.0)
    except FrameError as exc:
        assert exc.kind == "out_of_range", exc.message
        assert codec._next_counter[frame_id(name)] == counter  # a refused frame uses no counter value
        return
    assert codec._next_counter[frame_id(name)] == (counter + 1) % 16
    decoded = FrameValidator(None).validate(msg)
    message, layout = load_database().get_message_by_name(name), dbc.database.layout_named(name)
    for signal, value in values.items():
        if isinstance(value, str):
            continue
        scale = abs(layout.signal(signal).scale)
        assert abs(float(decoded.signals[signal]) - float(value)) <= scale / 2 + 1e-9 * abs(float(value))
    # cantools encodes the same bytes (its strict encoder, its E2E profile-2 CRC)
    data = {**{layout.signal(k).dbc_name: v for k, v in values.items()}, f"{name}_CRC": 0, f"{name}_Counter": counter}
    payload = message.encode(data, scaling=True, padding=False, strict=True)
    assert bytes(msg.data) == bytes(end_to_end.apply_profile2_crc(payload, msg.arbitration_id & 0xFF))


# ---------------------------------------------------------------- the target node, driven without a bus


@pytest.fixture(scope="module")
def node_artifacts(tmp_path_factory, artifact_texts):
    out = tmp_path_factory.mktemp("node")
    artifacts = {}
    for kind, text in artifact_texts.items():
        path = out / f"{kind}.json"
        path.write_text(text)
        artifacts[kind] = load_artifact(path)
    return artifacts


def _array(value):
    return None if value is None else np.asarray(value).tobytes()


def node_snapshot(node) -> tuple:
    """What a rejected frame must not change in the Python node (RX_ERROR and the error counters aside)."""
    model, acc = node.model, node.accumulator
    return (node.state, int(node.faults) & ~int(FaultBit.RX_ERROR), node.next_row, node.rows_used, node.model_steps,
            node.overruns, _array(node.estimate), _array(model.x), _array(model.y), _array(acc.sum),
            acc.count, _array(acc.last_inputs), repr(node._pending), repr(node._reset_frames),
            repr(node._restore_frames), node.last_reply_row, node.errors.get("sequence"))


def firmware_snapshot(node) -> bytes:
    """The firmware node's RAM but its output block, counters, mailbox, fault bits (compared with the Python
    node's) and stack: what a rejected frame must not change (a counter error resynchronizes the alive counter)."""
    fw = node.fw
    ram = bytearray(fw.read_bytes(fw.ram[0], fw.stack[0] - fw.ram[0]))
    for name in ("node_out", "node_counters", "node_rx", "faults"):
        symbol = fw.symbols[name]
        start = symbol.address - fw.ram[0]
        ram[start:start + symbol.size] = bytes(symbol.size)
    return bytes(ram)


def comparable(frames) -> list[tuple[int, bytes]]:
    """Replies as both engines must send them: timing frames (measured times) and TargetInfo (the ELF's flash and
    RAM against the estimate) by id only; Timing4 is the firmware's alone."""
    return [(f.arbitration_id, b"" if 0x222 <= f.arbitration_id <= 0x225 or f.arbitration_id == 0x232
             else bytes(f.data)) for f in frames if f.arbitration_id != 0x225]


def session_frames(host: FrameCodec, rows: int) -> list:
    """RESET, START and `rows` data rows, as a host sends them."""
    frames = [host.encode(name, signals) for name, signals in (
        ("ResetTemps1", {"Step": 0, "WindingTempInit": 60.0, "MagnetTempInit": 50.0}),
        ("ResetTemps2", {"Step": 0, "YokeTempInit": 45.0, "ToothTempInit": 55.0}),
        ("Control", {"Command": 1, "Step": 0}), ("Control", {"Command": 2, "Step": 0}))]
    for row in range(rows):
        frames.append(host.encode("DriveInputs", {"Step": row, "MotorTorque": 100.0 + row, "MotorSpeed": 2000.0}))
        frames.append(host.encode("DriveTemps", {"Step": row, "CoolantTemp": 40.0, "AmbientTemp": 25.0}))
    return frames


@st.composite
def node_inputs(draw, host: FrameCodec):
    """Random frames, CRC-valid random payloads, and well-formed host frames with random (maybe wild) values."""
    kind = draw(st.integers(0, 2))
    if kind == 0:
        return draw(raw_frames())
    if kind == 1:
        return draw(crc_valid_frames(tuple(HOST_MESSAGES)))
    name, values = draw(signal_sets(tuple(HOST_MESSAGES)))
    try:
        return host.encode(name, values)
    except FrameError:
        return draw(crc_valid_frames(tuple(HOST_MESSAGES)))


@pytest.fixture(scope="module")
def node_elves(node_artifacts, firmware_builds):
    """The firmware of each node artifact (built once per run: they are not the packaged ones), or None without the
    compiler."""
    try:
        import ziglang  # noqa: F401
    except ImportError:
        return None
    from bench.firmware.codegen import generate

    return {kind: firmware_builds.elf(generate(artifact)) for kind, artifact in node_artifacts.items()}


@pytest.mark.slow   # 14 s with its firmware fixtures: kept out of the 5-min default run
@settings(PROPERTY, max_examples=120)
@given(data=st.data(), kind=st.sampled_from(["hammerstein", "lti-lptn", "pv-lptn"]), rows=st.integers(0, 7),
       engine=st.sampled_from(["python", "firmware"]))
def test_node_survives_random_frames_and_rejects_without_a_trace(node_artifacts, node_elves, data, kind, rows,
                                                                 engine):
    """The Python node: a rejected frame leaves no trace but its counter; with engine "firmware" the firmware node
    gets every frame too and must answer byte for byte the same, with the same fault bits and error counts, its
    RAM untouched by a rejected frame."""
    from target_sim.firmware.node_engine import FirmwareNode
    from target_sim.node import TargetNode

    assume(engine == "python" or node_elves is not None)
    node = TargetNode(node_artifacts[kind], clock_ns=lambda: 0)
    twin = FirmwareNode(node_artifacts[kind], node_elves[kind]) if engine == "firmware" else None
    host = FrameCodec("HOST")
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # a wild but valid input may overflow float32: that is the node's business
        frames = session_frames(host, rows)
        startup = node.startup_frames()      # as serve() sends them (the firmware's node_init queued its own)
        if twin is not None:
            assert comparable(twin.startup_frames()) == comparable(startup)
        for msg in frames:
            out = node.handle(msg)
            if twin is not None:
                assert comparable(twin.handle(msg)) == comparable(out)
        for _ in range(data.draw(st.integers(1, 15))):
            msg = data.draw(node_inputs(host))
            before, counters, errors = node_snapshot(node), dict(node.validator._last_counter), dict(node.errors)
            ram = firmware_snapshot(twin) if twin is not None else b""
            out = node.handle(msg)
            if twin is not None:
                assert comparable(twin.handle(msg)) == comparable(out)
                assert (twin.faults, twin.errors, twin.state) == (int(node.faults), node.errors, node.state)
            assert not node.faults & FaultBit.INTERNAL, node.last_error
            changed = [k for k in FRAME_ERROR_KINDS if node.errors[k] != errors[k]]
            if not changed:
                continue
            assert len(changed) == 1 and node.errors[changed[0]] == errors[changed[0]] + 1
            assert out == [] and node.faults & FaultBit.RX_ERROR
            assert node_snapshot(node) == before, f"a rejected frame ({changed[0]}) changed the node"
            if changed[0] == "counter":
                assert node.validator._last_counter == {**counters, msg.arbitration_id: msg.data[1] & 0x0F}
            else:
                assert node.validator._last_counter == counters
                if twin is not None:
                    assert firmware_snapshot(twin) == ram, f"a rejected frame ({changed[0]}) changed the firmware"


# ---------------------------------------------------------------- the artifact loader

JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=12),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=25)


def verify_or_run(content) -> None:
    """verify() must raise ArtifactError or return an artifact the target can load and step."""
    try:
        artifact = verify(content)
    except ArtifactError as exc:
        assert str(exc) and "\n" not in str(exc)
        return
    from target_sim.node import TargetNode

    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        node = TargetNode(artifact)
        node.model.reset([40.0, 60.0, 50.0, 45.0])
        for _ in range(3):
            node.model.step(np.float32(200.0), np.float32(3000.0), np.float32(40.0), np.float32(25.0))


@settings(PROPERTY, max_examples=120)
@given(value=JSON, header=st.booleans(), sealed=st.booleans())
def test_verify_random_json(value, header, sealed):
    if header and isinstance(value, dict):
        value = {**value, "schema": "pmsm-thermal-bench.model-artifact", "schema_version": 1}
    if sealed and isinstance(value, dict):
        try:
            value = seal(value)
        except (ValueError, TypeError):  # NaN or infinity: seal() is the builder's, it may refuse
            assume(False)
    verify_or_run(value)


def tree_paths(node, prefix=()) -> list[tuple]:
    """Every dict key and a few list positions of a JSON tree (lists of numbers: first and last element)."""
    paths = []
    if isinstance(node, dict):
        for key, child in node.items():
            paths.append((*prefix, key))
            paths += tree_paths(child, (*prefix, key))
    elif isinstance(node, list) and node:
        for index in sorted({0, len(node) - 1}):
            paths.append((*prefix, index))
            paths += tree_paths(node[index], (*prefix, index))
    return paths


def replaced(content, path, value=None, delete=False):
    """A copy of content with the node at path replaced (or deleted); only the nodes along the path are copied."""
    out = copy.copy(content)
    node = out
    for key in path[:-1]:
        node[key] = copy.copy(node[key])
        node = node[key]
    if delete and isinstance(node, dict):
        del node[path[-1]]
    elif delete:
        node.pop(path[-1])
    else:
        node[path[-1]] = value
    return out


@pytest.fixture(scope="module")
def base_contents(artifact_texts):
    contents = {kind: json.loads(text) for kind, text in artifact_texts.items()}
    return {kind: (content, [p for p in tree_paths(content) if p[0] not in ("metrics", "provenance", "sha256")])
            for kind, content in contents.items()}


WRONG = [None, True, "x", -1, 0, 1e300, -1e-300, [], {}, [1.0, 2.0], {"shape": [], "f64": [1.0], "f32_hex": []}]


def test_every_field_with_every_wrong_type(base_contents):
    """Every field of every kind of artifact replaced by a value of the wrong type (or deleted), resealed so
    that the checksum holds: ArtifactError, or an artifact the target runs."""
    checked = 0
    for kind, (content, paths) in base_contents.items():
        step = 1 if kind == "hammerstein" else 4  # the other kinds share most of the tree
        for i, path in enumerate(paths[::step]):
            verify_or_run(seal(replaced(content, path, WRONG[i % len(WRONG)])))
            if i % 2:
                verify_or_run(seal(replaced(content, path, delete=True)))
            checked += 1
    assert checked > 150


@st.composite
def mutations(draw, base_contents):
    kind = draw(st.sampled_from(sorted(base_contents)))
    content, paths = base_contents[kind]
    path = draw(st.sampled_from(paths))
    how = draw(st.sampled_from(["json", "delete", "array", "number"]))
    if how == "delete":
        mutated = replaced(content, path, delete=True)
    elif how == "array":  # a well-formed encoded array of a random shape and random values
        shape = draw(st.sampled_from([(), (1,), (2,), (3,), (4,), (21,), (3, 3), (4, 4), (4, 8), (21, 16)]))
        values = draw(st.lists(st.floats(-1e6, 1e6), min_size=int(np.prod(shape)), max_size=int(np.prod(shape))))
        mutated = replaced(content, path, encode_array(np.array(values, dtype=float).reshape(shape)))
    elif how == "number":
        mutated = replaced(content, path, draw(st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                                                         st.integers(-(2**70), 2**70))))
    else:
        mutated = replaced(content, path, draw(JSON))
    return mutated, draw(st.booleans())


@settings(PROPERTY, max_examples=200)
@given(data=st.data())
def test_mutated_artifacts(base_contents, data):
    mutated, reseal = data.draw(mutations(base_contents))
    if reseal:
        try:
            mutated = seal(mutated)
        except (ValueError, TypeError):
            assume(False)
    verify_or_run(mutated)


@PROPERTY
@given(data=st.data())
def test_load_artifact_of_damaged_bytes(artifact_texts, data):
    text = artifact_texts[data.draw(st.sampled_from(sorted(artifact_texts)))].encode()
    how = data.draw(st.sampled_from(["truncate", "flip", "insert", "random"]))
    if how == "truncate":
        damaged = text[: data.draw(st.integers(0, len(text) - 1))]
    elif how == "flip":
        at = data.draw(st.integers(0, len(text) - 1))
        damaged = text[:at] + bytes([text[at] ^ data.draw(st.integers(1, 255))]) + text[at + 1:]
    elif how == "insert":
        at = data.draw(st.integers(0, len(text)))
        damaged = text[:at] + data.draw(st.binary(min_size=1, max_size=20)) + text[at:]
    else:
        damaged = data.draw(st.binary(max_size=200))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.json"
        path.write_bytes(damaged)
        try:
            load_artifact(path)
        except ArtifactError as exc:
            assert "model.json" in str(exc) and "\n" not in str(exc)


@pytest.mark.parametrize("text", [
    "[" * 100_000 + "]" * 100_000,
    '{"a":' * 50_000 + "1" + "}" * 50_000,
    '{"schema": ' + "9" * 5000 + "}",
    "1e999", "-Infinity", "NaN", '{"schema": NaN}', '"' + "x" * 100_000 + '"', "\x00", "\ufeff{}",
], ids=["deep-list", "deep-object", "huge-int", "inf", "-inf", "nan", "nan-field", "long-string", "nul", "bom"])
def test_load_artifact_of_absurd_json(tmp_path, text):
    path = tmp_path / "model.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ArtifactError, match="model.json"):
        load_artifact(path)


def test_verify_of_absurd_objects(base_contents):
    deep: list = []
    for _ in range(100_000):
        deep = [deep]
    content = base_contents["hammerstein"][0]
    for value in (deep, {**content, "extra": deep}, {**content, 1: "int key"},
                  {**content, "timing": {"dt_s": math.nan}}, {**content, "x": {1, 2}},
                  {**content, "schema_version": True}, {**content, "schema_version": 1.0}):
        with pytest.raises(ArtifactError):
            verify(value)


# ---------------------------------------------------------------- the dataset and log readers


@PROPERTY
@given(payload=st.one_of(st.binary(max_size=400), st.text(alphabet=st.sampled_from(list("0123456789.,-e\n\r\"naN x_")),
                                                              max_size=400).map(str.encode)),
       header=st.booleans())
def test_load_dataset_of_random_bytes(payload, header):
    from bench.drive.dataset import COLUMNS, DatasetError, load_dataset

    if header:
        payload = (",".join(COLUMNS) + "\n").encode() + payload
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "data.csv"
        path.write_bytes(payload)
        try:
            load_dataset(path)
        except DatasetError as exc:
            assert "data.csv" in str(exc) and "\n" not in str(exc) and len(str(exc)) < 600


@pytest.fixture(scope="module")
def log_bytes(tmp_path_factory) -> dict[str, bytes]:
    """A short log of real frames in every format."""
    from host.canlog import FrameLog

    host, target = FrameCodec("HOST"), FrameCodec("TARGET")
    frames = []
    for step in range(12):
        frames.append(host.encode("DriveInputs", {"Step": step, "MotorTorque": 10.0, "MotorSpeed": 100.0 * step},
                                  timestamp=1.7e9 + step * 0.01))
        frames.append(target.encode("Temperatures1", {"Step": step, "WindingTemp": 40.0, "MagnetTemp": 35.5},
                                    timestamp=1.7e9 + step * 0.01 + 0.001))
    out = tmp_path_factory.mktemp("logs")
    logs = {}
    for suffix in (".blf", ".asc", ".log", ".csv"):
        with FrameLog(out / f"bus{suffix}") as log:
            for msg in frames:
                log.write(msg)
        logs[suffix] = (out / f"bus{suffix}").read_bytes()
    return logs


@settings(PROPERTY, max_examples=150)
@given(data=st.data())
def test_read_log_of_damaged_logs(log_bytes, data):
    from host.canlog import LogError, read_log

    suffix = data.draw(st.sampled_from(sorted(log_bytes)))
    good = log_bytes[suffix]
    how = data.draw(st.sampled_from(["truncate", "flip", "random"]))
    if how == "truncate":
        damaged = good[: data.draw(st.integers(0, len(good) - 1))]
    elif how == "flip":
        at = data.draw(st.integers(0, len(good) - 1))
        damaged = good[:at] + bytes([good[at] ^ data.draw(st.integers(1, 255))]) + good[at + 1:]
    else:
        damaged = data.draw(st.binary(max_size=300))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"bus{suffix}"
        path.write_bytes(damaged)
        try:
            frames = list(read_log(path))
        except LogError as exc:
            assert f"bus{suffix}" in str(exc) and "\n" not in str(exc)
        else:
            assert how != "truncate" or suffix in (".log", ".csv"), "a truncated .blf/.asc was read as complete"
            assert all(isinstance(f, can.Message) for f in frames)


# ---------------------------------------------------------------- the DBC


@pytest.fixture
def dbc_path(monkeypatch, tmp_path):
    """Point dbc.database at a DBC file of the test's making; the real one is back (and reloaded) afterwards."""
    path = tmp_path / "contract.dbc"
    monkeypatch.setattr(dbc.database, "DBC_PATH", path)
    load_database.cache_clear()
    yield path
    monkeypatch.undo()
    load_database.cache_clear()
    load_database()


def _load_or_dbc_error(path: Path, data: bytes | None):
    if data is not None:
        path.write_bytes(data)
    load_database.cache_clear()
    try:
        return load_database()
    except dbc.database.DbcError as exc:
        message = str(exc)
        assert message.startswith("the CAN contract") and "\n" not in message
        assert "reinstall the package or restore dbc/thermal_bench.dbc" in message
        return None


def test_broken_dbc_files(dbc_path):
    good = Path(dbc.database.__file__).with_name("thermal_bench.dbc").read_bytes()
    assert _load_or_dbc_error(dbc_path, None) is None  # missing
    for data in (b"", b"\xff\xfe" + bytes(range(256)) * 8, b"VERSION \"1.0.0\"\n", good.replace(b"VERSION", b"VERS"),
                 good.replace(b'BA_ "E2EDataID"', b'BA_ "E2EDataId"'), good.replace(b'VERSION "', b'VERSION "x')):
        assert _load_or_dbc_error(dbc_path, data) is None
    dbc_path.unlink()
    dbc_path.mkdir()
    assert _load_or_dbc_error(dbc_path, None) is None  # a directory
    dbc_path.rmdir()


def test_truncated_dbc_at_every_tenth_line(dbc_path):
    good = Path(dbc.database.__file__).with_name("thermal_bench.dbc").read_bytes()
    lines = good.split(b"\n")
    loaded = 0
    for n in range(0, len(lines), 10):
        database = _load_or_dbc_error(dbc_path, b"\n".join(lines[:n]) + b"\n")
        if database is not None:  # only the value tables missing: every message, id and data id is there
            loaded += 1
            assert {m.name for m in database.messages} == set(SENDERS)
    assert _load_or_dbc_error(dbc_path, good) is not None
