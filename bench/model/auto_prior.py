"""`--prior auto`: a starting network read from the training data and the motor file, for a motor without one.

Why: the swarm searches a box around its prior. A prior from another machine (Table 1 is a 200 kW out-runner)
puts the true network outside any narrow box, and a wide box around a wrong centre leaves the swarm too much
space. What the data show directly is how fast and how far each measured node rises above the coolant when the
motor makes losses; those two numbers per node fix the network's resistances and capacitances to within a factor
of a few, which a wide log-scaled search (0.1-10 ×, bench.motor.description.AUTO_BOUNDS) and the local polish
then refine.

The steps (docs/method.md, "The automatic prior"):

1. Per measured node n: rise_n(t) = ϑ_n − ϑ_coolant ≈ K_s·LP_τ(P_stator) + K_m·LP_τ(P_magnet) + r0·e^(−t/τ):
   one first-order lag of the stator losses (copper at the measured winding temperature + iron) and of the
   magnet loss, τ on a fixed grid, the gains by non-negative least squares (exact sums, so the same bits on every
   CPU). K_s is the node's steady-state rise per W of stator loss, K_m per W of magnet loss, τ its time constant.
2. Resistances. Stator heat leaves through the yoke to the coolant: R_cy0 = K_s(yoke) when the yoke is measured,
   else a third of the winding's K_s (the jacket's share of the winding rise in water-jacket machines: Table 1 and
   the IPM example both have about 1/3). The winding's rise above the yoke per W, R_w = K_s(winding) − R_cy0, is
   split into a main path R_yw = 1.25 R_w and a path through the tooth R_wt = 5 R_w, R_yt = 0.5 R_w (in parallel
   they give R_w back). The magnet's heat crosses the air gap to winding and tooth and leaves by the shaft:
   R_rotor = K_m(PM) − R_cy0 is split into three equal conductances, a_wm = a_tm = a_ma = 3 R_rotor, and each
   speed-dependent part starts equal to its fixed part (R_xx0 = a_xx).
3. Capacitances from the time constants: the stator charges through R_cy0 (τ_slow = C_stator·R_cy0, the yoke's
   τ when measured), the winding through R_w; the winding's single τ is their gain-weighted mix,
   τ_w·K_w = C_stator·R_cy0² + C_w·R_w². The magnet charges through its own rise: C_m = τ_PM/K_m(PM).
   The stator's rest is split yoke 60 %, tooth 40 %.
4. What the data cannot show this way keeps the paper's values: the speed exponents b_wm, b_tm, b_ma, the coolant
   coefficient alpha_cy and the stator split k_0…k_3 (dimensionless, within fixed physical bounds).
5. Machine size is the fallback: when a node shows no rise (no magnet loss, say), its capacitance comes from the
   peak torque (STORED_HEAT_PER_NM, J/K per Nm: torque scales with rotor volume, heat capacity with mass) and its
   resistances from the winding's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from bench.errors import BenchError
from bench.model.runs import ModelRun
from bench.thermal import portable
from bench.thermal.parameters import TABLE1, LptnParameters

# Time constants tried for each node's first-order lag (s): a fixed list, so the fit needs no exp/log of numpy.
TAU_GRID_S = (10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0, 180.0, 250.0, 350.0, 500.0, 700.0, 1000.0, 1400.0,
              2000.0, 2800.0, 4000.0, 5600.0, 8000.0, 11000.0, 16000.0, 22000.0)
JACKET_SHARE = 1.0 / 3.0        # R_cy0 / K_s(winding) without a yoke sensor
WINDING_SPLIT = {"R_yw": 1.25, "R_wt": 5.0, "R_yt": 0.5}    # × R_w; R_yw ∥ (R_wt + R_yt) ≈ R_w
ROTOR_PATHS = 3.0               # a_wm = a_tm = a_ma = 3 R_rotor: three equal conductances in parallel
STATOR_WINDING_SHARE = 0.35     # C_w / C_stator without a yoke sensor
YOKE_SHARE_OF_IRON = 0.6        # of C_stator − C_w
STORED_HEAT_PER_NM = 40.0       # J/K of the whole machine per Nm of peak torque (fallback)
MIN_SHARE = 0.1                 # no resistance below a tenth of the winding's total rise per W


@dataclass(frozen=True)
class NodeResponse:
    """A measured node's first-order response to the losses."""

    gain_stator_K_per_W: float
    gain_magnet_K_per_W: float
    tau_s: float
    rmse_C: float

    def as_dict(self) -> dict:
        return {"gain_stator_K_per_W": self.gain_stator_K_per_W, "gain_magnet_K_per_W": self.gain_magnet_K_per_W,
                "tau_s": self.tau_s, "rmse_C": self.rmse_C}


@dataclass(frozen=True)
class AutoPrior:
    parameters: LptnParameters
    responses: dict[str, NodeResponse]
    fallbacks: tuple[str, ...]       # what came from machine size instead of the data


def node_losses(run: ModelRun) -> tuple[np.ndarray, np.ndarray]:
    """(stator, magnet) loss per step, W: copper at the measured winding temperature (eqs. 3-4) plus iron."""
    t = run.inputs.table_losses
    factor = 1.0 + run.inputs.alpha_cu * (run.ref_winding - run.inputs.copper_reference)
    return t[:, 0] * factor + t[:, 1] / factor + t[:, 2], t[:, 3]


