"""The LTI LPTN driven by the nominal loss maps, closed loop, in float64: the estimator the Hammerstein
model has to beat, run on a dataset to show how wrong the nominal model is.

Per model step k (interval [kΔt, (k+1)Δt)): the inputs are the means of the 5 Hz samples in the interval
(`bench.thermal.excitation.interval_means`); node losses come from the nominal maps with eqs. 3-8 at the
previous winding estimate; the temperature sources of eqs. 9-18 from the previous estimate; then one step of
the discretized LTI network. Row k of the result is the estimate at t = (k+1)Δt.
"""

from __future__ import annotations

import numpy as np

from bench.drive.dataset import Dataset
from bench.drive.motor import LossMaps, MotorSpec
from bench.thermal.discretize import discretize
from bench.thermal.excitation import interval_means
from bench.thermal.losses import node_losses
from bench.thermal.lptn import lti_matrices, temperature_sources
from bench.thermal.parameters import LptnParameters


def lti_lptn_estimate(dataset: Dataset, params: LptnParameters, loss_maps: LossMaps, spec: MotorSpec,
                      dt: float = 0.5, method: str = "zoh", initial=None) -> np.ndarray:
    """(steps, 4) estimates [yoke, winding, tooth, magnet] in °C at t = (k+1)·Δt.

    A plain-numpy statement of the estimator, kept beside the compiled kernel of bench.thermal.estimator as
    its independent cross-check (tests/bench/model/test_estimator_kernel.py). `initial` defaults to every node at
    the first coolant sample.
    """
    means = interval_means(dataset.drive_inputs(), dataset.sample_period_s, dt)
    torque, speed, coolant, ambient = means.T
    maps = loss_maps.evaluate(torque, speed)   # state-independent: all steps at once
    current_ratio = maps["current"] / spec.i_max_A
    speed_ratio = np.abs(speed) / spec.max_speed_rpm
    a, b, _, _ = lti_matrices(params)
    a_d, b_d = discretize(a, b, dt, method)
    x = np.full(4, float(dataset.coolant_C[0])) if initial is None else np.asarray(initial, dtype=float).copy()
    out = np.empty((len(means), 4))
    for k in range(len(means)):
        p = node_losses(params, maps["p_dc0"][k], maps["p_ac0"][k], maps["p_stator"][k], maps["p_magnet"][k],
                        current_ratio[k], speed_ratio[k], x[1])
        src = temperature_sources(params, x, speed_ratio[k], coolant[k], ambient[k])
        x = a_d @ x + b_d @ np.concatenate([p, src])
        out[k] = x
    return out


def compared_samples(dataset: Dataset, steps: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(model step indices, sample indices) where t = (k+1)Δt falls exactly on a sample.

    At Δt = 0.5 s and 5 Hz that is every second step (t = 1, 2, 3, ... s); measurements are never interpolated.
    """
    k = np.arange(steps)
    t_us = (k + 1) * int(round(dt * 1e6))
    period_us = int(round(dataset.sample_period_s * 1e6))
    hit = (t_us % period_us == 0) & (t_us // period_us < dataset.rows)
    samples = t_us[hit] // period_us
    return k[hit], samples


def baseline_rmse(dataset: Dataset, estimates: np.ndarray, dt: float = 0.5) -> dict[str, float]:
    """Winding and PM RMSE and maximum absolute error (°C) of estimates against the measurements."""
    k, n = compared_samples(dataset, len(estimates), dt)
    err_w = estimates[k, 1] - dataset.winding_C[n]
    err_m = estimates[k, 3] - dataset.pm_C[n]
    return {"winding_rmse_C": float(np.sqrt(np.mean(err_w ** 2))), "pm_rmse_C": float(np.sqrt(np.mean(err_m ** 2))),
            "winding_max_abs_C": float(np.abs(err_w).max()), "pm_max_abs_C": float(np.abs(err_m).max()),
            "winding_mean_error_C": float(err_w.mean()), "pm_mean_error_C": float(err_m.mean()),
            "compared_samples": int(len(k))}
