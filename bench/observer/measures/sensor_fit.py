"""A temperature sensor's lag, gradient and offset estimated from the training files (`bench observer --measure ntc_C
--lag auto --gradient auto --offset auto`).

The training files carry the lab's reference of the sensor's node (winding_C for the winding) and of the yoke
(yoke_C). The sensor is modelled as the target runs it (`target_sim.observer.measurements.lagged_sensor`): it reads
y = lag_τ(w + g·(w − yoke)) + offset, the lag first order at the model step Δ, discretized exactly for an input held
over the step (a = exp(−Δ/τ), y_k = a·y_(k−1) + (1 − a)·x_k) and settled at each file's first step. For a fixed τ
the lag is linear, y = lag(w) + g·lag(w − yoke) + offset, so g and the offset are least squares pooled over every
training file; τ is a bounded 1-D search over log τ (a grid, then Brent's method between the best point's
neighbours), no lag (τ = 0) one more candidate. Each of the three may be given instead (a number): it is then held.
Without a yoke reference the gradient is held at 0 and the estimate says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.errors import UsageError
from bench.observer.measures import step_means

# the slowest lag searched: a stator NTC in its potting lags tens of seconds; beyond this the sensor does not follow
# its node within a drive cycle's phase, and the estimate says it ended at the limit
LAG_MAX_S = 600.0
# the fastest lag searched, in model steps: below it a = exp(−Δ/τ) < 5e-5, no lag at all (τ = 0 is its own candidate)
LAG_MIN_STEPS = 0.1
LAG_LIMIT_FRACTION = 0.95    # a lag above this fraction of LAG_MAX_S ended at the limit, not at a minimum
LAG_GRID_POINTS = 40          # the log τ grid the refinement starts from (about 8.6 % apart over 0.1 Δ .. 600 s)
MIN_STEPS = 20                # fewest model steps with a reading and both references that an estimate takes
YOKE = "yoke_C"
# the lab's reference column of each model node
NODE_REFERENCE = {"yoke": "yoke_C", "winding": "winding_C", "tooth": "tooth_C", "magnet": "pm_C"}
ESTIMATED = ("lag", "gradient", "offset")


@dataclass(frozen=True)
class SensorFit:
    """A sensor's estimate: its values, the residual of its readings (K), what was estimated and what was held."""

    lag_s: float
    gradient: float
    offset_C: float
    residual_rms_K: float
    residual_max_K: float
    steps: int
    files: int
    reference: str
    estimated: tuple[str, ...]
    notes: tuple[str, ...] = ()       # what was held and why (part of the calibration's text)
    warnings: tuple[str, ...] = ()    # what makes the estimate doubtful (`bench observer` warns)

    def calibration(self) -> dict:
        """The estimate as the measurement's calibration record (`describe`, --json)."""
        return {"estimated": list(self.estimated), "reference": self.reference, "steps": self.steps,
                "files": self.files, "residual_rms_K": self.residual_rms_K, "residual_max_K": self.residual_max_K,
                "notes": list(self.notes)}


@dataclass(frozen=True)
class _File:
    reading: np.ndarray       # the sensor column's step means
    node: np.ndarray          # the node's reference
    spread: np.ndarray        # node − yoke (zeros without a yoke reference)
    valid: np.ndarray         # steps whose reading and references are finite


