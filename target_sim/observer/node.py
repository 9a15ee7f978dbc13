"""The observer as the CAN node runs it: where each of its raw channels comes from in a row's frames, one model step
with the row's measurements, what the node reports after the step (each node's 1-sigma, each measurement's
innovation) and its checkpoint.

The filter itself is `target_sim.observer.Float32Observer`, called through its per-step interface (the interval
means of its raw channels; NaN in a measurement's channels: no update with it). The node's rules around it:

* what CAN carries (`dbc.contract.MEASUREMENT_CHANNELS`, `ROW_CHANNELS`): a lagged sensor's one channel is a slot of
  the Measurements frame; the flux linkage's u_d, u_q travel in DriveVoltages (DBC 1.7.0) and its i_d, i_q are the
  row's own DriveCurrents, so the target computes the flux magnet temperature itself with its own winding estimate
  (R_s(ϑ̂_w)), as an inverter would. An observer whose model does not take the currents in its rows (loss maps), or
  whose two measurements would share one slot, has no frames to carry its readings: `can_refusal` says so in one
  sentence, and the bench and the target refuse it before any work rather than run it wrongly;
* slot: each measurement answers in one slot of Innovations (`dbc.contract.MEASUREMENT_SLOTS`): a kind that computes
  its reading from raw channels by the node it reads (the flux linkage's magnet in `flux`, the winding resistance's
  winding in `sensor`); a lagged sensor in its section's `source` (version 1) when it names one, else `flux` when it
  sees the magnet only (a magnet temperature from elsewhere) and `sensor` for any other node (a winding sensor, a
  stator NTC);
* reset: the model's RESET and a fresh covariance P0;
* restore: a StateCheckpoint carries the state vector x, an ObserverCheckpoint (DBC 1.7.0) the filter's extra states
  and covariance (`Float32Observer.checkpoint`); with both the restored filter continues bit for bit, with x alone it
  starts its covariance again at P0 (it knows as little as at key-on); the offline reference restarts the same way
  (`bench.analysis.canmetrics.segment_estimates`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from dbc.contract import (
    CHANNEL_NAMES,
    FLAG_MESSAGE,
    FLAGGED_SIGNALS,
    INNOVATION_MESSAGE,
    INNOVATION_SIGNALS,
    MEASUREMENT_CHANNELS,
    MEASUREMENT_SLOTS,
    REJECTED_SIGNALS,
    ROW_CHANNELS,
    SIGMA_SIGNALS,
    measurement_messages,
)
from target_sim.artifact import ModelArtifact
from target_sim.losses import reads_currents
from target_sim.observer.filter import Float32Observer
from target_sim.observer.measurements import MEASUREMENT_KINDS
from target_sim.observer.section import ObserverError, has_observer, load_measurements, measurement_entries


def _reads_temperature(entry: dict) -> bool:
    """Whether the entry's kind reads one temperature channel (a Measurements slot) rather than raw CAN channels."""
    return MEASUREMENT_KINDS[entry["kind"]].temperature_channel


def _slot(entry: dict, section: dict) -> str:
    """The Innovations slot of one measurement entry (see the module docstring)."""
    node = entry.get("node", section.get("node"))
    if not _reads_temperature(entry):
        return "flux" if node == "magnet" else "sensor"
    source = section.get("source")
    if source in MEASUREMENT_SLOTS:
        return source
    gradient = float(entry.get("gradient", 0.0) or 0.0)
    return "flux" if node == "magnet" and gradient == 0.0 else "sensor"


def measurement_slots(artifact: ModelArtifact) -> list[str]:
    """Each measurement's Innovations slot, in the observer's order ([] without an observer)."""
    if not has_observer(artifact):
        return []
    section = artifact.content["observer"]
    return [_slot(entry, section) for entry in measurement_entries(section)]


def _entry_channels(entry: dict, slot: str, measurement) -> tuple[str, ...]:
    """The CAN channels of one measurement's raw channels: a sensor's slot, or the kind's own (the flux linkage)."""
    return (slot,) if _reads_temperature(entry) else tuple(measurement.can_channels)


