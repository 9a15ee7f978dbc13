"""The observer as the CAN node runs it: which Measurements slot feeds it, one model step with the row's measurement,
and what the node reports after the step (each node's 1-sigma, the innovation).

The filter itself is `target_sim.observer.Float32Observer`, called through its per-step interface (the interval
mean of a measurement, NaN: predict only). The node's rules around it:

* what CAN carries: the host sends one temperature per slot, so the node runs an observer whose measurements are
  exactly one with one raw channel (a lagged sensor, section version 1 or 2; the value is its z). An observer that
  reads the flux linkage from its raw channels (u_d, u_q, i_d, i_q) or more than one measurement has no frame to
  carry its readings: `can_refusal` says so in one sentence, and the bench and the target refuse it before any work
  rather than run it wrongly;
* slot: the artifact's observer reads one slot of the Measurements frame (`dbc.contract.MEASUREMENT_SLOTS`): the
  section's `source` when it names one, else `flux` for a filter that measures the magnet (only the flux linkage
  sees the magnet in a running machine) and `sensor` for any other node (a winding sensor, a stator NTC);
* reset: the model's RESET and a fresh covariance P0;
* restore: a StateCheckpoint carries the state vector x only, so a restored target continues from that x bit for bit
  with the covariance of a fresh start, P0 (it knows as little as at key-on); the offline reference restarts the same
  way (`bench.analysis.canmetrics.segment_estimates`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dbc.contract import INNOVATION_MESSAGE, INNOVATION_SIGNALS, MEASUREMENT_SLOTS, SIGMA_SIGNALS
from target_sim.artifact import ModelArtifact
from target_sim.observer import Float32Observer, ObserverError, has_observer, measurement_entries


def can_refusal(artifact: ModelArtifact) -> str | None:
    """Why the artifact's observer cannot run over CAN (one sentence), None when it can or has no observer: the
    Measurements frame carries one temperature per slot, so exactly one measurement of one raw channel."""
    if not has_observer(artifact):
        return None
    entries = measurement_entries(artifact.content["observer"])
    name = f"model {artifact.model_id:08x}" + (f" ({artifact.path})" if artifact.path is not None else "")
    if len(entries) == 1 and len(entries[0]["columns"]) == 1:
        return None
    what = (f"{len(entries)} measurements" if len(entries) != 1
            else f"a {entries[0]['kind']} measurement of {len(entries[0]['columns'])} raw channels")
    return (f"{name} has an observer with {what}, and the Measurements frame carries one temperature per slot "
            "(one lagged sensor): use an observer with one temperature sensor, or run it offline with 'bench "
            "evaluate'")


def measured_column(artifact: ModelArtifact) -> str | None:
    """The dataset column the artifact's observer reads over CAN, None without an observer (ObserverError when CAN
    cannot carry it, `can_refusal`)."""
    if not has_observer(artifact):
        return None
    refusal = can_refusal(artifact)
    if refusal is not None:
        raise ObserverError(refusal)
    return measurement_entries(artifact.content["observer"])[0]["columns"][0]


def observer_slot(artifact: ModelArtifact) -> str | None:
    """The Measurements slot the artifact's observer reads, None without an observer (ObserverError when CAN cannot
    carry it, `can_refusal`)."""
    if measured_column(artifact) is None:
        return None
    section = artifact.content["observer"]
    source = section.get("source")
    if source in MEASUREMENT_SLOTS:
        return source
    return "flux" if section.get("node") == "magnet" else "sensor"


class NodeObserver:
    """The artifact's float32 observer with the node's reset, restore and step (see the module docstring)."""

    def __init__(self, artifact: ModelArtifact):
        self.filter = Float32Observer(artifact)
        self.model = self.filter.est          # the estimator the filter corrects: x, y, checkpoints
        self.slot = observer_slot(artifact)
        self.slot_index = MEASUREMENT_SLOTS.index(self.slot)
        self.width = len(artifact.drive_signals)   # the drive values before the measurement in a row

    def reset(self, temperatures: Sequence[float]) -> None:
        self.filter.reset(temperatures)

    def restore(self, state: Sequence[float]) -> None:
        """x bit for bit from a checkpoint, the covariance P0 of a fresh start."""
        self.filter.reset(np.zeros(len(state)))
        self.model.restore(state)

    def step(self, inputs: Sequence) -> np.ndarray:
        """One model step on a row's interval mean: the drive values, then the measurement (NaN: predict only)."""
        width = self.width
        return self.filter.step(*inputs[:width], z=inputs[width])

    def sigma(self) -> np.ndarray:
        """Each node's 1-sigma after the last step, in the temperature order (yoke, winding, tooth, magnet)."""
        return self.filter.sigma()

    def innovation(self) -> float:
        """The last step's innovation, NaN when it predicted only."""
        return float(self.filter.innovation)


def observer_signals(sigma: Sequence[float], innovation: float, slot: str,
                     sigma_limits: tuple[float, float], innovation_limits: tuple[float, float]) -> dict[str, dict]:
    """{message: {signal: value}} of Uncertainty1, Uncertainty2 and Innovations (without Step), values clamped to
    what the DBC carries (a non-finite sigma as its largest value)."""
    out: dict[str, dict] = {}
    for message, signals in SIGMA_SIGNALS.items():
        out[message] = {signal: _clamp(float(sigma[index]), sigma_limits) for signal, index in signals}
    innovations = {}
    for name, (value_signal, used_signal) in INNOVATION_SIGNALS.items():
        used = name == slot and np.isfinite(innovation)
        innovations[value_signal] = _clamp(innovation, innovation_limits) if used else 0.0
        innovations[used_signal] = int(used)
    out[INNOVATION_MESSAGE] = innovations
    return out


def _clamp(value: float, limits: tuple[float, float]) -> float:
    if not np.isfinite(value):
        return limits[1] if not value < 0 else limits[0]
    return min(max(value, limits[0]), limits[1])
