"""The winding temperature from the stator resistance (steady-state d-axis voltage of a PM synchronous machine).

u_d = R_s(ϑ_w) i_d - ω_e L_q i_q, so R̂_s = (u_d + ω_e L_q i_q)/i_d, and R_s(ϑ_w) = R_s0 (1 + α_cu (ϑ_w - ϑ_cu))
gives ϑ_w = ϑ_cu + (R̂_s/R_s0 - 1)/α_cu. It reads the winding node. The resistance's voltage is small beside the
speed voltage, so it is valid only at or below speed_max_rpm (the error of ω_e L_q i_q grows with the speed) and
where |i_d| is at least current_min_A: a voltage error δu gives a temperature error δu/(i_d R_s0 α_cu), so its
variance R = R_floor + R_current (i_min/i_d)² grows as |i_d| falls, both fitted to the calibration residual by the
lab (`bench observer --resistance`). Its raw channels are the flux linkage's (u_d, u_q, i_d, i_q; u_q only travels
with u_d in DriveVoltages and makes a step invalid when it is), and it answers in the `sensor` slot, as any reading
of the winding (`target_sim.observer.node`).
"""

from __future__ import annotations

import numpy as np

from target_sim.observer.measurements import MEASUREMENT_KINDS, MeasurementKind
from target_sim.observer.measurements._voltages import RAD_S_PER_RPM, VoltageReading

PARAMETERS = ("R_s_ohm", "alpha_cu_per_K", "copper_reference_C", "L_q_H", "pole_pairs", "speed_max_rpm",
              "current_min_A", "R_floor_C2", "R_current_C2")

# the generated C of `reading`, operation for operation (bench.firmware.observergen; _K is the measurement's index
# there, raw its four channels u_d, u_q, i_d, i_q, speed the step's mean speed)
C_READING = """\
/* WindingResistance.reading: R_s = (u_d + omega_e L_q i_q) / i_d, the winding temperature of R_s, and the variance
 * R_floor + R_current (i_min / i_d)^2; no reading above the speed limit, below the current or with a NaN channel */
static int obs_reading_K(const float raw[4], float speed, float *value, float *r)
{
    float omega, r_s, ratio;
    if (!(obs_finite(raw[0]) && obs_finite(raw[1]) && obs_finite(raw[2]) && obs_finite(raw[3]))) return 0;
    if (!(__builtin_fabsf(speed) <= OBS_SPEED_MAX_K)) return 0;
    if (!(__builtin_fabsf(raw[2]) >= OBS_CURRENT_MIN_K)) return 0;
    omega = OBS_OMEGA_PER_RPM_K * speed;
    r_s = (raw[0] + omega * OBS_L_Q_K * raw[3]) / raw[2];
    *value = OBS_COPPER_REF_K + (r_s / OBS_R_S_K - 1.0f) / OBS_ALPHA_CU_K;
    ratio = OBS_CURRENT_MIN_K / raw[2];
    *r = OBS_R_FLOOR_K + OBS_R_CURRENT_K * (ratio * ratio);
    return 1;
}
"""
# the C names of the constants C_READING uses: (name, attribute, comment)
C_SCALARS = (("OBS_SPEED_MAX", "speed_max_rpm", "valid at or below this speed (rpm)"),
             ("OBS_CURRENT_MIN", "current_min_A", "valid where |i_d| is at least this (A)"),
             ("OBS_OMEGA_PER_RPM", "omega_per_rpm", "omega_e per rpm: 2 pi / 60 times the pole pairs"),
             ("OBS_L_Q", "L_q_H", "L_q (H)"),
             ("OBS_COPPER_REF", "copper_reference_C", "the copper reference temperature (deg C)"),
             ("OBS_R_S", "R_s_ohm", "R_s at the copper reference (ohm)"),
             ("OBS_ALPHA_CU", "alpha_cu_per_K", "copper's temperature coefficient (1/K)"),
             ("OBS_R_FLOOR", "R_floor_C2", "R where |i_d| is large (deg C^2)"),
             ("OBS_R_CURRENT", "R_current_C2", "R's growth with (i_min / i_d)^2 (deg C^2)"))


class WindingResistance(VoltageReading):
    PARAMETERS = PARAMETERS
    C_READING = C_READING
    C_SCALARS = C_SCALARS
    NODE = "winding"
    DEFAULT_NAME = "resistance"

    def fold(self, exact: dict[str, float], f) -> None:
        self.omega_per_rpm = f(RAD_S_PER_RPM) * self.pole_pairs

    def reading(self, raw: np.ndarray, speed, y: np.ndarray) -> tuple | None:
        """(ϑ_w, R) from the step's interval means (the estimate y is not used: R_s0 and L_q are calibrated)."""
        if not np.all(np.isfinite(raw)) or not abs(speed) <= self.speed_max_rpm:
            return None
        u_d, _, i_d, i_q = raw
        if not abs(i_d) >= self.current_min_A:
            return None
        omega = self.omega_per_rpm * speed
        r_s = (u_d + omega * self.L_q_H * i_q) / i_d
        z = self.copper_reference_C + (r_s / self.R_s_ohm - self.one) / self.alpha_cu_per_K
        ratio = self.current_min_A / i_d
        return z, self.R_floor_C2 + self.R_current_C2 * (ratio * ratio)


MEASUREMENT_KINDS.register("winding-resistance", MeasurementKind(
    "winding-resistance", "winding temperature from u_d, i_d, i_q, speed: R_s(ϑ) = R_s0 (1 + α_cu (ϑ - ϑ_cu))",
    WindingResistance))
