"""The observer's figures of a run (`bench.analysis.results.ObserverResults`): from the target's observer frames in
the log (each node's 1-sigma, the innovations, the innovation gate's Rejected and Flagged flags) and the offline
references (open loop beside observer).

The gate (DBC 1.8.0) is read from the bus and cross-checked against the target's own float32 code offline: at every
model step of the run's first segment where the CAN estimate is that code's (within the quantization), the step's
Rejected flag and the Flagged flag after it must be the code's; a step where they differ is counted
(`SlotFigures.gate_steps_differing`, a problem of the run). A log of a target built against an older DBC carries no
gate flags: its figures are the offline code's, and the cross-check is not made."""

from __future__ import annotations

import numpy as np

from bench.analysis.logdecode import BusRecord
from bench.analysis.results import NodeValues, ObserverResults, SlotFigures
from bench.analysis.verdict import QUANTIZATION_C
from dbc.contract import TEMPERATURE_NODES
from target_sim.artifact import ModelArtifact
from target_sim.observer import measurement_entries
from target_sim.observer.node import channel_widths, measurement_slots, raw_channels, raw_sources

# the sigma series of the log per node (`BusRecord.observer`), in the temperature order
SIGMA_KEYS = {"yoke": ("row_u2", "yoke_sigma"), "winding": ("row_u1", "winding_sigma"),
              "tooth": ("row_u2", "tooth_sigma"), "magnet": ("row_u1", "magnet_sigma")}
GATE_ON_BUS_DBC = (1, 8)      # the first DBC whose Innovations and Uncertainty1 carry the gate's flags


def _last_by_row(record: BusRecord, row_key: str, key: str) -> dict[int, float]:
    """{row: value} of a per-step series of the log, the last frame of each row (a step sent again: its last)."""
    at, values = record.observer.get(row_key), record.observer.get(key)
    if at is None or values is None or not len(at):
        return {}
    return {int(r): v for r, v in zip(at.tolist(), values.tolist(), strict=True)}


def comparable_steps(record: BusRecord, refs) -> np.ndarray:
    """(steps,) the model steps whose CAN estimate is the offline float32 code's (within the quantization) in the
    run's first segment: there the target's gate must be that code's too."""
    steps = len(refs.step_rows)
    if refs.can is None or not steps:
        return np.zeros(steps, dtype=bool)
    rows = np.asarray(refs.step_rows, dtype=np.int64)
    with np.errstate(invalid="ignore"):
        same = (np.abs(refs.can - refs.f32) <= QUANTIZATION_C + 1e-9).all(axis=1)
    owner = record.owner if len(record.owner) == record.rows else np.zeros(record.rows, dtype=np.int64)
    first = np.zeros(steps, dtype=bool)
    inside = rows < record.rows
    first[inside] = owner[rows[inside]] == 0
    return same & first


def _gate_check(record: BusRecord, refs, slot: str, index: int, compare: np.ndarray) -> tuple[int, int]:
    """(steps compared, steps whose Rejected flag or Flagged flag on the bus differs from the offline code's)."""
    rejected = _last_by_row(record, "row_inn", f"{slot}_rejected")
    flagged = _last_by_row(record, "row_u1", f"{slot}_flagged")
    compared = differing = 0
    for k in np.flatnonzero(compare):
        row = int(refs.step_rows[k])
        if row not in rejected or row not in flagged:
            continue
        compared += 1
        offline = (bool(refs.rejected[k, index]), bool(refs.flagged_steps[k, index]))
        differing += (bool(rejected[row]), bool(flagged[row])) != offline
    return compared, differing


def sigma_at(record: BusRecord, rows: np.ndarray) -> np.ndarray:
    """(len(rows), 4) each node's 1-sigma the target reported for the model step of each row (NaN: none)."""
    out = np.full((len(rows), len(TEMPERATURE_NODES)), np.nan)
    for i, node in enumerate(TEMPERATURE_NODES):
        row_key, key = SIGMA_KEYS[node]
        at, values = record.observer.get(row_key), record.observer.get(key)
        if at is None or not len(at):
            continue
        last = {int(r): v for r, v in zip(at.tolist(), values.tolist(), strict=True)}   # a step sent again: its last
        out[:, i] = [last.get(int(r), np.nan) for r in rows]
    return out


def _rmse(a: np.ndarray, b: np.ndarray | None) -> float | None:
    if b is None:
        return None
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2))) if ok.any() else None


