"""The DBC file itself: structure, conventions and the layout the bench relies on."""

import re

import cantools
import numpy as np
import pytest

import dbc
from dbc import DBC_PATH, load_database
from dbc.database import contract, role_name

DB = load_database()
MESSAGES = DB.messages
E2E_SIGNALS = {f"{m.name}_{suffix}" for m in MESSAGES for suffix in ("CRC", "Counter")}
# Signals without a physical unit: E2E fields, enums, bit fields, identifiers and version numbers.
UNITLESS = E2E_SIGNALS | {
    "Command",
    "State",
    "FaultBits",
    "ModelId",
    "DbcVersionMajor",
    "DbcVersionMinor",
    "ModelKind",
    "Realization",
    "Event",
    "FaultKind",
    "FrameId",
    "StateIndex",
    "StateValue",
    "SensorStatus",
    "FluxMagnetStatus",
    "SensorUsed",
    "FluxMagnetUsed",
    "SensorRejected",
    "FluxMagnetRejected",
    "SensorFlagged",
    "FluxMagnetFlagged",
    "VoltageStatus",
    "Index",
    "Value",
}
ENUMS = {
    "Command": dbc.Command,
    "State": dbc.TargetState,
    "ModelKind": dbc.ModelKind,
    "Realization": dbc.Realization,
    "Event": dbc.BenchEvent,
    "FaultKind": dbc.FaultKind,
    "SensorStatus": dbc.contract.MeasurementStatus,
    "FluxMagnetStatus": dbc.contract.MeasurementStatus,
    "VoltageStatus": dbc.contract.MeasurementStatus,
}


def app_signals(message):
    return [s for s in message.signals if s.name not in E2E_SIGNALS]


def test_loads_with_strict_checks_and_is_ascii():
    database = cantools.database.load_file(DBC_PATH, strict=True)
    assert len(database.messages) == 26
    DBC_PATH.read_bytes().decode("ascii")  # cantools reads DBC files as cp1252: keep them plain ASCII


def test_version_is_in_the_file_and_exposed():
    text = DBC_PATH.read_text(encoding="ascii")
    version_line = re.search(r'^VERSION "(\d+)\.(\d+)\.(\d+)"$', text, re.MULTILINE)
    assert version_line is not None
    assert dbc.dbc_version() == DB.version == ".".join(version_line.groups())
    assert dbc.dbc_version_info() == tuple(int(part) for part in version_line.groups())
    assert DB.dbc.attributes["DBName"].value == "thermal_bench"


def test_nodes_and_frame_format():
    assert sorted(node.name for node in DB.nodes) == ["HOST", "TARGET"]
    for message in MESSAGES:
        assert message.length == 8, message.name
        assert not message.is_extended_frame and not message.is_fd, message.name
        assert 0 <= message.frame_id <= 0x7FF, message.name
        assert len(message.senders) == 1 and message.senders[0] in dbc.NODES, message.name
        receiver = "TARGET" if message.senders[0] == "HOST" else "HOST"
        assert all(s.receivers == [receiver] for s in message.signals), message.name
        assert all(s.byte_order == "little_endian" for s in message.signals), message.name


def test_host_frames_win_arbitration_over_target_frames():
    host = [m.frame_id for m in MESSAGES if m.senders == ["HOST"]]
    target = [m.frame_id for m in MESSAGES if m.senders == ["TARGET"]]
    assert all(0x100 <= fid < 0x200 for fid in host)
    assert all(0x200 <= fid < 0x300 for fid in target)
    assert max(host) < min(target)
    assert frozenset(host) == dbc.host_frame_ids()
    assert frozenset(target) == dbc.target_frame_ids()
    assert dict(dbc.frame_ids()) == {m.name: m.frame_id for m in MESSAGES}


