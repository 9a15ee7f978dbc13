"""The magnet temperature from the flux linkage (steady-state voltage equations of a PM synchronous machine).

u_q = R_s(ϑ_w) i_q + ω_e (ψ_PM + L_d i_d), so ψ_PM = (u_q - R_s(ϑ_w) i_q)/ω_e - L_d i_d, with R_s(ϑ_w) =
R_s0 (1 + α_cu (ϑ_w - ϑ_cu)) at the observer's winding estimate, and ψ_PM(ϑ_m) = ψ_0 (1 + α_B (ϑ_m - ϑ_0)) gives
ϑ_m = ϑ_0 + (ψ_PM/ψ_0 - 1)/α_B. (u_d = R_s i_d - ω_e L_q i_q carries no magnet information; it is a raw channel
so the host sends the whole voltage vector, and the lab checks L_q with it.) Valid only at or above
speed_min_rpm; its variance R = R_floor + R_speed (n_min/n)² grows as the speed falls (the voltage and current
noise over ω_e), both fitted to the calibration residual by the lab (`bench observer --flux`).
"""

from __future__ import annotations

import numpy as np

from target_sim.artifact import OUTPUTS
from target_sim.observer.measurements import MEASUREMENT_KINDS, MeasurementKind
from target_sim.observer.measurements._voltages import CAN_CHANNELS, COLUMNS, RAD_S_PER_RPM, VoltageReading  # noqa: F401 (re-exported)

PARAMETERS = ("psi_0_Vs", "alpha_B_per_K", "theta_0_C", "L_d_H", "R_s_ohm", "alpha_cu_per_K", "copper_reference_C",
              "pole_pairs", "speed_min_rpm", "R_floor_C2", "R_speed_C2")
WINDING = OUTPUTS.index("winding")


# the generated C of `reading`, operation for operation (bench.firmware.observergen; _K is the measurement's index
# there, y_est the corrected estimate so far, raw its four channels u_d, u_q, i_d, i_q, speed the step's mean speed).
# One division (1/n), the rest multiply-adds by constants folded at load (FluxLinkage.__init__).
C_READING = """\
/* FluxLinkage.reading: with w = 1/n, psi omega_per_rpm = (u_q - R_s(winding) i_q) w - L_d omega_per_rpm i_d,
 * theta = theta_0 + (psi omega_per_rpm - psi_0 omega_per_rpm) / (psi_0 alpha_B omega_per_rpm), and the variance
 * R_floor + R_speed (n_min w)^2; no reading below the speed limit or with a NaN channel */
static int obs_reading_K(const float raw[4], float speed, float *value, float *r)
{
    float w, r_s, psi, ratio;
    if (!(obs_finite(raw[0]) && obs_finite(raw[1]) && obs_finite(raw[2]) && obs_finite(raw[3]))) return 0;
    if (!(__builtin_fabsf(speed) >= OBS_SPEED_MIN_K)) return 0;
    w = 1.0f / speed;
    r_s = OBS_R_S_AT_0_K + OBS_R_S_SLOPE_K * y_est[1];
    psi = (raw[1] - r_s * raw[3]) * w - OBS_L_D_OMEGA_K * raw[2];
    *value = OBS_THETA_0_K + OBS_DEGREES_PER_PSI_K * (psi - OBS_PSI_0_OMEGA_K);
    ratio = OBS_SPEED_MIN_K * w;
    *r = OBS_R_FLOOR_K + OBS_R_SPEED_K * (ratio * ratio);
    return 1;
}
"""
# the C names of the constants C_READING uses: (name, attribute, comment)
C_SCALARS = (("OBS_SPEED_MIN", "speed_min_rpm", "valid at or above this speed (rpm)"),
             ("OBS_R_S_AT_0", "r_s_at_0", "R_s at 0 deg C: R_s0 (1 - alpha_cu theta_cu) (ohm)"),
             ("OBS_R_S_SLOPE", "r_s_slope", "R_s's growth per K: R_s0 alpha_cu (ohm/K)"),
             ("OBS_L_D_OMEGA", "l_d_omega", "L_d omega_e per rpm"),
             ("OBS_PSI_0_OMEGA", "psi_0_omega", "psi_0 omega_e per rpm"),
             ("OBS_DEGREES_PER_PSI", "degrees_per_psi", "1 / (psi_0 alpha_B omega_e per rpm)"),
             ("OBS_THETA_0", "theta_0_C", "psi_0's temperature (deg C)"),
             ("OBS_R_FLOOR", "R_floor_C2", "R at and above the speed limit's ratio 0 (deg C^2)"),
             ("OBS_R_SPEED", "R_speed_C2", "R's growth with (n_min / n)^2 (deg C^2)"))


class FluxLinkage(VoltageReading):
    PARAMETERS = PARAMETERS
    C_READING = C_READING
    C_SCALARS = C_SCALARS
    NODE = "magnet"
    DEFAULT_NAME = "flux"

    def fold(self, exact: dict[str, float], f) -> None:
        # the reading's constants, folded once in float64 and rounded once: one division per reading (1/n)
        omega_per_rpm = RAD_S_PER_RPM * exact["pole_pairs"]
        self.r_s_at_0 = f(exact["R_s_ohm"] * (1.0 - exact["alpha_cu_per_K"] * exact["copper_reference_C"]))
        self.r_s_slope = f(exact["R_s_ohm"] * exact["alpha_cu_per_K"])
        self.l_d_omega = f(exact["L_d_H"] * omega_per_rpm)
        self.psi_0_omega = f(exact["psi_0_Vs"] * omega_per_rpm)
        self.degrees_per_psi = f(1.0 / (exact["psi_0_Vs"] * exact["alpha_B_per_K"] * omega_per_rpm))

    def reading(self, raw: np.ndarray, speed, y: np.ndarray) -> tuple | None:
        """(ϑ_m, R) from the step's interval means (C: fw_flux_reading)."""
        if not np.all(np.isfinite(raw)) or not abs(speed) >= self.speed_min_rpm:
            return None
        _, u_q, i_d, i_q = raw
        w = self.one / speed
        r_s = self.r_s_at_0 + self.r_s_slope * y[WINDING]
        psi = (u_q - r_s * i_q) * w - self.l_d_omega * i_d           # ψ_PM times ω_e per rpm
        z = self.theta_0_C + self.degrees_per_psi * (psi - self.psi_0_omega)
        ratio = self.speed_min_rpm * w
        return z, self.R_floor_C2 + self.R_speed_C2 * (ratio * ratio)


MEASUREMENT_KINDS.register("flux-linkage", MeasurementKind(
    "flux-linkage", "magnet temperature from u_q, i_d, i_q, speed: ψ_PM(ϑ) = ψ_0 (1 + α_B (ϑ - ϑ_0))", FluxLinkage))