def can_refusal(artifact: ModelArtifact) -> str | None:
    """Why the artifact's observer cannot run over CAN (one sentence), None when it can or has no observer."""
    if not has_observer(artifact):
        return None
    section = artifact.content["observer"]
    entries = measurement_entries(section)
    slots = measurement_slots(artifact)
    name = f"model {artifact.model_id:08x}" + (f" ({artifact.path})" if artifact.path is not None else "")
    shared = [slot for slot in MEASUREMENT_SLOTS if slots.count(slot) > 1]
    if shared:
        return (f"{name} has an observer whose measurements {', '.join(e['name'] for e in entries)} would all "
                f"answer in the {shared[0]} slot, and the Measurements and Innovations frames carry one temperature "
                "per slot; keep one measurement per slot, or run it offline with 'bench evaluate'")
    row_read = {c for e, m, s in zip(entries, load_measurements(section), slots, strict=True)
                for c in _entry_channels(e, s, m) if c in ROW_CHANNELS and ROW_CHANNELS[c] >= 4}
    if row_read and not reads_currents(artifact.drive_signals):
        return (f"{name} has an observer that measures the flux linkage from the d/q currents, and its "
                f"{artifact.loss_model} loss model does not take the currents in its rows (no DriveCurrents frames); "
                "use a model with an electrical loss model, or run it offline with 'bench evaluate'")
    return None


def _row_readers(entries: Sequence[dict]) -> str:
    """The names of the measurements that read the row's currents ("the flux linkage"), for a refusal."""
    return " and ".join(f"the {MEASUREMENT_KINDS[e['kind']].name.replace('-', ' ')}" for e in entries
                        if not _reads_temperature(e))


def _check(artifact: ModelArtifact) -> None:
    refusal = can_refusal(artifact)
    if refusal is not None:
        raise ObserverError(refusal)


def measured_columns(artifact: ModelArtifact) -> dict[str, str]:
    """{host channel: dataset column} the host sends for the artifact's observer ({} without one; ObserverError
    when CAN cannot carry it, `can_refusal`); the row's own channels (currents) are not among them."""
    if not has_observer(artifact):
        return {}
    _check(artifact)
    section = artifact.content["observer"]
    out: dict[str, str] = {}
    for entry, measurement, slot in zip(measurement_entries(section), load_measurements(section),
                                        measurement_slots(artifact), strict=True):
        for channel, column in zip(_entry_channels(entry, slot, measurement), entry["columns"], strict=True):
            if channel in MEASUREMENT_CHANNELS:
                out[channel] = column
    return out


def measurement_width(artifact: ModelArtifact) -> int:
    """Columns of the host's measurement matrix for the artifact (0 without an observer): the Measurements slots,
    and the voltages too when its observer reads them (`dbc.contract.measurement_messages`)."""
    channels = measured_columns(artifact)
    if not has_observer(artifact):
        return 0
    return max(len(MEASUREMENT_SLOTS), *(CHANNEL_NAMES.index(c) + 1 for c in channels)) if channels \
        else len(MEASUREMENT_SLOTS)


def raw_sources(artifact: ModelArtifact) -> list[tuple[str, int]]:
    """Where each raw channel of the observer comes from, in the filter's order: ("channel", index into the host's
    measurement matrix) or ("row", index into the row's values)."""
    _check(artifact)
    section = artifact.content["observer"]
    out = []
    for entry, measurement, slot in zip(measurement_entries(section), load_measurements(section),
                                        measurement_slots(artifact), strict=True):
        for channel in _entry_channels(entry, slot, measurement):
            out.append(("channel", CHANNEL_NAMES.index(channel)) if channel in MEASUREMENT_CHANNELS
                       else ("row", ROW_CHANNELS[channel]))
    return out


def channel_widths(artifact: ModelArtifact) -> list[int]:
    """How many raw channels each measurement of the observer takes, in order."""
    return [m.width for m in load_measurements(artifact.content["observer"])]


def raw_channels(sources: Sequence[tuple[str, int]], rows: np.ndarray, measured: np.ndarray | None) -> np.ndarray:
    """(n, channels) the observer's raw channels per row from the row values (n, width) and the host's measurement
    matrix (n, columns) (None or a missing column: NaN)."""
    out = np.full((len(rows), len(sources)), np.nan)
    for i, (where, index) in enumerate(sources):
        if where == "row":
            out[:, i] = rows[:, index]
        elif measured is not None and index < measured.shape[1]:
            out[:, i] = measured[:, index]
    return out