def fit_sensor(datasets: Sequence, dt: float, column: str, node: str = "winding", lag_s: float | None = None,
               gradient: float | None = None, offset_C: float | None = None) -> SensorFit:
    """The sensor `column`'s lag τ (s), gradient g and offset (K) on the training files, each given value held
    (None: estimated), by least squares of its readings against lag_τ(w + g·(w − yoke)) + offset."""
    from scipy.optimize import minimize_scalar

    reference = NODE_REFERENCE[node]
    _require(datasets, column, reference)
    given = dict(zip(ESTIMATED, (lag_s, gradient, offset_C), strict=True))
    notes, warnings = [], []
    has_yoke = node != "yoke" and all(d.has(YOKE) for d in datasets)
    if node == "yoke":      # node − yoke is 0: a gradient changes nothing
        if gradient is None:
            notes.append("the gradient is held at 0: the sensor sees the yoke itself")
        gradient = 0.0
    elif not has_yoke:
        if gradient not in (None, 0.0):
            raise UsageError(f"--gradient {gradient:g} needs the yoke reference {YOKE} in every training file to "
                             "estimate the sensor's other values; map it with --mapping or give them too")
        if gradient is None:
            notes.append(f"the gradient is held at 0: not every training file has the yoke reference {YOKE}")
        gradient = 0.0
    files = [_file(d, dt, column, reference, has_yoke) for d in datasets]
    steps = sum(int(f.valid.sum()) for f in files)
    if steps < MIN_STEPS:
        raise UsageError(f"the training files have {steps} model steps with a reading of {column} and its "
                         f"references; estimating the sensor needs at least {MIN_STEPS}")

    def sse(tau: float) -> float:
        return float(np.sum(_residual(files, dt, tau, gradient, offset_C)[0] ** 2))

    if lag_s is not None:
        tau = lag_s
    else:
        low = math.log(LAG_MIN_STEPS * dt)
        high = math.log(LAG_MAX_S)
        grid = np.linspace(low, high, LAG_GRID_POINTS)
        costs = [sse(math.exp(u)) for u in grid]
        best = int(np.argmin(costs))
        bracket = (grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)])
        found = minimize_scalar(lambda u: sse(math.exp(u)), bounds=bracket, method="bounded",
                                options={"xatol": 1e-4})
        tau = math.exp(float(found.x)) if found.fun <= costs[best] else math.exp(float(grid[best]))
        if sse(0.0) <= sse(tau):
            tau = 0.0
        if tau > LAG_MAX_S * LAG_LIMIT_FRACTION:
            warnings.append(f"the estimate of {column}'s lag ended at {tau:.0f} s, near its upper limit "
                            f"{LAG_MAX_S:g} s: the sensor does not follow {reference} as a first-order lag, so its "
                            "estimate and the observer built on it are doubtful")
    resid, g, offset = _residual(files, dt, tau, gradient, offset_C)
    estimated = tuple(name for name, value in given.items() if value is None and (name != "gradient" or has_yoke))
    return SensorFit(tau, g, offset, float(np.sqrt(np.mean(resid ** 2))), float(np.max(np.abs(resid))), steps,
                     len(files), reference, estimated, tuple(notes), tuple(warnings))


def _require(datasets: Sequence, column: str, reference: str) -> None:
    """Each training file has the sensor's column and its node's reference, else one sentence."""
    for d in datasets:
        for name, what in ((column, "the sensor's column"), (reference, "the node's reference")):
            if not d.has(name):
                raise UsageError(f"{d.path} has no column {name!r} ({what}), which estimating the sensor's lag, "
                                 "gradient or offset ('auto') needs; map it with --mapping or give the values")


def _file(dataset, dt: float, column: str, reference: str, has_yoke: bool) -> _File:
    steps = len(step_means(dataset, ("speed_rpm",), dt, 10 ** 9))
    means = step_means(dataset, (column, reference, *((YOKE,) if has_yoke else ())), dt, steps)
    reading, node = means[:, 0], means[:, 1]
    spread = node - means[:, 2] if has_yoke else np.zeros_like(node)
    valid = np.isfinite(reading) & np.isfinite(spread)
    return _File(reading, _filled(node), _filled(spread), valid)


def _filled(x: np.ndarray) -> np.ndarray:
    """x with its gaps (NaN) interpolated, so the lag runs through them."""
    ok = np.isfinite(x)
    if ok.all() or not ok.any():
        return np.where(ok, x, 0.0)
    index = np.arange(len(x))
    return np.interp(index, index[ok], x[ok])


def _lag(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """x through the first-order lag τ at step dt, settled at x[0] (τ = 0: x itself)."""
    from scipy.signal import lfilter

    if tau <= 0:
        return x
    a = math.exp(-dt / tau)
    return lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])[0]


def _residual(files: Sequence[_File], dt: float, tau: float, gradient: float | None,
              offset_C: float | None) -> tuple[np.ndarray, float, float]:
    """(residual at the valid steps, gradient, offset): those given held, the others least squares for this τ."""
    target, spread = [], []
    for f in files:
        target.append((f.reading - _lag(f.node, dt, tau))[f.valid])
        spread.append(_lag(f.spread, dt, tau)[f.valid])
    y, s = np.concatenate(target), np.concatenate(spread)
    columns = []
    if gradient is None:
        columns.append(s)
    else:
        y = y - gradient * s
    if offset_C is None:
        columns.append(np.ones_like(y))
    else:
        y = y - offset_C
    if columns:
        x = np.column_stack(columns)
        beta, *_ = np.linalg.lstsq(x, y, rcond=None)
        y = y - x @ beta
        values = iter(beta)
        gradient = float(next(values)) if gradient is None else gradient
        offset_C = float(next(values)) if offset_C is None else offset_C
    return y, float(gradient), float(offset_C)
