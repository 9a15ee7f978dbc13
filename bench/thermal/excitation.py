"""A synthetic excitation for the linear block, and the rule that maps data samples onto model steps.

The precision analysis needs a long, rich input: 7274 s sampled at 0.2 s (the length and rate of the paper's
test sequence), with losses switching between random levels and slowly drifting source temperatures.
"""

from __future__ import annotations

import numpy as np

from dbc.contract import DRIVE_SAMPLE_PERIOD_S

SEQUENCE_S = 7274.0
SAMPLE_PERIOD_S = DRIVE_SAMPLE_PERIOD_S


def synthetic_lti_inputs(duration_s: float = SEQUENCE_S, sample_period_s: float = SAMPLE_PERIOD_S,
                         seed: int = 7) -> np.ndarray:
    """(rows, 8) inputs [P_y, P_w, P_t, P_m, ϑ_cv, ϑ_av, ϑ_a1, ϑ_a2] with plausible magnitudes."""
    rng = np.random.default_rng(seed)
    rows = int(round(duration_s / sample_period_s)) + 1
    t = np.arange(rows) * sample_period_s
    peak = np.array([900.0, 3000.0, 700.0, 120.0])
    losses = np.empty((rows, 4))
    start = 0
    while start < rows:  # piecewise-constant loss levels held 5-120 s, like a drive cycle's phases
        stop = min(rows, start + int(rng.uniform(5, 120) / sample_period_s))
        losses[start:stop] = peak * rng.uniform(0, 1, 4) ** 2
        start = stop
    coolant = 40 + 15 * np.sin(2 * np.pi * t / 3000)
    ambient = 25 + 3 * np.sin(2 * np.pi * t / 5000 + 1)
    a1 = 60 + 30 * np.sin(2 * np.pi * t / 1500)
    a2 = 80 + 40 * np.sin(2 * np.pi * t / 1100 + 0.5)
    return np.column_stack([losses, coolant, ambient, a1, a2])


def model_step_of_sample(sample_index, sample_period_s: float, dt: float):
    """Index of the model step whose interval [k·Δt, (k+1)·Δt) holds sample n (time n·T_s).

    Times are compared in integer microseconds so 0.2 s and 0.5 s never disagree by round-off.
    """
    t_us = np.asarray(sample_index, dtype=np.int64) * int(round(sample_period_s * 1e6))
    return t_us // int(round(dt * 1e6))


def interval_means(samples: np.ndarray, sample_period_s: float, dt: float) -> np.ndarray:
    """Mean of the samples in each complete model-step interval: the inputs of model step k."""
    samples = np.asarray(samples, dtype=np.float64)
    steps = model_step_of_sample(np.arange(len(samples)), sample_period_s, dt)
    last_complete = model_step_of_sample(len(samples), sample_period_s, dt)  # intervals ending by the last row
    keep = steps < last_complete
    counts = np.bincount(steps[keep], minlength=last_complete)
    sums = np.zeros((last_complete, samples.shape[1]))
    np.add.at(sums, steps[keep], samples[keep])
    return sums / counts[:, None]