class NodeObserver:
    """The artifact's float32 observer with the node's reset, restore and step (see the module docstring)."""

    def __init__(self, artifact: ModelArtifact):
        self.filter = Float32Observer(artifact)
        self.model = self.filter.est          # the estimator the filter corrects: x, y, checkpoints
        self.slots = measurement_slots(artifact)
        self.sources = raw_sources(artifact)
        self.width = len(artifact.drive_signals)   # the drive values before the measurements in a row
        self.messages = measurement_messages(measurement_width(artifact))   # the measurement frames it reads
        self.channels = len(self.sources)

    def raw(self, row_values: Sequence[float], measured: Sequence[float]) -> tuple[float, ...]:
        """The raw channels of one row: from its values and its measurement channels (NaN: none)."""
        return tuple(float(row_values[i]) if where == "row" else float(measured[i]) for where, i in self.sources)

    def reset(self, temperatures: Sequence[float]) -> None:
        self.filter.reset(temperatures)

    def restore(self, state: Sequence[float], elements: Mapping[int, float] | None = None) -> None:
        """x bit for bit from a checkpoint; the filter's extra states and covariance from its ObserverCheckpoint
        elements {Index: value} when every one came (bit for bit), else the covariance P0 of a fresh start and the
        lag states at what their sensors see of x."""
        self.filter.reset(np.zeros(len(state)))
        self.model.restore(state)
        size = self.filter.checkpoint_size()
        if elements is not None and all(i in elements for i in range(size)):
            self.filter.restore_checkpoint([elements[i] for i in range(size)])
        else:
            self.filter.reset_lags()

    def checkpoint(self) -> np.ndarray:
        return self.filter.checkpoint()

    def step(self, inputs: Sequence) -> np.ndarray:
        """One model step on a row's interval mean: the drive values, then the raw channels (NaN: no update)."""
        width = self.width
        return self.filter.step(*inputs[:width], z=np.asarray(inputs[width:], dtype=self.filter.f))

    def sigma(self) -> np.ndarray:
        """Each node's 1-sigma after the last step, in the temperature order (yoke, winding, tooth, magnet)."""
        return self.filter.sigma()

    def innovations(self) -> dict[str, float]:
        """{slot: innovation} of the last step, NaN where a measurement was not used."""
        return {slot: float(value) for slot, value in zip(self.slots, self.filter.innovations, strict=True)}

    def gate_status(self) -> dict[str, tuple[bool, bool]]:
        """{slot: (its reading rejected by the innovation gate in the last step, its sensor flagged)}; both False
        without a gate."""
        f = self.filter
        return {slot: (bool(f.gate.rejected[i]), bool(f.gate.flagged[i])) for i, slot in enumerate(self.slots)}


def observer_signals(sigma: Sequence[float], innovations: dict[str, float],
                     sigma_limits: tuple[float, float], innovation_limits: tuple[float, float],
                     gate: Mapping[str, tuple[bool, bool]] | None = None) -> dict[str, dict]:
    """{message: {signal: value}} of Uncertainty1, Uncertainty2 and Innovations (without Step), values clamped to
    what the DBC carries (a non-finite sigma as its largest value); `gate` {slot: (rejected, flagged)}
    (`NodeObserver.gate_status`; a slot without it: 0, 0)."""
    out: dict[str, dict] = {}
    for message, signals in SIGMA_SIGNALS.items():
        out[message] = {signal: _clamp(float(sigma[index]), sigma_limits) for signal, index in signals}
    gate = gate or {}
    out[FLAG_MESSAGE].update({signal: int(gate.get(slot, (False, False))[1])
                              for slot, signal in FLAGGED_SIGNALS.items()})
    values = {}
    for name, (value_signal, used_signal) in INNOVATION_SIGNALS.items():
        innovation = innovations.get(name, float("nan"))
        used = bool(np.isfinite(innovation))
        values[value_signal] = _clamp(innovation, innovation_limits) if used else 0.0
        values[used_signal] = int(used)
        values[REJECTED_SIGNALS[name]] = int(gate.get(name, (False, False))[0])
    out[INNOVATION_MESSAGE] = values
    return out


def _clamp(value: float, limits: tuple[float, float]) -> float:
    if not np.isfinite(value):
        return limits[1] if not value < 0 else limits[0]
    return min(max(value, limits[0]), limits[1])
