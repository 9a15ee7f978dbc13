"""The magnet temperature from the flux linkage (steady-state voltage equations of a PM synchronous machine).

u_q = R_s(ϑ_w) i_q + ω_e (ψ_PM + L_d i_d), so ψ_PM = (u_q - R_s(ϑ_w) i_q)/ω_e - L_d i_d, with R_s(ϑ_w) =
R_s0 (1 + α_cu (ϑ_w - ϑ_cu)) at the observer's winding estimate, and ψ_PM(ϑ_m) = ψ_0 (1 + α_B (ϑ_m - ϑ_0)) gives
ϑ_m = ϑ_0 + (ψ_PM/ψ_0 - 1)/α_B. (u_d = R_s i_d - ω_e L_q i_q carries no magnet information; it is a raw channel
so the host sends the whole voltage vector, and the lab checks L_q with it.) Valid only at or above
speed_min_rpm; its variance R = R_floor + R_speed (n_min/n)² grows as the speed falls (the voltage and current
noise over ω_e), both fitted to the calibration residual by the lab (`bench observer --flux`).
"""

from __future__ import annotations

import math

import numpy as np

from target_sim.artifact import OUTPUTS, decode_array
from target_sim.measurements import MEASUREMENT_KINDS, MeasurementKind

# raw channels in the order the filter reads them: the dataset's columns, and over CAN the host's measurement
# channels and the row's own values (`dbc.contract.MEASUREMENT_CHANNELS`, `ROW_CHANNELS`: DriveVoltages, DriveCurrents)
COLUMNS = ("u_d_V", "u_q_V", "i_d_A", "i_q_A")
CAN_CHANNELS = ("u_d", "u_q", "i_d", "i_q")
PARAMETERS = ("psi_0_Vs", "alpha_B_per_K", "theta_0_C", "L_d_H", "R_s_ohm", "alpha_cu_per_K", "copper_reference_C",
              "pole_pairs", "speed_min_rpm", "R_floor_C2", "R_speed_C2")
RAD_S_PER_RPM = 2.0 * math.pi / 60.0
WINDING = OUTPUTS.index("winding")


# the generated C of `reading`, operation for operation (bench.firmware.observergen; _K is the measurement's index
# there, y_est the corrected estimate so far, raw its four channels u_d, u_q, i_d, i_q, speed the step's mean speed)
C_READING = """\
/* FluxLinkage.reading: psi = (u_q - R_s(winding) i_q) / omega_e - L_d i_d, the magnet temperature of psi, and the
 * variance R_floor + R_speed (n_min / n)^2; no reading below the speed limit or with a NaN channel */
static int obs_reading_K(const float raw[4], float speed, float *value, float *r)
{
    float omega, r_s, psi, ratio;
    if (!(obs_finite(raw[0]) && obs_finite(raw[1]) && obs_finite(raw[2]) && obs_finite(raw[3]))) return 0;
    if (!(__builtin_fabsf(speed) >= OBS_SPEED_MIN_K)) return 0;
    omega = OBS_OMEGA_PER_RPM_K * speed;
    r_s = OBS_R_S_K * (1.0f + OBS_ALPHA_CU_K * (y_est[1] - OBS_COPPER_REF_K));
    psi = (raw[1] - r_s * raw[3]) / omega - OBS_L_D_K * raw[2];
    *value = OBS_THETA_0_K + (psi / OBS_PSI_0_K - 1.0f) / OBS_ALPHA_B_K;
    ratio = OBS_SPEED_MIN_K / speed;
    *r = OBS_R_FLOOR_K + OBS_R_SPEED_K * (ratio * ratio);
    return 1;
}
"""
# the C names of the constants C_READING uses: (name, attribute, comment)
C_SCALARS = (("OBS_SPEED_MIN", "speed_min_rpm", "valid at or above this speed (rpm)"),
             ("OBS_OMEGA_PER_RPM", "omega_per_rpm", "omega_e per rpm: 2 pi / 60 times the pole pairs"),
             ("OBS_R_S", "R_s_ohm", "R_s at the copper reference (ohm)"),
             ("OBS_ALPHA_CU", "alpha_cu_per_K", "copper's temperature coefficient (1/K)"),
             ("OBS_COPPER_REF", "copper_reference_C", "the copper reference temperature (deg C)"),
             ("OBS_L_D", "L_d_H", "L_d (H)"), ("OBS_THETA_0", "theta_0_C", "psi_0's temperature (deg C)"),
             ("OBS_PSI_0", "psi_0_Vs", "psi_PM at theta_0 (Vs)"), ("OBS_ALPHA_B", "alpha_B_per_K", "alpha_B (1/K)"),
             ("OBS_R_FLOOR", "R_floor_C2", "R at and above the speed limit's ratio 0 (deg C^2)"),
             ("OBS_R_SPEED", "R_speed_C2", "R's growth with (n_min / n)^2 (deg C^2)"))


class FluxLinkage:
    def __init__(self, entry: dict, where: str, f):
        arrays = entry["arrays"]
        for key in PARAMETERS:
            setattr(self, key, decode_array(arrays[key], f"{where}.arrays.{key}", f)[()])
        self.name = str(entry.get("name", "flux"))
        self.columns = COLUMNS
        self.can_channels = CAN_CHANNELS
        self.sees = np.zeros(len(OUTPUTS), dtype=f)
        self.sees[OUTPUTS.index("magnet")] = f(1.0)
        self.lag_pole = f(0.0)
        self.omega_per_rpm = f(RAD_S_PER_RPM) * self.pole_pairs
        self.one = f(1.0)

    @property
    def width(self) -> int:
        return len(COLUMNS)

    def c_scalars(self) -> list[tuple[str, np.floating, str]]:
        """(C name, float32 value, comment) of the constants `C_READING` names (the generator suffixes them)."""
        return [(name, getattr(self, attribute), comment) for name, attribute, comment in C_SCALARS]

    c_reading = C_READING

    def reading(self, raw: np.ndarray, speed, y: np.ndarray) -> tuple | None:
        """(ϑ_m, R) from the step's interval means (C: fw_flux_reading)."""
        if not np.all(np.isfinite(raw)) or not abs(speed) >= self.speed_min_rpm:
            return None
        _, u_q, i_d, i_q = raw
        omega = self.omega_per_rpm * speed
        r_s = self.R_s_ohm * (self.one + self.alpha_cu_per_K * (y[WINDING] - self.copper_reference_C))
        psi = (u_q - r_s * i_q) / omega - self.L_d_H * i_d
        z = self.theta_0_C + (psi / self.psi_0_Vs - self.one) / self.alpha_B_per_K
        ratio = self.speed_min_rpm / speed
        return z, self.R_floor_C2 + self.R_speed_C2 * (ratio * ratio)


MEASUREMENT_KINDS.register("flux-linkage", MeasurementKind(
    "flux-linkage", "magnet temperature from u_q, i_d, i_q, speed: ψ_PM(ϑ) = ψ_0 (1 + α_B (ϑ - ϑ_0))", FluxLinkage))
