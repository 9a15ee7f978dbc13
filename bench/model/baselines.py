"""Simple estimators a thermal model has to beat, fitted on the training runs and recorded in the artifact.

- `coolant`: the coolant temperature as the estimate of every node (what a drive without a model assumes);
- `copper_lowpass`: coolant + K·LP_τ(P_cu) + r0·e^(-t/τ), a first-order low-pass of the nominal copper loss (dc +
  ac at the copper reference temperature) with one gain K (K/W) and time constant τ (s) per node, fitted by least
  squares on the training runs (τ on a logarithmic grid, K in closed form for each τ); r0, the measured rise at
  the start, decays with the same τ, so the baseline starts where the model starts.
Both use only what the model itself gets (coolant, the loss model's copper loss), so a model that does not beat
them clearly has not learnt the machine.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bench.model.deploy import DEPLOYED_NODES
from bench.model.runs import ModelRun
from bench.thermal import portable

TAU_GRID_S = np.geomspace(5.0, 20000.0, 121)
NODES = DEPLOYED_NODES


def copper_loss(run: ModelRun) -> np.ndarray:
    """Nominal copper loss per step (W): p_dc0 + p_ac0 of the loss model."""
    return run.inputs.table_losses[:, 0] + run.inputs.table_losses[:, 1]


def lowpass(signal: np.ndarray, tau_s: float, dt: float) -> np.ndarray:
    """Exact first-order lag of a signal held over each step, starting from 0."""
    from scipy.signal import lfilter

    a = portable.exp(-dt / tau_s)
    return lfilter([1.0 - a], [1.0, -a], signal)


def _reference(run: ModelRun, node: str) -> np.ndarray:
    return run.ref_winding if node == "winding" else run.ref_pm


def _initial_rise(run: ModelRun, node: str) -> float:
    return float(run.initial[1 if node == "winding" else 3] - run.initial[0])   # initial[0]: first coolant sample


def _decay(run: ModelRun, tau: float) -> np.ndarray:
    return portable.exp_array(-(np.arange(len(run.inputs.coolant)) + 1) * run.dt / tau)


def fit_copper_lowpass(runs: Sequence[ModelRun], node: str) -> dict[str, float]:
    """{gain_K_per_W, tau_s, rmse_C} minimizing the pooled squared error over the runs."""
    return fit_copper_lowpasses(runs, (node,))[node]


def fit_copper_lowpasses(runs: Sequence[ModelRun], nodes: Sequence[str] = NODES) -> dict[str, dict[str, float]]:
    """`fit_copper_lowpass` of each node, the low-passed losses and decays of each τ computed once for all nodes."""
    best = dict.fromkeys(nodes)
    for tau in TAU_GRID_S:
        decays = [_decay(r, tau) for r in runs]
        filtered = [lowpass(copper_loss(r), tau, r.dt) for r in runs]
        # exact sums (portable.dot): a BLAS dot's last bit depends on the CPU's kernel, and the gain is recorded
        den = math.fsum(portable.dot(f, f) for f in filtered)
        for node in nodes:
            rises = [_reference(r, node) - r.inputs.coolant - _initial_rise(r, node) * d
                     for r, d in zip(runs, decays, strict=True)]
            num = math.fsum(portable.dot(f, y) for f, y in zip(filtered, rises, strict=True))
            gain = num / den if den > 0 else 0.0
            sse = math.fsum(portable.dot(e, e) for e in (y - gain * f for f, y in zip(filtered, rises, strict=True)))
            if best[node] is None or sse < best[node][0]:
                best[node] = (sse, gain, float(tau))
    count = sum(len(r.inputs.coolant) for r in runs)
    return {node: {"gain_K_per_W": gain, "tau_s": tau, "rmse_C": float(np.sqrt(sse / count))}
            for node, (sse, gain, tau) in best.items()}


def fit_baselines(runs: Sequence[ModelRun]) -> dict:
    """What the artifact records: the fitted copper low-pass per node (the coolant baseline has no parameter)."""
    return {"copper_lowpass": fit_copper_lowpasses(runs, NODES)}


def baseline_estimates(baselines: dict, run: ModelRun) -> dict[str, dict[str, np.ndarray]]:
    """{baseline: {node: (steps,) estimate}} on one run."""
    out = {"coolant": {node: np.asarray(run.inputs.coolant, dtype=float) for node in NODES}}
    fitted = baselines.get("copper_lowpass") if isinstance(baselines, dict) else None
    if fitted:
        out["copper_lowpass"] = {}
        for node in NODES:
            gain, tau = fitted[node]["gain_K_per_W"], fitted[node]["tau_s"]
            out["copper_lowpass"][node] = (run.inputs.coolant + gain * lowpass(copper_loss(run), tau, run.dt)
                                           + _initial_rise(run, node) * _decay(run, tau))
    return out