def test_every_message_has_comment_cycle_time_and_e2e_data_id():
    data_ids = set()
    for message in MESSAGES:
        assert message.comment and len(message.comment) > 20, message.name
        assert "GenMsgCycleTime" in message.dbc.attributes, message.name  # set explicitly, not by default
        data_id = message.dbc.attributes["E2EDataID"].value
        assert data_id == message.frame_id & 0xFF == dbc.database.e2e_data_id(message.frame_id), message.name
        assert f"E2E data id 0x{data_id:02X}." in message.comment, message.name
        data_ids.add(data_id)
    assert len(data_ids) == len(MESSAGES)  # a frame on the wrong id fails the CRC


@pytest.mark.parametrize(
    ("name", "cycle_ms"),
    [
        ("Control", 0),
        ("ResetTemps1", 0),
        ("ResetTemps2", 0),
        ("DriveInputs", 200),
        ("DriveTemps", 200),
        ("DriveCurrents", 200),
        ("Temperatures1", 200),
        ("Temperatures2", 200),
        ("Timing1", 200),
        ("Timing2", 200),
        ("Timing3", 200),
        ("Timing4", 200),
        ("Timing5", 200),
        ("Status", 100),
        ("RxErrors", 100),
        ("TargetInfo", 0),
        ("BenchEvent", 0),
    ],
)
def test_cycle_times(name, cycle_ms):
    assert DB.get_message_by_name(name).dbc.attributes["GenMsgCycleTime"].value == cycle_ms


def test_e2e_header_layout():
    for message in MESSAGES:
        crc = message.get_signal_by_name(f"{message.name}_CRC")
        counter = message.get_signal_by_name(f"{message.name}_Counter")
        assert (crc.start, crc.length, crc.is_signed) == (0, 8, False), message.name
        assert (counter.start, counter.length, counter.is_signed) == (8, 4, False), message.name
        used = 0
        for signal in app_signals(message):
            assert signal.start >= 12, signal.name
            bits = ((1 << signal.length) - 1) << signal.start
            assert used & bits == 0, signal.name
            used |= bits
        assert used >> 64 == 0, message.name
        assert sum(s.length for s in app_signals(message)) <= 52, message.name


def test_every_signal_has_unit_comment_and_range():
    for message in MESSAGES:
        for signal in message.signals:
            label = f"{message.name}.{signal.name}"
            assert signal.comment and len(signal.comment) > 10, label
            assert signal.minimum is not None and signal.maximum is not None, label
            assert signal.minimum < signal.maximum, label
            if signal.name in UNITLESS or role_name(message.name, signal.name) in UNITLESS:
                assert not signal.unit, label
            else:
                assert signal.unit, label


def test_ranges_are_representable_and_on_the_raw_grid():
    for message in MESSAGES:
        for signal in message.signals:
            if signal.is_float:  # IEEE single: the range must hold exactly in float32
                assert signal.length == 32 and (signal.scale, signal.offset) == (1, 0), signal.name
                assert all(float(np.float32(limit)) == limit for limit in (signal.minimum, signal.maximum))
                continue
            low = -(1 << (signal.length - 1)) if signal.is_signed else 0
            high = (1 << (signal.length - 1)) - 1 if signal.is_signed else (1 << signal.length) - 1
            for limit in (signal.minimum, signal.maximum):
                raw = (limit - signal.offset) / signal.scale
                assert abs(raw - round(raw)) < 1e-6, (signal.name, limit)
                assert low <= round(raw) <= high, (signal.name, limit)


def test_value_tables_match_python_enums():
    for message in MESSAGES:
        for signal in message.signals:
            if signal.name in ENUMS:
                enum = ENUMS[signal.name]
                table = {int(raw): str(text).lower() for raw, text in signal.choices.items()}
                assert table == {m.value: m.name.lower().replace("_", "-") for m in enum}, signal.name
                assert (signal.minimum, signal.maximum) == (0, max(table)), signal.name
            else:
                assert not signal.choices, signal.name


def test_fault_bits_are_documented():
    comment = DB.get_message_by_name("Status").get_signal_by_name("FaultBits").comment
    for bit in dbc.FaultBit:
        assert f"bit {bit.value.bit_length() - 1} {bit.name} " in comment, bit.name
    assert len(list(dbc.FaultBit)) == 8


