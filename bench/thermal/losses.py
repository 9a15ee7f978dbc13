"""The loss model of paper eqs. 3-8: copper dc/ac losses with temperature and the stator loss split."""

from __future__ import annotations

import numpy as np

from bench.thermal.parameters import ALPHA_CU_PER_K, LptnParameters

COPPER_REFERENCE_C = 20.0  # ϑ_ref of eqs. 3-4: the temperature the loss maps were computed at


def copper_losses(p_dc0, p_ac0, winding_c, reference_c: float = COPPER_REFERENCE_C, alpha: float = ALPHA_CU_PER_K):
    """P_w = P_w,dc(ϑ_w) + P_w,ac(ϑ_w) (eqs. 3-5): dc rises with resistance, ac (eddy) falls with it."""
    factor = 1.0 + alpha * (np.asarray(winding_c) - reference_c)
    return np.asarray(p_dc0) * factor + np.asarray(p_ac0) / factor


def stator_split_factor(p: LptnParameters, current_ratio, speed_ratio):
    """k_s(I, ω) of eq. 8, the share of the stator iron loss that goes to the yoke."""
    i, w = np.asarray(current_ratio), np.asarray(speed_ratio)
    return p.k_0 + p.k_1 * i + p.k_2 * w + p.k_3 * i * w


def split_stator_losses(p: LptnParameters, p_stator, current_ratio, speed_ratio):
    """(P_y, P_t) of eqs. 6-7."""
    k = stator_split_factor(p, current_ratio, speed_ratio)
    return k * np.asarray(p_stator), (1.0 - k) * np.asarray(p_stator)


def node_losses(p: LptnParameters, p_dc0, p_ac0, p_stator, p_magnet, current_ratio, speed_ratio, winding_c):
    """[P_y, P_w, P_t, P_m] (…, 4) from map losses at the reference temperature and the winding temperature."""
    p_y, p_t = split_stator_losses(p, p_stator, current_ratio, speed_ratio)
    p_w = copper_losses(p_dc0, p_ac0, winding_c)
    return np.stack(np.broadcast_arrays(p_y, p_w, p_t, np.asarray(p_magnet, dtype=float)), axis=-1)
