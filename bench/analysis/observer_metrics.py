"""The observer's figures of a run (`bench.analysis.results.ObserverResults`): from the target's observer frames in
the log (each node's 1-sigma, the innovations) and the offline references (open loop beside observer)."""

from __future__ import annotations

import numpy as np

from bench.analysis.logdecode import BusRecord
from bench.analysis.results import NodeValues, ObserverResults, SlotFigures
from dbc.contract import TEMPERATURE_NODES
from target_sim.artifact import ModelArtifact
from target_sim.observer import measurement_entries
from target_sim.observer_node import channel_widths, measurement_slots, raw_channels, raw_sources

# the sigma series of the log per node (`BusRecord.observer`), in the temperature order
SIGMA_KEYS = {"yoke": ("row_u2", "yoke_sigma"), "winding": ("row_u1", "winding_sigma"),
              "tooth": ("row_u2", "tooth_sigma"), "magnet": ("row_u1", "magnet_sigma")}


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
    per_slot, used_by, rows_by = {}, [np.zeros(steps, dtype=bool)], [np.zeros(record.rows, dtype=bool)]
    for index, (slot, entry) in enumerate(zip(slots, measurement_entries(section), strict=True)):
        used = obs.get(f"{slot}_used", np.zeros(steps)) > 0
        innovation = obs.get(f"{slot}_innovation", np.zeros(steps))[used]
        rows = channels[index] if channels else np.zeros(record.rows, dtype=bool)
        used_by.append(used)
        rows_by.append(rows)
        rejected = getattr(refs, "rejected", None)
        flagged = getattr(refs, "flagged", None)
        per_slot[slot] = SlotFigures(
            measured_node="magnet" if slot == "flux" else entry.get("node", section.get("node")),
            rows_measured=int(np.count_nonzero(rows)), model_steps_updated=int(np.count_nonzero(used)),
            innovation_rms_C=float(np.sqrt(np.mean(innovation ** 2))) if innovation.size else None,
            readings_rejected=0 if rejected is None else int(np.count_nonzero(rejected[:, index])),
            sensor_flagged=bool(flagged is not None and flagged[index]),
            sensor=", ".join(entry.get("columns", [])) or str(entry.get("name", section.get("column", slot))))

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