def signal(message_name, signal_name):
    """Signal `signal_name` of a message, by the name the code knows it by (Step for Control_Step)."""
    message = DB.get_message_by_name(message_name)
    return next(s for s in message.signals if role_name(message_name, s.name) == signal_name)


def test_layout_meets_the_resolution_and_range_requirements():
    for name in ("Control", "ResetTemps1", "ResetTemps2", "DriveInputs", "DriveTemps", "DriveCurrents"):
        step = signal(name, "Step")
        assert (step.length, step.is_signed, step.scale, step.minimum, step.maximum) == (16, False, 1, 0, 65535)
    for name in ("Temperatures1", "Temperatures2", "Timing1", "Timing2", "Timing3", "Timing4"):
        assert signal(name, "Step").length == 16
    torque = signal("DriveInputs", "MotorTorque")
    assert (torque.scale, torque.minimum, torque.maximum, torque.unit) == (0.1, -2000, 2000, "Nm")
    speed = signal("DriveInputs", "MotorSpeed")
    assert (speed.scale, speed.minimum, speed.maximum, speed.unit) == (0.5, -1000, 15000, "rpm")
    for name in ("CoolantTemp", "AmbientTemp"):
        temp = signal("DriveTemps", name)
        assert (temp.scale, temp.minimum, temp.maximum, temp.unit) == (0.1, -40, 150, "degC")
    for message_name, names in [
        ("Temperatures1", ("WindingTemp", "MagnetTemp")),
        ("Temperatures2", ("YokeTemp", "ToothTemp")),
        ("ResetTemps1", ("WindingTempInit", "MagnetTempInit")),
        ("ResetTemps2", ("YokeTempInit", "ToothTempInit")),
    ]:
        for name in names:
            temp = signal(message_name, name)
            assert (temp.length, temp.scale, temp.minimum, temp.maximum) == (16, 0.01, -50, 600), name
    step_time = signal("Timing1", "StepTimeMeasured")
    assert step_time.scale <= 1 and step_time.maximum >= 60_000 and step_time.unit == "us"
    assert (signal("Timing1", "Overruns").length, signal("Timing1", "Overruns").maximum) == (8, 255)
    cycles = signal("Timing2", "EstCycles")
    assert cycles.scale == 1 and cycles.maximum >= 500_000
    exec_time = signal("Timing2", "EstExecTime")
    assert exec_time.scale <= 0.1 and exec_time.maximum >= cycles.maximum / 90  # 90 MHz
    load = signal("Timing3", "CpuLoad")
    assert load.scale <= 0.0001 and load.maximum >= 100 and load.unit == "%"
    model_id = signal("Status", "ModelId")
    assert (model_id.length, model_id.maximum) == (32, 0xFFFFFFFF)
    dt = signal("TargetInfo", "ModelDt")
    assert (dt.scale, dt.minimum, dt.maximum, dt.unit) == (0.1, 0, 25.5, "s")
    for name in ("RestoreState", "StateCheckpoint"):  # one float32 state element per frame, bit for bit
        value = signal(name, "StateValue")
        assert (value.length, value.is_float, value.scale, value.offset) == (32, True, 1, 0)
        assert (signal(name, "StateIndex").minimum, signal(name, "StateIndex").maximum) == (0, 3)
        assert signal(name, "Step").length == 16
    counters = ("UnknownId", "WrongLength", "CrcError", "CounterError", "OutOfRange", "SequenceError")
    assert [s.name for s in app_signals(DB.get_message_by_name("RxErrors"))] == list(counters)
    assert all(signal("RxErrors", name).length == 8 for name in counters)


