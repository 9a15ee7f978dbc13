"""A designer's prior for a distributed plant: its network lumped into the bench's four nodes (yoke, winding, tooth,
magnet), as the 22 parameters of the LPTN `bench identify` fits.

Groups: yoke = yoke layers, housing and end caps; winding = slot halves and end windings; tooth = tips and bodies;
magnet = magnets, rotor iron, shaft and bearings. The coolant cells and the end-space air are internal nodes (part
of the paths to the boundaries).
- capacitances: the sums over each group;
- conductances: a steady-state fit onto the groups' capacitance-weighted mean temperatures. Each group's loss
  (placed as the plant places it: copper by conductor length, iron by flux density, magnet loss over the segments)
  is injected alone with both boundaries at 0 °C; the mean rises form a 4x4 thermal resistance matrix. The seven
  conductances of the four-node topology (yoke-winding, yoke-tooth, winding-tooth, winding-magnet, tooth-magnet,
  yoke-coolant, magnet-ambient) are fitted so that the four-node network's resistance matrix matches it in the
  least-squares sense of the log ratios of its 16 entries (paths the topology has no place for, such as tooth to
  coolant, end up in the nearest ones); the worst remaining ratio is reported.
- speed: the magnet's paths (R_wm, R_tm, R_ma) at 0, ½ and 1 × the top speed, fitted exactly by eq. 15's
  R = a + R0·exp(-ω/(b ω_max)); the stator paths at half the top speed.
- coolant: R_cy at 40 °C (the reference of eq. 16) and α_cy from 20 and 60 °C.
- the stator iron split k_s (eq. 8): the plant's yoke share of the iron loss, constant (k_1 = k_2 = k_3 = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.drive.virtual.plants.distributed import DistributedPlant
from bench.thermal.parameters import COOLANT_REFERENCE_C, LptnParameters
from dbc.contract import TEMPERATURE_NODES

GROUPS = {"yoke": ("yoke_in", "yoke_back", "housing", "cap"), "winding": ("w_bot", "w_top", "ew"),
          "tooth": ("tip", "body"), "magnet": ("magnet", "rotor", "shaft", "bearing")}
ORDER = TEMPERATURE_NODES
SPEED_RATIOS = (0.0, 0.5, 1.0)
COOLANT_SPAN_K = 20.0
RESISTANCE_CAP = 20.0        # a speed-dependent resistance at most this many times its value at half speed


@dataclass(frozen=True)
class LumpedPrior:
    parameters: LptnParameters
    fit_error: dict[str, float]       # worst |log ratio| of the resistance matrix entries per fitted point, as a %

    def as_dict(self) -> dict:
        return {"parameters": {k: float(f"{v:.4g}") for k, v in self.parameters.as_dict().items()},
                "fit_error_percent": {k: round(v, 1) for k, v in self.fit_error.items()}}


def group_nodes(plant: DistributedPlant) -> dict[str, list[int]]:
    return {group: [i for layer in layers for i in plant.ids[layer]] for group, layers in GROUPS.items()}


def _injections(plant: DistributedPlant, nodes: dict[str, list[int]]) -> np.ndarray:
    """(n, 4): one column per group, its loss as the plant places it, 1 W in all."""
    size = plant.net.size
    out = np.zeros((size, 4))
    out[plant.copper_nodes, 1] = plant.dc_share
    for col, group in ((0, "yoke"), (2, "tooth")):
        share = np.zeros(size)
        share[nodes[group]] = plant.iron[nodes[group]]
        out[:, col] = share / share.sum()
    out[:, 3] = plant.magnet
    return out


def resistances(plant: DistributedPlant, speed_rpm: float, coolant_C: float) -> np.ndarray:
    """(4, 4): the groups' mean temperature rises (K) per W of each group's loss, both boundaries at 0 °C."""
    nodes = group_nodes(plant)
    caps = plant.net.capacitances
    mean = np.zeros((4, plant.net.size))
    for row, group in enumerate(ORDER):
        mean[row, nodes[group]] = caps[nodes[group]] / caps[nodes[group]].sum()
    g, _ = plant.matrices(speed_rpm, coolant_C)
    return mean @ np.linalg.solve(-g, _injections(plant, nodes))


# the seven conductances of the four-node topology: (i, j) between nodes, (i, None) to a boundary
LINKS = {"yw": (0, 1), "yt": (0, 2), "wt": (1, 2), "wm": (1, 3), "tm": (2, 3), "cy": (0, None), "ma": (3, None)}


def _four_node(g: np.ndarray) -> np.ndarray:
    k = np.zeros((4, 4))
    for value, (i, j) in zip(g, LINKS.values(), strict=True):
        k[i, i] += value
        if j is not None:
            k[j, j] += value
            k[i, j] -= value
            k[j, i] -= value
    return np.linalg.inv(k)


def fit(target: np.ndarray) -> tuple[dict[str, float], float]:
    """The seven conductances (W/K) whose four-node resistance matrix best matches target, and the worst |log
    ratio| left."""
    from scipy.optimize import least_squares

    def residual(log_g):
        return np.log(np.abs(_four_node(np.exp(log_g))) / np.abs(target)).ravel()

    start = np.log(np.full(len(LINKS), 1.0 / np.mean(np.diag(target))))
    solution = least_squares(residual, start, method="lm", xtol=1e-12, ftol=1e-12)
    return dict(zip(LINKS, np.exp(solution.x).tolist(), strict=True)), float(np.abs(residual(solution.x)).max())


def _speed_fit(values: list[float]) -> tuple[float, float, float]:
    """(R0, a, b) of R(w) = a + R0·exp(-w/b) through R at w = 0, ½, 1 (b < 0: the resistance grows with speed)."""
    y0, y1, y2 = values
    q = (y1 - y2) / (y0 - y1) if y0 != y1 else 0.0
    if q <= 0.0 or abs(q - 1.0) < 1e-9:        # no exponential passes through the three: keep the ends' trend
        q = 0.5 if y0 >= y2 else 2.0
        r0 = (y0 - y2) / (1.0 - q * q)
    else:
        r0 = (y0 - y1) / (1.0 - q)
    b = -0.5 / math.log(q)
    a = y0 - r0
    if a <= 0.0:                               # the LPTN needs a positive constant part
        a = 0.05 * min(values)
        r0 = y0 - a
    return r0, a, b


def designer_prior(plant: DistributedPlant, speed_max_rpm: float) -> LumpedPrior:
    """The 22 LPTN parameters of the plant, lumped (see the module's docstring)."""
    nodes = group_nodes(plant)
    caps = plant.net.capacitances
    c = {group: float(caps[nodes[group]].sum()) for group in ORDER}
    errors, by_speed = {}, []
    for w in SPEED_RATIOS:
        g, worst = fit(resistances(plant, w * speed_max_rpm, COOLANT_REFERENCE_C))
        by_speed.append(g)
        errors[f"speed {w:g}"] = 100.0 * worst
    mid = by_speed[SPEED_RATIOS.index(0.5)]
    values = {f"R_{name}": 1.0 / mid[name] for name in ("yw", "yt", "wt")}
    for name in ("wm", "tm", "ma"):        # a path that vanishes at some speed: capped, as a designer would
        series = [min(1.0 / g[name], RESISTANCE_CAP / mid[name]) for g in by_speed]
        values[f"R_{name}0"], values[f"a_{name}"], values[f"b_{name}"] = _speed_fit(series)
    r_cy = 1.0 / mid["cy"]
    r_lo, r_hi = (1.0 / fit(resistances(plant, 0.5 * speed_max_rpm, COOLANT_REFERENCE_C + s))[0]["cy"]
                  for s in (-COOLANT_SPAN_K, COOLANT_SPAN_K))
    values.update(R_cy0=r_cy, alpha_cy=(r_hi - r_lo) / (2.0 * COOLANT_SPAN_K * r_cy))
    values.update(C_y=c["yoke"], C_w=c["winding"], C_t=c["tooth"], C_m=c["magnet"],
                  k_0=plant.yoke_share, k_1=0.0, k_2=0.0, k_3=0.0)
    return LumpedPrior(LptnParameters(**{n: float(values[n]) for n in LptnParameters.names()}), errors)
