"""The parameter-varying LPTN's continuous-time matrices from its resistances: one construction that the target's
model (in float32, as the firmware's pv_network) and the artifact loader's stability check (in float64) share."""

from __future__ import annotations

import numpy as np

from target_sim.fmath import lanes

COOLANT_REFERENCE_C = 40.0   # the coolant temperature R_cy0 is given at (eq. 16)

# (node i, node j, the parameter of their constant resistance) among (yoke, winding, tooth, magnet)
_FIXED_LINKS = ((0, 1, "R_yw"), (0, 2, "R_yt"), (1, 2, "R_wt"))


def network_matrices(p: dict, r_tm, r_wm, r_ma, r_cy, f=np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Continuous A (4x4) and B (4x6) of the LPTN, every operation in dtype `f`.

    g[i, j] is the conductance between nodes i and j of (yoke, winding, tooth, magnet, coolant, ambient);
    A[i, j] = g[i, j]/C_i off the diagonal, A[i, i] = -(row sum of g[i])/C_i with the row summed left to right over
    all six columns (the C's order), B = [diag(1/C) | g[:, 4:]/C_i]."""
    one = f(1.0)
    extra = np.shape(r_tm)                 # lanes of trajectories: every matrix gets trailing axes (L...)
    g = np.zeros((4, 6) + extra, dtype=f)
    links = [(i, j, p[name]) for i, j, name in _FIXED_LINKS] + [(1, 3, r_wm), (2, 3, r_tm)]
    for i, j, resistance in links:
        g[i, j] = g[j, i] = one / resistance
    g[3, 5], g[0, 4] = one / r_ma, one / r_cy
    inv_c = lanes(one / np.array([p["C_y"], p["C_w"], p["C_t"], p["C_m"]], dtype=f), r_tm)
    a = g[:, :4] * inv_c[:, None]
    row_sum = g[:, 0]
    for j in range(1, 6):
        row_sum = row_sum + g[:, j]
    a[np.diag_indices(4)] = -row_sum * inv_c
    b = np.zeros((4, 6) + extra, dtype=f)
    b[np.diag_indices(4)] = inv_c
    b[:, 4:] = g[:, 4:] * inv_c[:, None]
    return a, b