def test_version_1_3_adds_timing4_beside_the_c28x_estimate_and_says_so():
    """1.3.0: the firmware engine's measured Cortex-M4F cycles in a message of their own, laid out like the C28x
    estimate of Timing2 (same range, same µs resolution at the same 90 MHz), sent by the target; the history in
    the DBC's comment; TargetInfo's flash and RAM say when they are measured."""
    assert dbc.dbc_version_info()[:2] >= (1, 3)
    timing4 = DB.get_message_by_name(dbc.contract.FIRMWARE_TIMING_MESSAGE)
    assert timing4.frame_id == 0x225 and timing4.senders == ["TARGET"] and 0x200 <= timing4.frame_id <= 0x2FF
    assert [role_name(timing4.name, s.name) for s in app_signals(timing4)] == ["Step", "M4Cycles", "M4ExecTime"]
    cycles, exec_time = signal("Timing4", "M4Cycles"), signal("Timing4", "M4ExecTime")
    est_cycles, est_time = signal("Timing2", "EstCycles"), signal("Timing2", "EstExecTime")
    assert (cycles.length, cycles.scale, cycles.maximum, cycles.unit) == (est_cycles.length, 1, est_cycles.maximum,
                                                                          "cycles")
    assert (exec_time.scale, exec_time.maximum, exec_time.unit) == (est_time.scale, est_time.maximum, "us")
    assert exec_time.maximum == pytest.approx(cycles.maximum / (dbc.contract.M4_CLOCK_HZ / 1e6), abs=0.1)
    assert dbc.contract.M4_CLOCK_HZ == 90_000_000 and "at 90 MHz" in exec_time.comment
    assert "Cortex-M4" in timing4.comment and "C28x estimate of Timing2" in timing4.comment
    assert "Python model sends none" in timing4.comment
    network = DBC_PATH.read_text(encoding="ascii").split('CM_ "', 1)[1].split('";', 1)[0]
    assert "1.3.0 added Timing4" in network and "1.2.0 added StateCheckpoint" in network
    for name in ("FlashBytes", "RamBytes"):
        assert "measured from its ELF" in signal("TargetInfo", name).comment and "C28x estimate" in \
            signal("TargetInfo", name).comment


def test_version_1_4_adds_drive_currents_for_electrical_loss_models_and_says_so():
    """1.4.0: the d/q stator currents of a data row in a host message of their own, laid out like every host frame
    (CRC8, counter, Step, two 16-bit signals from bit 28), at the drive data's cycle; the history in the DBC's
    comment; the contract's row layout (`dbc.contract.row_signals`) names them after the four drive values."""
    assert dbc.dbc_version_info()[:2] >= (1, 4)
    currents = DB.get_message_by_name("DriveCurrents")
    assert currents.frame_id == 0x112 and currents.senders == ["HOST"] and currents.frame_id in dbc.host_frame_ids()
    assert [role_name(currents.name, s.name) for s in app_signals(currents)] == ["Step", "CurrentD", "CurrentQ"]
    for name, start in (("CurrentD", 28), ("CurrentQ", 44)):
        s = signal("DriveCurrents", name)
        assert (s.start, s.length, s.is_signed, s.scale, s.offset, s.minimum, s.maximum, s.unit) == \
            (start, 16, True, 0.1, 0, -3000, 3000, "A"), name
        assert "stator current" in s.comment
    assert currents.dbc.attributes["E2EDataID"].value == 0x12
    assert currents.cycle_time == DB.get_message_by_name("DriveInputs").cycle_time == 200
    assert "electrical loss model" in currents.comment and "ignores it" in currents.comment
    network = DBC_PATH.read_text(encoding="ascii").split('CM_ "', 1)[1].split('";', 1)[0]
    assert "1.4.0 added DriveCurrents" in network and "1.3.0 added Timing4" in network
    contract = dbc.contract
    assert contract.CURRENT_SIGNALS == (("DriveCurrents", "CurrentD"), ("DriveCurrents", "CurrentQ"))
    assert contract.row_signals(4) == contract.DRIVE_SIGNALS
    assert contract.row_signals(6) == contract.DRIVE_SIGNALS + contract.CURRENT_SIGNALS
    assert contract.row_messages(4) == ("DriveInputs", "DriveTemps")
    assert contract.row_messages(6) == ("DriveInputs", "DriveTemps", "DriveCurrents")
    with pytest.raises(ValueError, match="4 or 6 values, not 5"):
        contract.row_signals(5)


