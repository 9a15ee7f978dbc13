"""An XCP DAQ recording into an MF4 (ASAM MDF 4), as a calibration tool keeps one: pyxcp configures the DAQ list,
python-can hears its packets, asammdf writes them (public APIs only; asammdf is the `mf4` extra).

    channels = daq_channels(artifact, ["y_est_0", "y_est_1", "y_est_2", "y_est_3", "obs_sigma_1", "obs_extra_0"])
    first_pid = configure_daq(xcp, channels)            # a connected pyxcp Master; the model step's event
    recorder = DaqRecorder(first_pid, len(channels))    # a can.Listener: give it to a can.Notifier on the bus
    xcp.startStopSynch(0x01)                            # ... the run ...; then xcp.startStopSynch(0x00)
    write_daq_mf4(Path("daq.mf4"), channels, recorder.samples())

One ODT per channel (a float32 of the A2L's MEASUREMENT: 5 bytes of the 8 a CAN DTO holds with its PID), so a
sample of N channels is N packets with the absolute ODT numbers first_pid ... first_pid + N - 1, sent in that order
after each model step. The slave sends no time stamp (it refuses time-stamped DAQ), so a sample's time is the
master's receive time of its first packet; the MF4's header states the recording's first sample, and its time
channel counts from it. A packet lost on the bus leaves its value NaN in its sample, and `DaqSamples.lost` counts it.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import can
import numpy as np

from bench.errors import BenchError
from bench.fileio import write_bytes_atomically
from dbc.xcp import res_id
from target_sim.artifact import ModelArtifact
from target_sim.xcp.daq import EVENT_MODEL_STEP, EVENTS

FLOAT32_SIZE = 4
FIRST_CTO_PID = 0xFC     # PIDs from here up are replies, errors, events and service requests, not DAQ packets
DIRECT_ADDRESS = 0xFF    # WRITE_DAQ's bit offset 0xFF: the whole element, no bit mask


@dataclass(frozen=True)
class DaqChannel:
    """One measurement of the A2L recorded by DAQ: its name, address, unit and comment."""

    name: str
    address: int
    unit: str = ""
    comment: str = ""


def daq_channels(artifact: ModelArtifact, names: Sequence[str], elf: str | Path | None = None) -> list[DaqChannel]:
    """The measurements `names` of `artifact`'s target, at the addresses its A2L gives them (`bench firmware a2l`,
    with `elf` as its --elf); BenchError naming the known ones for a name the target does not have."""
    from target_sim.node import TargetNode

    cells = TargetNode(artifact, xcp_elf=elf).xcp.memory.by_name
    unknown = [name for name in names if name not in cells]
    if unknown:
        raise BenchError(f"the target of this model has no measurement {', '.join(unknown)}; its measurements are "
                         f"{', '.join(name for name in cells if not name.startswith('cal_'))}")
    return [DaqChannel(name, cells[name].address, cells[name].unit, cells[name].comment) for name in names]


def configure_daq(xcp, channels: Sequence[DaqChannel], event: int = EVENT_MODEL_STEP) -> int:
    """Set up and select (not start) DAQ list 0 of the connected pyxcp master `xcp`: one ODT per channel on
    `event`; start it with `xcp.startStopSynch(0x01)`. Returns the list's first PID (START_STOP_DAQ_LIST's reply)."""
    xcp.freeDaq()
    xcp.allocDaq(1)
    xcp.allocOdt(0, len(channels))
    for odt in range(len(channels)):
        xcp.allocOdtEntry(0, odt, 1)
    for odt, channel in enumerate(channels):
        xcp.setDaqPtr(0, odt, 0)
        xcp.writeDaq(DIRECT_ADDRESS, FLOAT32_SIZE, 0, channel.address)
    xcp.setDaqListMode(0x00, 0, event, 1, 0)      # mode 0: DAQ, no time stamp; prescaler 1, priority 0
    return xcp.startStopDaqList(0x02, 0).firstPid  # 2: select, for START_STOP_SYNCH


@dataclass(frozen=True)
class DaqSamples:
    """A DAQ recording: `times` (s since the epoch, one per sample), `values` (samples x channels, float32, NaN
    where a packet was lost) and `lost`, the packets missing."""

    times: np.ndarray
    values: np.ndarray
    lost: int


class DaqRecorder(can.Listener):
    """Keeps each DAQ packet of the list whose PIDs are first_pid ... first_pid + count - 1, with its receive time
    (the slave's response id; its command replies and error packets are not DAQ packets)."""

    def __init__(self, first_pid: int, count: int, arbitration_id: int | None = None) -> None:
        self.first_pid, self.count = first_pid, count
        self.arbitration_id = res_id() if arbitration_id is None else arbitration_id
        self.packets: list[tuple[float, bytes]] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id != self.arbitration_id or msg.is_extended_id or not msg.data:
            return
        pid = msg.data[0]
        if pid < FIRST_CTO_PID and 0 <= pid - self.first_pid < self.count:
            self.packets.append((msg.timestamp, bytes(msg.data)))

    def samples(self) -> DaqSamples:
        """The packets as samples: a sample starts with its first ODT, or with an ODT not after the last one heard
        (its first was lost)."""
        times: list[float] = []
        rows: list[list[float]] = []
        last = self.count
        for stamp, data in self.packets:
            odt = data[0] - self.first_pid
            if odt == 0 or odt <= last:
                times.append(stamp)
                rows.append([np.nan] * self.count)
            rows[-1][odt] = float(np.frombuffer(data, "<f4", count=1, offset=1)[0])
            last = odt
        values = np.array(rows, dtype=np.float32).reshape(len(rows), self.count)
        return DaqSamples(np.array(times, dtype=np.float64), values,
                          lost=len(rows) * self.count - len(self.packets))


def write_daq_mf4(path: Path, channels: Sequence[DaqChannel], samples: DaqSamples, event: int = EVENT_MODEL_STEP,
                  ) -> Path:
    """Write `samples` to the .mf4 `path` (atomically): one channel group, a float32 channel per DAQ channel with
    its unit and comment, its time channel counting from the header's start (the first sample's time)."""
    from asammdf import MDF, Signal

    start = float(samples.times[0]) if len(samples.times) else datetime.now(UTC).timestamp()
    mdf = MDF(version="4.10")
    try:
        mdf.header.start_time = datetime.fromtimestamp(start, UTC)
        offsets = samples.times - start
        mdf.append([Signal(samples=samples.values[:, i], timestamps=offsets, name=channel.name, unit=channel.unit,
                           comment=channel.comment) for i, channel in enumerate(channels)],
                   comment=f"XCP DAQ list 0 on the {EVENTS[event]} event, {samples.lost} packet(s) lost")
        buffer = io.BytesIO()
        mdf.save(buffer, compression=2)
    finally:
        mdf.close()
    write_bytes_atomically(path, buffer.getvalue(), "the DAQ recording")
    return path
