"""The other side of a WCET bound: inputs searched for the most cycles the emulated core measures.

    best = maximize(cycles_of, dimension, evaluations=48, seed=0)     # cycles_of: [0, 1]^d -> measured cycles
    step_scenario(artifact, image)   /   frame_scenario(artifact, image, run_frames, ...)     # the two objectives

A drive cycle's rows show what a drive does, not what the code can be made to do; the gap between a static bound
and the truth is only shown from both ends when the measured side is pushed too. The search is a (1+1) evolution
strategy with the one-fifth success rule (Rechenberg 1973; the step-size control of CMA-ES, Hansen 2016, in its
simplest form) after a uniform random start: a candidate is a point of the unit cube, mapped to inputs within the
ranges the bus can carry (the DBC's signal ranges), the objective is the largest cycle count the emulator measures
on them (`target_sim.firmware.cycles`: the same cost model the bound sums). Seeded: the same seed, the same search.

- `step_scenario`: the model step (fw_step, or an observer's fw_obs_step) called directly, from start temperatures
  and over a few steps whose drive values and, for an observer, raw measurement channels (a channel is NaN, no
  reading, in the lower part of its coordinate's range, which switches measurement updates on and off) come from
  the candidate;
- `frame_scenario`: node_on_frame beside the current loop's interrupt (`bench.firmware.timing.run_frames`), a RESET
  to start temperatures, START, then rows in order whose values (and, for an observer, the host's measurement
  channels, NaN in part of their range: ABSENT) come from the candidate, enough of them to pass a StateCheckpoint
  (every CHECKPOINT_EVERY_STEPS model steps).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dbc.contract import CHECKPOINT_EVERY_STEPS, row_signals
from dbc.database import signal_ranges, temperature_range
from target_sim.artifact import ModelArtifact
from target_sim.firmware.elf import ElfImage

NO_READING_BELOW = 0.15        # a channel coordinate below this is NaN (no reading)
STEPS_PER_CANDIDATE = 4        # model steps of one step-scenario candidate
RANDOM_SHARE = 0.4             # of the evaluations, spent on uniform random candidates before the local search


@dataclass(frozen=True)
class SearchResult:
    cycles: int                # the most cycles measured
    point: np.ndarray          # the candidate that gave them
    evaluations: int


def maximize(cycles_of: Callable[[np.ndarray], int], dimension: int, *, evaluations: int, seed: int = 0,
             starts: list[np.ndarray] | tuple = ()) -> SearchResult:
    """The largest `cycles_of(point)` found over `evaluations` points of [0, 1]^dimension: `starts` and uniform
    random points first, then a (1+1)-ES from the best (Gaussian steps, step size x1.5 on a success and x0.9 on a
    failure, clipped to the cube; an equal count is a success, so plateaus are crossed)."""
    if evaluations < 1:
        raise ValueError(f"evaluations must be 1 or more, not {evaluations}")
    rng = np.random.default_rng(seed)
    best_point, best = None, -1
    done = 0
    randoms = max(1, int(RANDOM_SHARE * evaluations))
    for point in [*(np.clip(np.asarray(s, dtype=float), 0.0, 1.0) for s in starts),
                  *(rng.random(dimension) for _ in range(randoms))]:
        if done >= evaluations:
            break
        value = cycles_of(point)
        done += 1
        if value > best:
            best, best_point = value, point
    sigma = 0.2
    while done < evaluations:
        candidate = np.clip(best_point + sigma * rng.standard_normal(dimension), 0.0, 1.0)
        value = cycles_of(candidate)
        done += 1
        if value >= best:
            best, best_point, sigma = value, candidate, min(sigma * 1.5, 0.5)
        else:
            sigma = max(sigma * 0.9, 0.01)
    return SearchResult(int(best), best_point, done)


def _row_ranges(width: int) -> np.ndarray:
    """(width, 2) low/high of each data-row value on the bus."""
    return np.array([signal_ranges(message)[signal] for message, signal in row_signals(width)], dtype=float)


def _scale(unit: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    return ranges[:, 0] + unit * (ranges[:, 1] - ranges[:, 0])


def _start_temperatures(unit: np.ndarray) -> list[float]:
    low, high = temperature_range()
    return [round(float(v), 1) for v in low + unit * (high - low)]


def step_scenario(artifact: ModelArtifact, image: ElfImage) -> tuple[Callable[[np.ndarray], int], int]:
    """(objective, dimension) of the model step called directly: start temperatures, then STEPS_PER_CANDIDATE
    steps of drive values (and raw channels) from the candidate; the objective is the largest step's cycles."""
    from target_sim.firmware import FirmwareEstimator

    model = FirmwareEstimator(artifact, image)
    width = len(artifact.drive_signals)
    channels = model.channels if model.observer else 0
    ranges = _row_ranges(width)
    low, high = temperature_range()
    per_step = width + channels

    def cycles_of(point: np.ndarray) -> int:
        model.reset(_start_temperatures(point[:4]))
        most = 0
        for k in range(STEPS_PER_CANDIDATE):
            part = point[4 + k * per_step: 4 + (k + 1) * per_step]
            values = [float(v) for v in _scale(part[:width], ranges)]
            if model.observer:
                raw = [float("nan") if u < NO_READING_BELOW else low + (u - NO_READING_BELOW)
                       / (1 - NO_READING_BELOW) * (high - low) for u in part[width:]]
                model.step(*values, z=raw)
            else:
                model.step(*values)
            most = max(most, int(model.last_cycles))
        return most

    return cycles_of, 4 + STEPS_PER_CANDIDATE * per_step


