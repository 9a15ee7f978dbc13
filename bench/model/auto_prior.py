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
2. Stator resistances. Stator heat leaves through the yoke to the coolant: R_cy0 = K_s(yoke) when the yoke is
   measured, else a third of the winding's K_s (the jacket's share of the winding rise in water-jacket machines:
   Table 1 and the IPM example both have about 1/3). The winding's and the tooth's rises above the yoke per W,
   R_w = K_s(winding) − R_cy0 and R_t = K_s(tooth) − R_cy0 (without a tooth sensor 0.6 R_w), fix the triangle
   R_yw, R_wt, R_yt (winding_split) with the copper's share of the stator loss in the winding, the tooth's share
   of the iron loss (1 − k_0) in the tooth, and two thirds of the copper heat crossing to the tooth (a slot has
   two tooth flanks and one bottom).
3. The rotor (rotor_response). The magnet's own loss is a few % of the stator's and moves with it, so its
   response to the magnet loss cannot be seen; what the data show is how the magnet follows its measured
   neighbours: ϑ_PM − ϑ_a ≈ LP_τ(w_w·(ϑ_w − ϑ_a) + w_t·(ϑ_t − ϑ_a) + K_m·P_magnet). The weights are the shares of
   the magnet's conductance G to winding, tooth and (the rest) ambient, K_m = 1/G and τ = C_m/G, so C_m = τ/K_m
   and each path's resistance is 1/(share·G) at the training data's mean speed, split into a fixed part a_xx and
   a speed-dependent part R_xx0 (AT_REST: R_xx0 = 10 a_xx where the rotor stirs the end-space air, winding and
   ambient; 1 × across the air gap, to the tooth).
