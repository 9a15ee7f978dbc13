"""`dbc.contract`'s facts against the DBC they describe, and a package that reads no file when imported."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from dbc import contract as c
from dbc.database import contract, heartbeat_period_s, signal_ranges, temperature_range


def _signals(name: str) -> set[str]:
    return set(contract().by_name[name].signal_names)


def test_reply_and_reset_layouts_name_every_temperature_once():
    for layout, extra in ((c.REPLY_SIGNALS, {"Step"}), (c.RESET_SIGNALS, {"Step"})):
        indices = sorted(index for signals in layout.values() for _, index in signals)
        assert indices == list(range(c.STATE_SIZE)) == list(range(len(c.TEMPERATURE_NODES)))
        for message, signals in layout.items():
            assert _signals(message) == {name for name, _ in signals} | extra
    assert c.REPLY_MESSAGES == ("Temperatures1", "Temperatures2")
    assert c.REPLY_COMPLETE == 3 and sorted(c.REPLY_BIT.values()) == [1, 2]


def test_temperatures_round_trip_through_the_layout():
    values = [40.0, 100.5, 60.25, 55.0]   # yoke, winding, tooth, magnet
    for layout in (c.REPLY_SIGNALS, c.RESET_SIGNALS):
        frames = c.split_temperatures(values, layout)
        assert c.join_temperatures(frames, layout) == values
    out = np.full(4, np.nan)
    bits = sum(c.place_temperatures(m, s, out) for m, s in c.split_temperatures(values).items())
    assert bits == c.REPLY_COMPLETE and out.tolist() == values
    assert c.split_temperatures(values)["Temperatures1"] == {"WindingTemp": 100.5, "MagnetTemp": 55.0}


def test_every_temperature_signal_shares_the_one_range():
    for layout in (c.REPLY_SIGNALS,):
        for message, signals in layout.items():
            for name, _ in signals:
                assert signal_ranges(message)[name] == temperature_range()


def test_step_arithmetic_matches_the_step_signal():
    step = contract().by_name["DriveInputs"].signal("Step")
    assert c.STEP_MODULO == 1 << step.length == step.maximum + 1
    assert c.step_of(65537) == 1
    assert c.nearest_row(1, 65535) == 65537 and c.nearest_row(65535, 1) == -1
    assert c.latest_row(3, 70000) == 65539 and c.latest_row(70000 % 65536, 70000) == 70000


def test_rx_error_signals_are_the_rxerrors_message():
    assert set(c.RX_ERROR_SIGNALS.values()) == _signals("RxErrors")
    assert tuple(c.RX_ERROR_SIGNALS) == c.RX_ERROR_KINDS
    assert c.rx_error_counts({"CrcError": 2, "SequenceError": 1}) == {"crc": 2, "sequence": 1}


def test_drive_signals_and_heartbeat_timing():
    for message, signal in c.DRIVE_SIGNALS:
        assert signal in _signals(message)
    assert heartbeat_period_s() == 0.1                       # Status' GenMsgCycleTime
    assert c.HEARTBEAT_TIMEOUT_S == 5 * heartbeat_period_s()


def test_importing_the_layers_reads_no_dbc():
    code = ("import dbc, dbc.contract, dbc.codec, dbc.mutations, dbc.transport, target_sim.node, host.procedure, "
            "bench.cli, bench.commands.run; from dbc.database import contract; "
            "print(contract.cache_info().currsize)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "0"


def test_the_drive_sample_period_is_the_row_messages_cycle_time():
    from dbc.contract import DRIVE_SAMPLE_PERIOD_S, row_messages
    from dbc.database import contract

    for message in row_messages(6):
        assert contract().by_name[message].cycle_time_ms / 1000.0 == DRIVE_SAMPLE_PERIOD_S


def test_the_messages_whose_step_is_their_data_row():
    from dbc.database import row_step_messages

    assert row_step_messages() == ("DriveInputs", "DriveTemps", "DriveCurrents", "Measurements", "DriveVoltages",
                                   "Temperatures1",
                                   "Temperatures2", "Timing1", "Timing2", "Timing3", "Timing4", "Timing5",
                                   "StateCheckpoint", "Uncertainty1", "Uncertainty2", "Innovations")