def frame_rows(artifact: ModelArtifact) -> int:
    """Rows of a frame-scenario candidate: one StateCheckpoint's worth of model steps and a few rows more."""
    rows_per_step = artifact.dt / artifact.data_sample_period
    return int(np.ceil((CHECKPOINT_EVERY_STEPS + 1) * rows_per_step)) + 2


def frame_scenario(artifact: ModelArtifact, image: ElfImage, run_frames: Callable[..., object], *, isr_rate_hz: float,
                   clock_mhz: float, seed: int = 0) -> tuple[Callable[[np.ndarray], tuple[int, object]], int]:
    """(run, dimension) of node_on_frame beside the interrupt: start temperatures and `frame_rows` rows from the
    candidate; run(point) gives the most cycles any one call of node_on_frame took, and the run (its
    interrupts' handler cycles too). `run_frames` is the timing's own run of frames
    (`bench.firmware.timing.run_frames`, given by its caller: the timing imports this module, not the reverse)."""
    from target_sim.observer import has_observer
    from target_sim.observer.node import measurement_width

    width = len(artifact.drive_signals)
    channels = measurement_width(artifact) if has_observer(artifact) else 0
    rows = frame_rows(artifact)
    ranges = _row_ranges(width)
    limits = _channel_ranges(channels)
    per_row = width + channels

    def run_of(point: np.ndarray) -> tuple[int, object]:
        parts = [point[4 + r * per_row: 4 + (r + 1) * per_row] for r in range(rows)]
        drive = np.array([_scale(part[:width], ranges) for part in parts])
        measured = np.array([[np.nan if u < NO_READING_BELOW else low + (u - NO_READING_BELOW)
                              / (1 - NO_READING_BELOW) * (high - low) for u, (low, high) in zip(part[width:], limits,
                                                                                                 strict=True)]
                             for part in parts]) if channels else None
        run = run_frames(artifact, image, drive, _start_temperatures(point[:4]), isr_rate_hz=isr_rate_hz,
                         clock_mhz=clock_mhz, seed=seed, measurement=measured)
        return max(job.cycles for job in (*run.step_jobs, *run.other_jobs)), run

    return run_of, 4 + rows * per_row


def _channel_ranges(channels: int) -> list[tuple[float, float]]:
    """(low, high) of the first `channels` host measurement channels on the bus (their value signals)."""
    from dbc.contract import CHANNEL_NAMES, MEASUREMENT_CHANNELS

    out = []
    for channel in CHANNEL_NAMES[:channels]:
        message, value_signal, _ = MEASUREMENT_CHANNELS[channel]
        out.append(signal_ranges(message)[value_signal])
    return out