4. Capacitances from the time constants: the stator charges through R_cy0 (C_stator = τ_yoke/R_cy0). The
   winding's own capacitance does not show in its single τ, which is the yoke's on every suite motor (the whole
   stator rises together); it shows in the winding's rise above the yoke (winding_response): after a copper step
   the winding first charges through its walls, ϑ_w − ϑ_y ≈ K_f·LP_τf(P_copper) + K_s·LP_τs(P_stator), and
   C_w = τf/K_f. (The earlier gain-weighted mix τ_w·K_w = C_stator·R_cy0² + C_w·R_w² gave C_w = C_stator·R_cy0/R_w
   when the two τ coincide, 4-5 × C_stator, and its 0.6 × C_stator clamp set C_w at 2-3.5 × the designers'.)
   Without a yoke sensor C_w is 35 % of the stator's. The stator's rest is split yoke 60 %, tooth 40 %.
5. What the data cannot show this way keeps the paper's values: the magnitudes of the speed exponents b_tm, b_ma
   (all positive: convection grows with speed; Table 1's b_ma < 0 would make the magnet's path to the air grow
   with speed, and a box in factors of the prior can never change that sign) and b_wm = b_ma (both paths cross the
   rotor-stirred end-space air; SPEED_EXPONENTS), the coolant coefficient alpha_cy and the stator split k_0…k_3
   (dimensionless, within fixed physical bounds).
6. Machine size is the fallback: when the magnet shows no response to its loss (K_m = 0), its capacitance comes
   from the peak torque (STORED_HEAT_PER_NM, J/K per Nm: torque scales with rotor volume, heat capacity with
   mass) and G = C_m/τ.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

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
# The copper heat leaves the slot through its three walls: two tooth flanks and the slot bottom (yoke), so two
# thirds of it go through the tooth. (A fixed split R_yw : R_wt : R_yt = 1.25 : 5 : 0.5 put the tooth's rise at
# 0.09 × the winding's; the suite motors' training data show 0.51-0.75 ×.)
SLOT_FLANK_SHARE = 2.0 / 3.0
TOOTH_RISE_SHARE = 0.6          # tooth's rise above the yoke / the winding's, without a tooth sensor
TOOTH_RISE_LIMITS = (0.1, 0.9)  # a measured share outside is noise or a hotter tooth the split cannot place
ROTOR_MIN_SHARE = 0.05          # no rotor path below 5 % of the magnet's conductance (an NNLS zero)
ROTOR_SHARE_OF_MACHINE = 0.3    # C_m / machine_C without a visible magnet-loss response
ROTOR_C_LIMITS = (0.05, 3.0)    # C_m from the data within these × machine_C (a tiny magnet gain: a huge C_m)
# The speed exponents keep Table 1's magnitudes but are positive: R_xx1 = R_xx0·exp(−(ω/ω_max)/b) falls with speed
# only for b > 0, as convection does (more air movement, more heat transfer). Table 1's b_ma = −0.176 makes the
# magnet-ambient resistance grow ~300× at full speed, and a box in factors of the prior never changes a sign.
# The winding-magnet path takes the magnet-air path's exponent, not Table 1's b_wm = 0.968: both cross the same
# end-space air that the rotor stirs (AT_REST treats them alike), so their convection follows one function of the
# speed. 0.968 kept 36 % of the at-rest part at full speed where the suite's plants lose all but 0.1 % (their
# lumped b_wm 0.14-0.15, end-space h = k1·(1 + k2·v^k3)); the magnitude is Table 1's b_ma, 0.176.
SPEED_EXPONENTS = {"b_wm": abs(TABLE1.b_ma), "b_tm": abs(TABLE1.b_tm), "b_ma": abs(TABLE1.b_ma)}
# R_xx0 / a_xx, the path's resistance at rest over the part that stays at speed: the winding and the air reach the
# magnet through the end-space air, which the rotor stirs (at rest natural convection only, h ≈ 5-10 W/m²K; forced
# by the rotor about ten times that), the tooth across the air gap, which a thin gap's conduction bridges at rest too
AT_REST = {"wm": 10.0, "tm": 1.0, "ma": 10.0}
STATOR_WINDING_SHARE = 0.35     # C_w / C_stator without a yoke sensor
WINDING_SHARE_LIMITS = (0.05, 0.6)  # C_w / C_stator from the data kept within (the suite's plants: 0.24-0.36)
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
        return asdict(self)


@dataclass(frozen=True)
class RotorResponse:
    """The magnet's first-order response to its measured neighbours and its own loss (rotor_response)."""

    weight_winding: float
    weight_tooth: float
    gain_magnet_K_per_W: float
    tau_s: float
    rmse_C: float

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class WindingResponse:
    """The winding's rise above the yoke: a fast lag of the copper loss (the winding charging through its own walls)
    and a slow one of the whole stator loss (the tooth's and the yoke's part), winding_response."""

    gain_fast_K_per_W: float
    tau_fast_s: float
    gain_slow_K_per_W: float
    tau_slow_s: float
    rmse_C: float

    @property
    def capacity_J_per_K(self) -> float:
        """C_w = τ_fast / R_fast: the fast mode is the winding's capacitance charging through its resistance to
        the (much heavier, nearly still) iron around it."""
        return self.tau_fast_s / self.gain_fast_K_per_W

    def as_dict(self) -> dict:
        return {**asdict(self), "capacity_J_per_K": self.capacity_J_per_K}


@dataclass(frozen=True)
class AutoPrior:
    parameters: LptnParameters
    responses: dict[str, NodeResponse]
    rotor: RotorResponse
    winding: WindingResponse | None  # the winding's fast response above the yoke (None: no yoke sensor, or no fit)
    fallbacks: tuple[str, ...]       # what came from machine size instead of the data


def copper_loss(run: ModelRun) -> np.ndarray:
    """The copper loss per step (W) at the measured winding temperature (eqs. 3-4)."""
    t = run.inputs.table_losses
    factor = 1.0 + run.inputs.alpha_cu * (run.ref_winding - run.inputs.copper_reference)
    return t[:, 0] * factor + t[:, 1] / factor


def node_losses(run: ModelRun) -> tuple[np.ndarray, np.ndarray]:
    """(stator, magnet) loss per step, W: copper at the measured winding temperature (eqs. 3-4) plus iron."""
    t = run.inputs.table_losses
    return copper_loss(run) + t[:, 2], t[:, 3]


def _lag(signal: np.ndarray, tau: float, dt: float) -> np.ndarray:
    a = portable.exp(-dt / tau)
    return lfilter([1.0 - a], [1.0, -a], signal)


def _nonnegative_fit(columns: list[np.ndarray], target: np.ndarray) -> tuple[np.ndarray, float]:
    """Least squares with non-negative coefficients for all columns but the last (the gains), by trying the
    subsets; the last column (the initial-rise decay) is free. Returns (coefficients, sum of squared errors)."""
    gram = np.array([[portable.dot(a, b) for b in columns] for a in columns])
    rhs = np.array([portable.dot(a, target) for a in columns])
    return _nonnegative_solve(gram, rhs, portable.dot(target, target))


def _nonnegative_solve(gram: np.ndarray, rhs: np.ndarray, total: float) -> tuple[np.ndarray, float]:
    """_nonnegative_fit from the columns' Gram matrix, their products with the target and its square sum."""
    n = len(rhs)
    best = (np.zeros(n), total)
    free = [n - 1] if gram[-1, -1] > 0 else []   # no initial rise in any run: no decay column
    subsets = [keep for size in range(n - 1, 0, -1) for keep in itertools.combinations(range(n - 1), size)]
    for keep in subsets:
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


def rotor_response(runs: Sequence[ModelRun], with_tooth: bool) -> RotorResponse:
    """The magnet as one node between the measured stator and the ambient air (module docstring, step 3), pooled
    over the runs: ϑ_PM − ϑ_a ≈ LP_τ(w_w·(ϑ_w − ϑ_a) + w_t·(ϑ_t − ϑ_a) + K_m·P_magnet) + r0·e^(−t/τ).

    Why the measured temperatures and not the losses: the magnet is heated mostly across the air gap by the
    stator, and its own loss is a few % of the stator's and moves with it, so a fit to the losses cannot tell the
    two apart (no suite motor showed a magnet-loss gain). Its steady state is the conductance-weighted mean of its
    neighbours plus P_m/G, so w_w = g_wm/G, w_t = g_tm/G, the ambient's share is 1 − w_w − w_t, K_m = 1/G and
    τ = C_m/G, with G the sum of the magnet's conductances. Without a tooth sensor w_t = 0 (the winding stands for
    the stator)."""
    best = None
    for tau in TAU_GRID_S:
        drives = [[] for _ in range(3 if with_tooth else 2)]     # winding, (tooth,) magnet loss
        decay, target = [], []
        for run in runs:
            ambient = run.inputs.ambient
            steps = (np.arange(len(ambient)) + 1) * run.dt
            neighbours = [run.ref_winding, run.ref_tooth] if with_tooth else [run.ref_winding]
            for column, node in zip(drives[:-1], neighbours, strict=True):
                column.append(_lag(node - ambient, tau, run.dt))
            drives[-1].append(_lag(node_losses(run)[1], tau, run.dt))
            decay.append((run.initial[3] - ambient[0]) * portable.exp_array(-steps / tau))
            target.append(run.ref_pm - ambient)
        columns = [np.concatenate(c) for c in (*drives, decay)]
        coef, sse = _nonnegative_fit(columns, np.concatenate(target))
        if best is None or sse < best[0]:
            best = (sse, coef, tau, sum(len(t) for t in target))
    sse, coef, tau, count = best
    tooth = float(coef[1]) if with_tooth else 0.0
    return RotorResponse(float(coef[0]), tooth, float(coef[-2]), float(tau), math.sqrt(max(sse, 0.0) / count))


def winding_response(runs: Sequence[ModelRun]) -> WindingResponse | None:
    """ϑ_w − ϑ_y ≈ K_fast·LP_τf(P_copper) + K_slow·LP_τs(P_stator) + r0·e^(−t/τf), τf < τs on TAU_GRID_S, pooled
    over the runs (module docstring, step 4). Why the difference: the winding's single lag (node_response) is its
    slow rise with the whole stator, the same τ as the yoke's, and says nothing of the winding's own capacitance; the
    difference takes the yoke's slow rise out, so what is left after a copper step is first the winding charging
    through its walls (τf = C_w·R_fast), then the tooth's slower part. None when no fit gives a positive fast gain."""
    columns = []    # per τ of the grid: the copper loss's lag, the stator loss's lag, the initial difference's decay
    for tau in TAU_GRID_S:
        columns += [np.concatenate([_lag(copper_loss(run), tau, run.dt) for run in runs]),
                    np.concatenate([_lag(node_losses(run)[0], tau, run.dt) for run in runs]),
                    np.concatenate([(run.initial[1] - run.initial[0]) * portable.exp_array(
                        -(np.arange(len(run.ref_winding)) + 1) * run.dt / tau) for run in runs])]
    target = np.concatenate([run.ref_winding - run.ref_yoke for run in runs])
    every = np.column_stack([*columns, target])
    gram = portable.matmul(every.T, every)     # all products at once (a fixed summation order: same bits anywhere)
    best = None
    for (i, fast), (j, slow) in itertools.combinations(enumerate(TAU_GRID_S), 2):   # ascending grid: fast < slow
        pick = [3 * i, 3 * j + 1, 3 * i + 2]
        coef, sse = _nonnegative_solve(gram[np.ix_(pick, pick)], gram[pick, -1], gram[-1, -1])
        if coef[0] > 0 and (best is None or sse < best[0]):
            best = (sse, coef, fast, slow)
    if best is None:
        return None
    sse, coef, fast, slow = best
    return WindingResponse(float(coef[0]), fast, float(coef[1]), slow, math.sqrt(max(sse, 0.0) / len(target)))


def winding_split(rise_winding: float, rise_tooth: float, copper_share: float, tooth_iron_share: float
                  ) -> dict[str, float]:
    """R_yw, R_wt, R_yt of the stator triangle that gives the winding and the tooth their steady rises above the
    yoke (K/W per W of stator loss), with `copper_share` of the loss in the winding, `tooth_iron_share` in the tooth
    and SLOT_FLANK_SHARE of the copper heat crossing to the tooth (the rest straight to the yoke)."""
    low, high = TOOTH_RISE_LIMITS
    rise_tooth = min(max(rise_tooth, low * rise_winding), high * rise_winding)
    copper = max(copper_share, MIN_SHARE)
    through_tooth = SLOT_FLANK_SHARE * copper
    return {"R_yw": rise_winding / (copper - through_tooth),
            "R_wt": (rise_winding - rise_tooth) / through_tooth,
            "R_yt": rise_tooth / (through_tooth + tooth_iron_share)}


def copper_share(runs: Sequence[ModelRun]) -> float:
    """The copper losses' share of the stator losses over the training runs."""
    copper = stator = 0.0
    for run in runs:
        copper += math.fsum(copper_loss(run))
        stator += math.fsum(node_losses(run)[0])
    return copper / stator if stator > 0 else 1.0


def rotor_paths(rotor: RotorResponse, conductance: float, speed_ratio: float) -> dict[str, float]:
    """R_xx0 and a_xx of the three magnet paths from the magnet's conductance G (W/K) and its neighbours' shares,
    at the training data's mean speed ratio: R(ω) = R_xx0·exp(−ω/b) + a_xx with R_xx0 = AT_REST × a_xx. Without a
    tooth sensor the stator's share is split evenly between winding and tooth."""
    stator = rotor.weight_winding + rotor.weight_tooth
    shares = {"wm": rotor.weight_winding, "tm": rotor.weight_tooth} if rotor.weight_tooth > 0 else \
        {"wm": stator / 2, "tm": stator / 2}
    shares["ma"] = 1.0 - stator
    values = {}
    for path, share in shares.items():
        resistance = 1.0 / (max(share, ROTOR_MIN_SHARE) * conductance)
        fixed = resistance / (1.0 + AT_REST[path] * portable.exp(-speed_ratio / SPEED_EXPONENTS[f"b_{path}"]))
        values.update({f"R_{path}0": AT_REST[path] * fixed, f"a_{path}": fixed})
    return values


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
    fast = None
    if "yoke" in responses and responses["yoke"].gain_stator_K_per_W > 0:
        c_stator = responses["yoke"].tau_s / r_cy0
        fast = winding_response(runs)
        if fast is not None:
            c_w = fast.capacity_J_per_K
        else:   # the gain-weighted mix of the two time constants (its C_w is poor when they coincide)
            fallbacks.append("winding heat capacity")
            c_w = (winding.tau_s * k_w - c_stator * r_cy0 ** 2) / r_w ** 2
        low, high = WINDING_SHARE_LIMITS
        c_w = min(max(c_w, low * c_stator), high * c_stator)
    else:
        c_stator = winding.tau_s * k_w / (r_cy0 ** 2 + STATOR_WINDING_SHARE * r_w ** 2)
        c_w = STATOR_WINDING_SHARE * c_stator
    r_t = responses["tooth"].gain_stator_K_per_W - r_cy0 if "tooth" in responses else TOOTH_RISE_SHARE * r_w
    copper = copper_share(runs)
    split = winding_split(r_w, r_t, copper, (1.0 - copper) * (1.0 - TABLE1.k_0))
    rotor = rotor_response(runs, "tooth" in responses)
    c_m_limits = tuple(share * machine_C for share in ROTOR_C_LIMITS)
    if rotor.gain_magnet_K_per_W > 0:
        c_m = min(max(rotor.tau_s / rotor.gain_magnet_K_per_W, c_m_limits[0]), c_m_limits[1])
    else:   # no visible magnet-loss response: the magnet's heat capacity from the machine's size
        fallbacks.append("rotor heat capacity")
        c_m = ROTOR_SHARE_OF_MACHINE * machine_C
    speed = math.fsum(math.fsum(run.inputs.speed_ratio) for run in runs) / sum(len(r.inputs.speed_ratio) for r in runs)
    iron = c_stator - c_w
    values = TABLE1.as_dict()
    values.update(
        C_y=YOKE_SHARE_OF_IRON * iron, C_w=c_w, C_t=(1 - YOKE_SHARE_OF_IRON) * iron, C_m=c_m,
        R_cy0=r_cy0, **split, **rotor_paths(rotor, c_m / rotor.tau_s, speed), **SPEED_EXPONENTS)
    if not all(math.isfinite(v) and v > 0 for k, v in values.items() if k.startswith(("C_", "R_", "a_", "b_"))):
        raise BenchError("--prior auto: the training files give no usable time constants and gains; give a "
                         "--prior file")
    return AutoPrior(LptnParameters(**values), responses, rotor, fast, tuple(fallbacks))