def observer_results(record: BusRecord, artifact: ModelArtifact, refs) -> ObserverResults | None:
    """The run's observer figures; None for a model without an observer."""
    slots = measurement_slots(artifact)
    if not slots:
        return None
    obs = record.observer
    sigma = np.column_stack([obs.get(SIGMA_KEYS[n][1], np.zeros(0)) for n in TEMPERATURE_NODES]) \
        if all(len(obs.get(SIGMA_KEYS[n][1], ())) for n in TEMPERATURE_NODES) else np.zeros((0, 4))
    measured = {"winding": refs.measured_winding, "magnet": refs.measured_pm}
    channels = observed_rows(record, artifact)
    section = artifact.content["observer"]
    steps = len(obs.get("row_inn", ()))
    # the gate's flags are on the bus from DBC 1.8.0 on (a log without a Status: the current contract's target)
    on_bus = record.target_dbc is None or record.target_dbc >= GATE_ON_BUS_DBC
    compare = comparable_steps(record, refs) if on_bus else None
    per_slot, used_by, rows_by = {}, [np.zeros(steps, dtype=bool)], [np.zeros(record.rows, dtype=bool)]
    for index, (slot, entry) in enumerate(zip(slots, measurement_entries(section), strict=True)):
        used = obs.get(f"{slot}_used", np.zeros(steps)) > 0
        innovation = obs.get(f"{slot}_innovation", np.zeros(steps))[used]
        rows = channels[index] if channels else np.zeros(record.rows, dtype=bool)
        used_by.append(used)
        rows_by.append(rows)
        rejected = getattr(refs, "rejected", None)
        flagged = getattr(refs, "flagged", None)
        offline_rejected = 0 if rejected is None else int(np.count_nonzero(rejected[:, index]))
        offline_flagged = bool(flagged is not None and flagged[index])
        if on_bus:
            bus_rejected = int(np.count_nonzero(obs.get(f"{slot}_rejected", np.zeros(0)) > 0))
            bus_flagged = bool(np.any(obs.get(f"{slot}_flagged", np.zeros(0)) > 0))
            compared, differing = (0, 0) if rejected is None or refs.flagged_steps is None else \
                _gate_check(record, refs, slot, index, compare)
        else:
            bus_rejected, bus_flagged, compared, differing = offline_rejected, offline_flagged, 0, 0
        per_slot[slot] = SlotFigures(
            measured_node="magnet" if slot == "flux" else entry.get("node", section.get("node")),
            rows_measured=int(np.count_nonzero(rows)), model_steps_updated=int(np.count_nonzero(used)),
            innovation_rms_C=float(np.sqrt(np.mean(innovation ** 2))) if innovation.size else None,
            readings_rejected=bus_rejected, sensor_flagged=bus_flagged,
            sensor=", ".join(entry.get("columns", [])) or str(entry.get("name", section.get("column", slot))),
            gate_source="bus" if on_bus else "offline float32",
            readings_rejected_float32=offline_rejected, sensor_flagged_float32=offline_flagged,
            gate_steps_compared=compared, gate_steps_differing=differing)

    def per_node(trajectory: np.ndarray | None) -> NodeValues:
        if trajectory is None:
            return NodeValues()
        return NodeValues(**{n: _rmse(trajectory[:, i], measured.get(n)) for i, n in enumerate(TEMPERATURE_NODES)})

    last = sigma[-1] if len(sigma) else np.full(4, np.nan)
    top = sigma.max(axis=0) if len(sigma) else np.full(4, np.nan)
    first = per_slot[slots[0]]
    return ObserverResults(
        measured_node=section["node"], slot=slots[0],
        rows_measured=int(np.count_nonzero(np.logical_or.reduce(rows_by))),
        model_steps=steps, model_steps_updated=int(np.count_nonzero(np.logical_or.reduce(used_by))),
        sigma_final_C=NodeValues(*(None if np.isnan(v) else float(v) for v in last)),
        sigma_max_C=NodeValues(*(None if np.isnan(v) else float(v) for v in top)),
        innovation_rms_C=first.innovation_rms_C,
        open_loop_rmse_C=per_node(refs.open_loop), observer_rmse_C=per_node(refs.f32), measurements=per_slot)


def observed_rows(record: BusRecord, artifact: ModelArtifact) -> list[np.ndarray]:
    """Per measurement of the observer, which rows of the log carried all its raw channels (VALID)."""
    if not len(record.measurements):
        return []
    raw = raw_channels(raw_sources(artifact), np.asarray(record.drive, dtype=np.float64), record.measurements)
    out, at = [], 0
    for width in channel_widths(artifact):
        out.append(np.isfinite(raw[:, at: at + width]).all(axis=1))
        at += width
    return out
