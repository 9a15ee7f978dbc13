"""The float32 observer over a whole dataset, offline: the reference of a run over CAN, bit for bit (the same
interval means, the same filter steps).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from target_sim.artifact import ModelArtifact
from target_sim.model import F32, InputAccumulator
from target_sim.observer.filter import Float32Observer


@dataclass(frozen=True)
class ObserverRun:
    """A whole run of the float32 observer: per model step the estimate, each node's 1-σ, the first
    measurement's innovation (NaN without a reading), every measurement's and, on request, the covariance in the
    state coordinates and the filter's own (node coordinates)."""

    rows: np.ndarray
    outputs: np.ndarray
    innovations: np.ndarray
    covariances: np.ndarray | None
    sigmas: np.ndarray | None = None
    all_innovations: np.ndarray | None = None
    filter_covariances: np.ndarray | None = None      # on request: the filter's own P' (node coordinates)
    rejected: np.ndarray | None = None                # per step and measurement: the gate rejected its reading
    flagged: np.ndarray | None = None                 # per measurement: its sensor was flagged (latched)
    flagged_steps: np.ndarray | None = None           # per step and measurement: its sensor flagged after the step


def run_observer_offline(artifact: ModelArtifact, drive: np.ndarray, measurement: np.ndarray,
                         initial: Sequence[float], form: str | None = None, keep_covariance: bool = False,
                         dtype=F32) -> ObserverRun:
    """The float32 observer over a whole dataset: `drive` as `target_sim.model.run_offline` takes it,
    `measurement` the measurements' raw channels per row ((rows,) for one channel; NaN: none), accumulated with the
    drive into the step's float32 interval mean."""
    obs = Float32Observer(artifact, form, dtype)
    obs.reset(initial)
    drive = np.asarray(drive, dtype=np.float64)
    measurement = np.asarray(measurement, dtype=np.float64)
    width, channels = len(artifact.drive_signals), sum(obs.layout.widths)
    if measurement.ndim == 1:
        measurement = measurement[:, None]
    if drive.ndim != 2 or drive.shape[1] != width or measurement.shape != (len(drive), channels):
        raise ValueError(f"the observer needs {width} drive columns and {channels} measurement channel(s) per row, "
                         f"not {drive.shape} and {measurement.shape}")
    rows = np.column_stack([drive, measurement])
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt, width + channels)
    steps, outputs, innovations, covariances, sigmas, own, rejected, flagged = [], [], [], [], [], [], [], []
    for row, sample in enumerate(rows):
        means = acc.add(row, sample)
        if means is None:
            continue
        outputs.append(obs.step(*means[:width], z=means[width:]))
        innovations.append(obs.innovations.copy())
        rejected.append(obs.gate.rejected.copy())
        flagged.append(obs.gate.flagged.copy())
        sigmas.append(obs.sigma())
        if keep_covariance:
            covariances.append(np.array(obs.covariance(), dtype=np.float64))
            own.append(obs.filter_covariance())
        steps.append(row)
    every = np.array(innovations, dtype=np.float64).reshape(-1, len(obs.measurements))
    return ObserverRun(np.array(steps, dtype=np.int64), np.array(outputs, dtype=dtype).reshape(-1, 4), every[:, 0],
                       np.array(covariances) if keep_covariance else None,
                       np.array(sigmas).reshape(-1, 4), every, np.array(own) if keep_covariance else None,
                       np.array(rejected, dtype=bool).reshape(-1, len(obs.measurements)), obs.gate.flagged.copy(),
                       np.array(flagged, dtype=bool).reshape(-1, len(obs.measurements)))