def test_version_1_5_names_every_signal_once_and_says_so():
    """1.5.0: no two messages share a signal name (canmatrix's ARXML export and asammdf look signals up by name
    alone); a shared role is `<Message>_<Role>` as the E2E signals are; the frames are 1.4.0's bit for bit, and the
    codec still calls the role by its short name (Step), the database layer keeping both."""
    assert dbc.dbc_version_info()[:2] >= (1, 5)
    names = [s.name for m in MESSAGES for s in m.signals]
    assert len(names) == len(set(names)), sorted({n for n in names if names.count(n) > 1})
    carriers = [m.name for m in MESSAGES if any(s.name == f"{m.name}_Step" for s in m.signals)]
    assert len(carriers) == 21 and "Status" not in carriers   # 15 in 1.5.0; 1.6.0: Timing5, 4 observer frames;
    # 1.7.0: DriveVoltages (the observer checkpoint's frames name their row by StepLow)
    for name in ("RestoreState", "StateCheckpoint"):
        layout = contract().by_name[name]
        assert [(s.name, s.dbc_name) for s in layout.signals] == [
            ("Step", f"{name}_Step"), ("StateIndex", f"{name}_StateIndex"), ("StateValue", f"{name}_StateValue")]
        assert [(s.start, s.length) for s in layout.signals] == [(12, 16), (28, 4), (32, 32)]
    network = DBC_PATH.read_text(encoding="ascii").split('CM_ "', 1)[1].split('";', 1)[0]
    assert "1.5.0 names every signal uniquely" in network and "1.4.0 added DriveCurrents" in network


def test_version_1_6_adds_timing5_the_response_time_beside_the_interrupt_and_says_so():
    """1.6.0: the firmware target with the motor-control interrupt sends the model step's response time (reception
    -> result, 0.1 µs at 90 MHz like Timing4's time) and the interrupt's CPU load per step, after Timing4."""
    assert dbc.dbc_version_info()[:2] >= (1, 6)
    timing5 = DB.get_message_by_name(dbc.contract.RESPONSE_TIMING_MESSAGE)
    assert timing5.frame_id == 0x226 and timing5.senders == ["TARGET"]
    assert [role_name(timing5.name, s.name) for s in app_signals(timing5)] == ["Step", "ResponseTime", "IsrLoad"]
    response, load = signal("Timing5", "ResponseTime"), signal("Timing5", "IsrLoad")
    assert (response.scale, response.unit, response.minimum) == (signal("Timing4", "M4ExecTime").scale, "us", 0)
    assert response.maximum > 100_000 and "at 90 MHz" in response.comment
    assert (load.scale, load.minimum, load.maximum, load.unit) == (0.01, 0, 100, "%")
    assert timing5.dbc.attributes["E2EDataID"].value == 0x26 and timing5.cycle_time == 200
    network = DBC_PATH.read_text(encoding="ascii").split('CM_ "', 1)[1].split('";', 1)[0]
    assert "1.6.0 added Timing5" in network and "1.5.0 names every signal uniquely" in network


def test_version_1_6_also_adds_the_observer_frames_and_one_history_names_both():
    """1.6.0 is one release: Timing5 and the observer's frames (Measurements from the host; Uncertainty1/2 and
    Innovations from the target) in the same version, its history naming both."""
    ids = {name: DB.get_message_by_name(name).frame_id
           for name in ("Measurements", "Uncertainty1", "Uncertainty2", "Innovations", "Timing5")}
    assert ids == {"Measurements": 0x113, "Uncertainty1": 0x240, "Uncertainty2": 0x241, "Innovations": 0x242,
                   "Timing5": 0x226}
    network = DBC_PATH.read_text(encoding="ascii").split('CM_ "', 1)[1].split('";', 1)[0]
    history = network.split("; 1.6.0 added Timing5", 1)[1].split("; 1.5.0", 1)[0]
    assert "Measurements" in history and "Innovations" in history
    assert network.count("1.6.0") == 2     # its own entry, and 1.7.0's "the frames of 1.6.0 unchanged"


