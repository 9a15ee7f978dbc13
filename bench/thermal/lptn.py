"""The fourth-order lumped-parameter thermal network (paper Fig. 4, eqs. 2, 9-25; REFERENCE.md §1).

States x = [yoke, winding, tooth, magnet] in °C. The LTI network takes u = [P_y, P_w, P_t, P_m, ϑ_cv, ϑ_av,
ϑ_a1, ϑ_a2]; the parameter-varying (PV) network of Fig. 4 (top) takes u = [P_y, P_w, P_t, P_m, ϑ_c, ϑ_a] with
speed- and coolant-dependent resistances. With the temperature sources of eqs. 9-18 evaluated at the current
state, both give the same heat flows.
"""

from __future__ import annotations

import numpy as np

from bench.thermal.parameters import COOLANT_REFERENCE_C, LptnParameters


def speed_varying_part(r0, b, speed_ratio):
    """R_xx1 of eq. 15: the speed-dependent part R0·exp(-(ω/ω_max)/b) of a convection resistance."""
    return r0 * np.exp(-np.asarray(speed_ratio) / b)


def coolant_varying_part(p: LptnParameters, coolant_c):
    """R_cy01 of eq. 16: the coolant-dependent part of the yoke-coolant resistance."""
    return p.R_cy0 * p.alpha_cy * (np.asarray(coolant_c) - COOLANT_REFERENCE_C)


def varying_resistances(p: LptnParameters, speed_ratio, coolant_c) -> dict[str, np.ndarray]:
    """The varying parts R_wm1, R_tm1, R_ma1, R_cy01 (eqs. 15-16); speed_ratio = ω/ω_max."""
    return {
        "R_wm1": speed_varying_part(p.R_wm0, p.b_wm, speed_ratio),
        "R_tm1": speed_varying_part(p.R_tm0, p.b_tm, speed_ratio),
        "R_ma1": speed_varying_part(p.R_ma0, p.b_ma, speed_ratio),
        "R_cy01": coolant_varying_part(p, coolant_c),
    }


def lti_matrices(p: LptnParameters) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Continuous A (4x4), B (4x8), C = I4, D = 0 of the LTI LPTN with temperature sources.

    The parameters may be arrays of one shape S (a batch of candidate models); A and B are then S + (4, 4|8).
    """
    shape = np.shape(p.C_y)
    a = np.zeros(shape + (4, 4))
    a[..., 0, 0] = -(1 / p.R_yw + 1 / p.R_yt + 1 / p.R_cy0) / p.C_y
    a[..., 0, 1], a[..., 0, 2] = 1 / (p.C_y * p.R_yw), 1 / (p.C_y * p.R_yt)
    a[..., 1, 0], a[..., 1, 1] = 1 / (p.C_w * p.R_yw), -(1 / p.R_yw + 1 / p.R_wt) / p.C_w
    a[..., 1, 2], a[..., 1, 3] = 1 / (p.C_w * p.R_wt), 1 / (p.C_w * p.a_wm)
    a[..., 2, 0], a[..., 2, 1] = 1 / (p.C_t * p.R_yt), 1 / (p.C_t * p.R_wt)
    a[..., 2, 2] = -(1 / p.R_yt + 1 / p.R_wt + 1 / p.a_tm) / p.C_t
    a[..., 3, 2], a[..., 3, 3] = 1 / (p.C_m * p.a_tm), -(1 / p.a_wm + 1 / p.a_ma) / p.C_m
    b = np.zeros(shape + (4, 8))
    b[..., 0, 0], b[..., 1, 1], b[..., 2, 2], b[..., 3, 3] = 1 / p.C_y, 1 / p.C_w, 1 / p.C_t, 1 / p.C_m
    b[..., 0, 4] = 1 / (p.C_y * p.R_cy0)
    b[..., 3, 5] = 1 / (p.C_m * p.a_ma)
    b[..., 2, 6], b[..., 3, 6] = 1 / (p.C_t * p.a_tm), -1 / (p.C_m * p.a_tm)
    b[..., 1, 7], b[..., 3, 7] = -1 / (p.C_w * p.a_wm), 1 / (p.C_m * p.a_wm)
    return a, b, np.eye(4), np.zeros((4, 8))


def temperature_sources(p: LptnParameters, x, speed_ratio, coolant_c, ambient_c) -> np.ndarray:
    """[ϑ_cv, ϑ_av, ϑ_a1, ϑ_a2] of eqs. 9-18 from the state x (…, 4); broadcasts over leading axes."""
    x = np.asarray(x, dtype=float)
    th_y, th_w, th_t, th_m = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
    r = varying_resistances(p, speed_ratio, coolant_c)
    g_tm, g_wm = r["R_tm1"] / p.a_tm, r["R_wm1"] / p.a_wm
    g_ma, g_cy = r["R_ma1"] / p.a_ma, r["R_cy01"] / p.R_cy0
    theta_a1 = (th_m + g_tm * th_t) / (1 + g_tm)                      # eq. 9
    theta_a2 = (th_w + g_wm * th_m) / (1 + g_wm)                      # eq. 10
    theta_ma = g_ma * (th_m - ambient_c) / (1 + g_ma)                 # eq. 13
    theta_cy = g_cy * (th_y - coolant_c) / (1 + g_cy)                 # eq. 14
    return np.stack([coolant_c + theta_cy, ambient_c + theta_ma, theta_a1, theta_a2], axis=-1)  # eqs. 17-18


def pv_matrices(p: LptnParameters, speed_ratio: float, coolant_c: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous A (4x4), B (4x6) of the parameter-varying LPTN (Fig. 4 top) at one operating point."""
    r = varying_resistances(p, speed_ratio, coolant_c)
    r_wm, r_tm, r_ma = r["R_wm1"] + p.a_wm, r["R_tm1"] + p.a_tm, r["R_ma1"] + p.a_ma
    r_cy = p.R_cy0 + r["R_cy01"]
    g = np.zeros((6, 6))  # conductances between nodes y, w, t, m, coolant, ambient
    for i, j, res in ((0, 1, p.R_yw), (0, 2, p.R_yt), (1, 2, p.R_wt), (1, 3, r_wm), (2, 3, r_tm),
                      (3, 5, r_ma), (0, 4, r_cy)):
        g[i, j] = g[j, i] = 1.0 / res
    caps = np.array([p.C_y, p.C_w, p.C_t, p.C_m])
    a = (g[:4, :4] - np.diag(g[:4].sum(axis=1))) / caps[:, None]
    b = np.zeros((4, 6))
    b[:, :4] = np.diag(1.0 / caps)
    b[:, 4:] = g[:4, 4:] / caps[:, None]
    return a, b


def continuous_eigenvalues(p: LptnParameters) -> np.ndarray:
    """Eigenvalues of the LTI A, sorted from fastest to slowest (all real and negative)."""
    eig = np.linalg.eigvals(lti_matrices(p)[0])
    return np.sort(eig.real)


def time_constants(p: LptnParameters) -> np.ndarray:
    """τ_i = -1/λ_i in seconds, shortest first."""
    return -1.0 / continuous_eigenvalues(p)