def _lag(signal: np.ndarray, tau: float, dt: float) -> np.ndarray:
    a = portable.exp(-dt / tau)
    return lfilter([1.0 - a], [1.0, -a], signal)


def _nonnegative_fit(columns: list[np.ndarray], target: np.ndarray) -> tuple[np.ndarray, float]:
    """Least squares with non-negative coefficients for the first two columns (the gains), by trying the subsets;
    the last column (the initial-rise decay) is free. Returns (coefficients, sum of squared errors)."""
    n = len(columns)
    gram = np.array([[portable.dot(a, b) for b in columns] for a in columns])
    rhs = np.array([portable.dot(a, target) for a in columns])
    total = portable.dot(target, target)
    best = (np.zeros(n), total)
    free = [n - 1] if gram[-1, -1] > 0 else []   # no initial rise in any run: no decay column
    for keep in ((0, 1), (0,), (1,)):
        idx = [*keep, *free]
        if any(gram[i, i] == 0.0 for i in idx):
            continue
        coef = portable.solve(gram[np.ix_(idx, idx)], rhs[idx])
        if any(coef[k] < 0 for k in range(len(keep))):
            continue
        full = np.zeros(n)
        full[idx] = coef
        sse = total - 2.0 * math.fsum(full * rhs) + math.fsum((full[:, None] * gram * full[None, :]).ravel())
        if sse < best[1]:
            best = (full, sse)
    return best


def node_response(runs: Sequence[ModelRun], node: str) -> NodeResponse:
    """The node's gains per W of stator and magnet loss and its time constant, pooled over the runs."""
    index = {"yoke": 0, "winding": 1, "tooth": 2, "pm": 3}[node]
    best = None
    for tau in TAU_GRID_S:
        cols, target = [[], [], []], []
        for run in runs:
            stator, magnet = node_losses(run)
            rise = run.reference(node) - run.inputs.coolant
            steps = (np.arange(len(rise)) + 1) * run.dt
            cols[0].append(_lag(stator, tau, run.dt))
            cols[1].append(_lag(magnet, tau, run.dt))
            cols[2].append((run.initial[index] - run.inputs.coolant[0]) * portable.exp_array(-steps / tau))
            target.append(rise)
        columns = [np.concatenate(c) for c in cols]
        coef, sse = _nonnegative_fit(columns, np.concatenate(target))
        if best is None or sse < best[0]:
            best = (sse, coef, tau, sum(len(t) for t in target))
    sse, coef, tau, count = best
    return NodeResponse(float(coef[0]), float(coef[1]), float(tau), math.sqrt(max(sse, 0.0) / count))


def auto_prior(runs: Sequence[ModelRun], nodes: Sequence[str], peak_torque_Nm: float) -> AutoPrior:
    """The starting network for `nodes` measured in `runs` (winding and PM at least)."""
    responses = {node: node_response(runs, node) for node in nodes}
    winding = responses["winding"]
    k_w = winding.gain_stator_K_per_W
    if not k_w > 0:
        raise BenchError("--prior auto: the measured winding temperature does not rise with the motor's losses in "
                         "the training files, so no network can be read from them; give a --prior file")
    fallbacks = []
    floor = MIN_SHARE * k_w
    r_cy0 = responses["yoke"].gain_stator_K_per_W if "yoke" in responses else JACKET_SHARE * k_w
    r_cy0 = min(max(r_cy0, floor), (1 - MIN_SHARE) * k_w)
    r_w = k_w - r_cy0
    machine_C = STORED_HEAT_PER_NM * peak_torque_Nm
    # the stator's capacitances from the time constants (step 3 of the module docstring)
    if "yoke" in responses and responses["yoke"].gain_stator_K_per_W > 0:
        c_stator = responses["yoke"].tau_s / r_cy0
        c_w = (winding.tau_s * k_w - c_stator * r_cy0 ** 2) / r_w ** 2
        c_w = min(max(c_w, 0.1 * c_stator), 0.6 * c_stator)
    else:
        c_stator = winding.tau_s * k_w / (r_cy0 ** 2 + STATOR_WINDING_SHARE * r_w ** 2)
        c_w = STATOR_WINDING_SHARE * c_stator
    pm = responses["pm"]
    k_m = pm.gain_magnet_K_per_W
    if k_m > r_cy0 * (1 + MIN_SHARE):
        r_rotor = k_m - r_cy0
        c_m = pm.tau_s / k_m
    else:   # no visible magnet-loss response: the rotor from the winding and the machine's size
        fallbacks.append("rotor")
        r_rotor = k_w
        c_m = 0.3 * machine_C
    a_rotor = ROTOR_PATHS * r_rotor
    iron = c_stator - c_w
    values = TABLE1.as_dict()
    values.update(
        C_y=YOKE_SHARE_OF_IRON * iron, C_w=c_w, C_t=(1 - YOKE_SHARE_OF_IRON) * iron, C_m=c_m,
        R_cy0=r_cy0, **{name: share * r_w for name, share in WINDING_SPLIT.items()},
        a_wm=a_rotor, a_tm=a_rotor, a_ma=a_rotor, R_wm0=a_rotor, R_tm0=a_rotor, R_ma0=a_rotor)
    if not all(math.isfinite(v) and v > 0 for k, v in values.items() if k.startswith(("C_", "R_", "a_"))):
        raise BenchError("--prior auto: the training files give no usable time constants and gains; give a "
                         "--prior file")
    return AutoPrior(LptnParameters(**values), responses, tuple(fallbacks))
