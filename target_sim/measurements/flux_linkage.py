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
