"""Many trajectories of one model at once: the target's own float32 code (`target_sim.model.Float32Estimator`) run
on L lanes side by side, each lane bit for bit what `target_sim.model.run_offline` gives for its drive rows.

A lane is one perturbed copy of a data file (one seed of one case). The drive samples reach the model as on the
target: the float32 mean of the samples of each model step's interval, summed left to right in float32 as
`target_sim.model.InputAccumulator` does (`interval_means`), the step running on the interval's last sample.
Δt jitter moves the interval boundaries of a lane (`step_boundaries`): the model still believes every step is Δt
long, the samples it averages and the time its output refers to are those of the jittered clock.
With an observer artifact a lane's rows also carry the measurement columns; `run_observer_lanes` runs the target's
float32 observer (`target_sim.observer.Float32Observer`) on the same interval means, lane by lane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.robustness.channels import lane_columns, measurement_columns
from target_sim.artifact import ModelArtifact
from target_sim.model import Float32Estimator
from target_sim.observer import Float32Observer

F32 = np.float32


def nominal_step_of_rows(rows: int, sample_period_s: float, dt: float) -> np.ndarray:
    """The model step each row belongs to on the target's clock (`InputAccumulator.model_step_of`), for the rows
    and the one after the last (whether the last row ends its interval)."""
    sample_us, dt_us = int(round(sample_period_s * 1e6)), int(round(dt * 1e6))
    return np.arange(rows + 1, dtype=np.int64) * sample_us // dt_us


def jittered_step_of_rows(rows: int, sample_period_s: float, boundaries_s: np.ndarray) -> np.ndarray:
    """The step each row (and the one after the last) falls in when the steps start at `boundaries_s`
    (increasing, from 0 s)."""
    times = np.arange(rows + 1, dtype=np.float64) * sample_period_s
    return np.searchsorted(boundaries_s, times, side="right") - 1


@dataclass(frozen=True)
class LaneSteps:
    """One lane's model steps: the interval means the model consumes and when each output is due."""

    means: np.ndarray        # (steps, width) float32
    end_s: np.ndarray        # (steps,) the time each step's output refers to, from the file's start


def interval_means(drive: np.ndarray, step_of_row: np.ndarray, end_of_step_s: np.ndarray) -> LaneSteps:
    """The float32 mean of each complete interval's rows (a step runs on the last row of its interval; rows after
    the last complete interval never make a step, as on the target). An interval without a row (a jittered clock
    faster than the samples) holds the previous step's inputs."""
    drive = np.asarray(drive, dtype=F32)
    rows = len(drive)
    if rows == 0:
        return LaneSteps(np.zeros((0, drive.shape[1]), F32), np.zeros(0))
    ends = np.flatnonzero(step_of_row[1:] != step_of_row[:-1])     # rows that end their interval (rows + 1 given)
    steps = int(step_of_row[ends[-1]]) + 1 if len(ends) else 0
    counts = np.bincount(step_of_row[: ends[-1] + 1], minlength=steps) if steps else np.zeros(0, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    total = np.zeros((steps, drive.shape[1]), dtype=F32)
    for offset in range(int(counts.max()) if steps else 0):        # left to right, as sum <- sum + sample
        has = counts > offset
        total[has] = total[has] + drive[starts[has] + offset]
    with np.errstate(invalid="ignore", divide="ignore"):
        means = total / counts.astype(F32)[:, None]
    for k in np.flatnonzero(counts == 0):
        means[k] = means[k - 1] if k else drive[0]
    return LaneSteps(means, np.asarray(end_of_step_s[:steps], dtype=np.float64))


def nominal_steps(drive: np.ndarray, sample_period_s: float, dt: float) -> LaneSteps:
    step_of_row = nominal_step_of_rows(len(drive), sample_period_s, dt)
    return interval_means(drive, step_of_row, (np.arange(int(step_of_row[-1]) + 2) + 1) * dt)


def jittered_steps(drive: np.ndarray, sample_period_s: float, boundaries_s: np.ndarray) -> LaneSteps:
    step_of_row = jittered_step_of_rows(len(drive), sample_period_s, boundaries_s)
    return interval_means(drive, step_of_row, boundaries_s[1:])


def run_lanes(artifact: ModelArtifact, lanes: list[LaneSteps], initial: np.ndarray) -> list[np.ndarray]:
    """Each lane's (steps, 4) float32 estimates from its interval means and its initial temperatures (initial:
    (4, L)); the lanes run in one estimator, a shorter lane padded with its last inputs and cut back after."""
    model = Float32Estimator(artifact)
    model.reset(np.asarray(initial, dtype=np.float64))
    longest = max(len(lane.means) for lane in lanes)
    width = len(artifact.drive_signals)          # a lane's measurement columns are the observer's, not the model's
    inputs = np.empty((longest, width, len(lanes)), dtype=F32)
    for index, lane in enumerate(lanes):
        inputs[: len(lane.means), :, index] = lane.means[:, :width]
        inputs[len(lane.means):, :, index] = lane.means[-1, :width] if len(lane.means) else 0
    out = np.empty((longest, 4, len(lanes)), dtype=F32)
    with np.errstate(over="ignore", invalid="ignore"):   # a diverging lane is a result, not a warning
        for k in range(longest):
            out[k] = model.step(*inputs[k])
    return [out[: len(lane.means), :, index] for index, lane in enumerate(lanes)]


def run_observer_lanes(artifact: ModelArtifact, lanes: list[LaneSteps], initial: np.ndarray) -> list[np.ndarray]:
    """Each lane's (steps, 4) float32 estimates of the artifact's observer (its deployed form): the interval means
    hold the lane columns (`channels.lane_columns`: the drive's, then the measurement columns it lacks); the
    measurements' raw channels are picked from them in the observer's order (NaN: no reading that step, predict
    only), as `target_sim.observer.run_observer_offline` accumulates them. The observer keeps one covariance per
    trajectory, so the lanes run one after the other."""
    width = len(artifact.drive_signals)
    columns = lane_columns(artifact)
    raw = np.array([columns.index(c) for c in measurement_columns(artifact)], dtype=np.int64)
    out = []
    with np.errstate(over="ignore", invalid="ignore"):   # a diverging lane is a result, not a warning
        for index, lane in enumerate(lanes):
            observer = Float32Observer(artifact)
            observer.reset(np.asarray(initial, dtype=np.float64)[:, index])
            estimates = np.empty((len(lane.means), 4), dtype=F32)
            for k, means in enumerate(lane.means):
                estimates[k] = observer.step(*means[:width], z=means[raw])
            out.append(estimates)
    return out