def test_version_1_7_adds_the_voltages_and_the_observer_checkpoint_and_says_so():
    """1.7.0: DriveVoltages (host: the d/q voltages of a row with one status, for a target that computes the flux
    linkage itself) and the observer's checkpoint (ObserverCheckpoint from the target, RestoreObserver from the
    host: an 8-bit element index, the Step mod 4096 and an IEEE float value), new frames only."""
    assert dbc.dbc_version_info()[:2] >= (1, 7)
    voltages = contract().by_name["DriveVoltages"]
    assert (voltages.frame_id, voltages.sender, voltages.data_id, voltages.cycle_time_ms) == (0x114, "HOST", 0x14, 200)
    assert [(s.name, s.start, s.length) for s in voltages.signals] == [
        ("Step", 12, 16), ("VoltageD", 28, 16), ("VoltageQ", 44, 16), ("VoltageStatus", 60, 2)]
    assert signal("DriveVoltages", "VoltageD").scale == 0.01 and signal("DriveVoltages", "VoltageQ").unit == "V"
    for name, fid, sender, data_id in (("ObserverCheckpoint", 0x234, "TARGET", 0x34),
                                       ("RestoreObserver", 0x104, "HOST", 0x04)):
        layout = contract().by_name[name]
        assert (layout.frame_id, layout.sender, layout.data_id) == (fid, sender, data_id)
        assert [(s.name, s.start, s.length) for s in layout.signals] == [
            ("Index", 12, 8), ("StepLow", 20, 12), ("Value", 32, 32)]
        assert 1 << 12 == dbc.contract.CHECKPOINT_STEP_LOW_MODULO
    network = DBC_PATH.read_text(encoding="ascii").split('CM_ "', 1)[1].split('";', 1)[0]
    history = network.split("History: ", 1)[1].split("; 1.7.0 ", 1)[1]
    assert history.startswith("added DriveVoltages") and "ObserverCheckpoint" in history.split("; 1.6.0")[0]


def test_version_1_8_puts_the_observers_gate_in_free_bits_and_says_so():
    """1.8.0: the innovation gate on the bus, in bits 1.7.0 left free (the same ids, lengths and other signals, so
    a 1.7.0 log decodes with them 0): a Rejected flag per slot in Innovations (bits 62, 63, beside the Used flags),
    a Flagged flag per slot in Uncertainty1 (bits 60, 61); one signal each, named per slot as the contract names
    them; the history's newest entry says so."""
    assert dbc.dbc_version_info()[:2] >= (1, 8)
    innovations, flags = contract().by_name["Innovations"], contract().by_name[dbc.contract.FLAG_MESSAGE]
    assert [(s.name, s.start, s.length) for s in innovations.signals][-2:] == [
        ("SensorRejected", 62, 1), ("FluxMagnetRejected", 63, 1)]
    assert [(s.name, s.start, s.length) for s in flags.signals] == [
        ("Step", 12, 16), ("WindingSigma", 28, 16), ("MagnetSigma", 44, 16), ("SensorFlagged", 60, 1),
        ("FluxMagnetFlagged", 61, 1)]
    assert dict(dbc.contract.REJECTED_SIGNALS) == {"sensor": "SensorRejected", "flux": "FluxMagnetRejected"}
    assert dict(dbc.contract.FLAGGED_SIGNALS) == {"sensor": "SensorFlagged", "flux": "FluxMagnetFlagged"}
    slots = set(dbc.contract.MEASUREMENT_SLOTS)
    assert set(dbc.contract.REJECTED_SIGNALS) == slots == set(dbc.contract.FLAGGED_SIGNALS)
    for message, last in ((innovations, 63), (flags, 61)):      # every bit at most once, within the 8 bytes
        bits = [b for s in message.signals for b in range(s.start, s.start + s.length)]
        assert len(bits) == len(set(bits)) and max(bits) == last
    network = DBC_PATH.read_text(encoding="ascii").split('CM_ "', 1)[1].split('";', 1)[0]
    history = network.split("History: ", 1)[1]
    assert history.startswith("1.8.0 added the observer's innovation gate") and "1.7.0 added DriveVoltages" in history
