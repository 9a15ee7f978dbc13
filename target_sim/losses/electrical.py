"""The electrical loss model: losses from the measured d/q currents and the speed, for a motor without maps
(f = pp·|n|/60, I² = i_d² + i_q², p_dc0 = (1.5·R)·I², p_ac0 = p_dc0·(k_ac·(f/f_ac)²),
p_stator = (P_h·(f/f_fe) + P_e·(f/f_fe)²)·(1 + c_I·(I/I_max)²), p_magnet = (P_m·(f/f_m)²)·(c0 + (1 - c0)·I/I_max)²).
The artifact's `losses` holds one scalar per coefficient (`COEFFICIENTS`); the data rows carry the currents."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from target_sim.losses import LossKind, register

COEFFICIENTS = ("pole_pairs", "stator_resistance_ohm", "ac_factor", "ac_reference_Hz", "iron_hysteresis_W",
                "iron_eddy_W", "iron_reference_Hz", "iron_current_factor", "magnet_W", "magnet_reference_Hz",
                "magnet_no_load_share")


class ElectricalEvaluator:
    """The formulas in float32, in the order the C writes them (C: electrical_losses); the same formulas as
    bench.motor.losses.electrical.ElectricalLosses in float64."""

    def __init__(self, artifact, dtype=np.float32):
        self.f = f = np.dtype(dtype).type
        self.c = {name: artifact.array("losses", name, dtype=f)[()] for name in COEFFICIENTS}
        self.current_max = artifact.array("losses", "current_max_A", dtype=f)[()]
        self.sqrt = np.sqrt

    def lookup(self, speed, i_d, i_q) -> np.ndarray:
        """[p_dc0, p_ac0, p_stator, p_magnet, current] at one operating point."""
        c, f = self.c, self.f
        one = f(1.0)
        speed, i_d, i_q = f(speed), f(i_d), f(i_q)
        freq = (c["pole_pairs"] * abs(speed)) / f(60.0)
        i2 = i_d * i_d + i_q * i_q
        current = self.sqrt(i2)
        ratio = current / self.current_max
        p_dc0 = (f(1.5) * c["stator_resistance_ohm"]) * i2
        f_ac = freq / c["ac_reference_Hz"]
        p_ac0 = p_dc0 * (c["ac_factor"] * (f_ac * f_ac))
        f_fe = freq / c["iron_reference_Hz"]
        p_stator = (c["iron_hysteresis_W"] * f_fe + c["iron_eddy_W"] * (f_fe * f_fe)) * (
            one + c["iron_current_factor"] * (ratio * ratio))
        f_m = freq / c["magnet_reference_Hz"]
        m = c["magnet_no_load_share"] + (one - c["magnet_no_load_share"]) * ratio
        p_magnet = (c["magnet_W"] * (f_m * f_m)) * (m * m)
        return np.array([p_dc0, p_ac0, p_stator, p_magnet, current], dtype=f)


_C_CODE = """\
/* sqrt and |x| in float32: the FPU's VSQRT.F32 (correctly rounded, as np.sqrt on float32) and VABS.F32. GCC and
 * clang lower the builtins to the instructions (with -fno-math-errno: no libm call, no errno); another compiler
 * gets C99's sqrtf and fabsf, which Annex F (IEC 60559) requires to be exact too. */
#if defined(__GNUC__)
#define FW_SQRTF(x) __builtin_sqrtf(x)
#define FW_FABSF(x) __builtin_fabsf(x)
#else
#include <math.h>
#define FW_SQRTF(x) sqrtf(x)
#define FW_FABSF(x) fabsf(x)
#endif

/* ElectricalLosses.lookup: [p_dc0, p_ac0, p_stator, p_magnet, current] from the speed and the d/q currents:
 * f = pp |n| / 60, I^2 = i_d^2 + i_q^2, I = sqrt(I^2), p_dc0 = (1.5 R) I^2, p_ac0 = p_dc0 (k_ac (f/f_ac)^2),
 * p_stator = (P_h (f/f_fe) + P_e (f/f_fe)^2) (1 + c_I (I/I_max)^2),
 * p_magnet = (P_m (f/f_m)^2) (c0 + (1 - c0) I/I_max)^2; every sum and product in this order, as in Python */
static void electrical_losses(float speed, float i_d, float i_q, float out[LOSS_TABLE_COUNT])
{
    const float freq = (POLE_PAIRS * FW_FABSF(speed)) / 60.0f;
    const float i2 = i_d * i_d + i_q * i_q;
    const float current = FW_SQRTF(i2);
    const float ratio = current / CURRENT_MAX;
    const float p_dc0 = (1.5f * STATOR_RESISTANCE_OHM) * i2;
    const float f_ac = freq / AC_REFERENCE_HZ;
    const float p_ac0 = p_dc0 * (AC_FACTOR * (f_ac * f_ac));
    const float f_fe = freq / IRON_REFERENCE_HZ;
    const float p_stator = (IRON_HYSTERESIS_W * f_fe + IRON_EDDY_W * (f_fe * f_fe)) * (
        1.0f + IRON_CURRENT_FACTOR * (ratio * ratio));
    const float f_m = freq / MAGNET_REFERENCE_HZ;
    const float m = MAGNET_NO_LOAD_SHARE + (1.0f - MAGNET_NO_LOAD_SHARE) * ratio;
    out[0] = p_dc0;
    out[1] = p_ac0;
    out[2] = p_stator;
    out[3] = (MAGNET_W * (f_m * f_m)) * (m * m);
    out[4] = current;
}
"""


class ElectricalKind(LossKind):
    name = "electrical"
    inputs = ("speed_rpm", "i_d_A", "i_q_A")
    summary = "losses from the d/q currents and the speed; the torque is not used"
    c_function = "electrical_losses"
    c_words = "electrical loss model"
    c_code = _C_CODE

    def fields(self, losses: Mapping[str, Any]) -> list[tuple[str, ...]]:
        return [(name,) for name in COEFFICIENTS]

    def evaluator(self, artifact, dtype=np.float32) -> ElectricalEvaluator:
        return ElectricalEvaluator(artifact, dtype)

    def c_scalars(self, artifact) -> list[tuple[str, tuple[str, ...] | np.float32, str]]:
        return [(name.upper(), ("losses", name), f"losses.{name}") for name in COEFFICIENTS]

    def ops(self, op: Callable[..., Counter]) -> Counter:
        """[p_dc0, p_ac0, p_stator, p_magnet, I] from the d/q currents and the speed; a square root counts as a
        divide (EISQRTF32 estimate + two Newton-Raphson steps, as fastRTS's sqrtf)."""
        frequency = op(multiply=1, divide=1, add=1)     # f = (pp·|n|)/60, |n| as a compare
        current = op(multiply=2, add=1, divide=2)       # I² = i_d² + i_q², I = √I² (a divide's cost), I/I_max
        copper = op(multiply=2 + 3, divide=1)           # p_dc0 = (1.5·R)·I²; p_ac0 = p_dc0·(k_ac·(f/f_ac)²)
        iron = op(multiply=6, add=2, divide=1)          # (P_h·f_fe + P_e·f_fe²)·(1 + c_I·ratio²)
        magnet = op(multiply=5, add=2, divide=1)        # (P_m·f_m²)·(c0 + (1 - c0)·ratio)²
        reads = op(load_store=len(COEFFICIENTS) + 2 + 3 + 5)   # coefficients, I_max, inputs, results
        return frequency + current + copper + iron + magnet + reads + op(call=1)

    def coefficient_count(self, artifact) -> int:
        return len(COEFFICIENTS)


register(ElectricalKind())
