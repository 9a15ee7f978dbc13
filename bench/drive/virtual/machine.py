"""The virtual plant's electrical machine: its dq parameters, its true losses' differences from the motor file's
loss model, and the steady-state dq model (torque -> currents -> voltages) of an interior-PM machine."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.drive.motor import RPM_PER_RAD_S


@dataclass(frozen=True)
class Machine:
    power_W: float
    flux_linkage_Vs: float
    L_d_H: float
    L_q_H: float
    voltage_limit_V: float
    remanence_per_K: float


@dataclass(frozen=True)
class TrueLosses:
    resistance_factor: float
    ac_factor: float
    ac_magnet_W: float
    copper_load_error: float
    iron_factor: float
    iron_per_K: float
    magnet_factor: float
    magnet_load_error: float
    magnet_resistivity_per_K: float



@dataclass(frozen=True)
class DqModel:
    """Torque -> (i_d, i_q) and voltages of an interior-PM machine (amplitude-invariant dq quantities)."""

    pole_pairs: int
    torque_max_Nm: float
    speed_max_rpm: float
    current_max_A: float
    machine: Machine

    def torque_limit(self, speed_rpm) -> np.ndarray:
        omega = np.maximum(np.abs(np.asarray(speed_rpm, dtype=float)), 1e-9) / RPM_PER_RAD_S
        return np.minimum(self.torque_max_Nm, self.machine.power_W / omega)

    def _mtpa(self, torque, psi):
        """MTPA currents for |torque| by bisection on the current amplitude; torque per MTPA amplitude grows."""
        m = self.machine
        dl, k = m.L_q_H - m.L_d_H, 1.5 * self.pole_pairs
        lo, hi = np.zeros_like(torque), np.full_like(torque, 2.0 * self.current_max_A)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            i_d = (psi - np.sqrt(psi * psi + 8.0 * dl * dl * mid * mid)) / (4.0 * dl)
            i_q = np.sqrt(np.maximum(mid * mid - i_d * i_d, 0.0))
            low = k * i_q * (psi - dl * i_d) < torque
            lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
        amp = 0.5 * (lo + hi)
        i_d = (psi - np.sqrt(psi * psi + 8.0 * dl * dl * amp * amp)) / (4.0 * dl)
        return i_d, np.sqrt(np.maximum(amp * amp - i_d * i_d, 0.0))

    def _voltage(self, i_d, i_q, omega_e, psi, resistance):
        m = self.machine
        u_d = resistance * i_d - omega_e * m.L_q_H * i_q
        u_q = resistance * i_q + omega_e * (psi + m.L_d_H * i_d)
        return u_d, u_q

    def currents(self, torque, speed_rpm, flux_ratio=1.0, resistance: float = 0.0):
        """(i_d, i_q, feasible): MTPA, field weakening above the voltage limit; vectorized.

        flux_ratio: the magnet's flux relative to flux_linkage_Vs. feasible is False where the torque needs more
        than limits.current_A or cannot be reached within the voltage limit.
        """
        m = self.machine
        torque, speed = np.broadcast_arrays(np.asarray(torque, dtype=float), np.asarray(speed_rpm, dtype=float))
        psi = m.flux_linkage_Vs * np.broadcast_to(np.asarray(flux_ratio, dtype=float), torque.shape)
        t_abs = np.abs(torque)
        omega_e = self.pole_pairs * np.abs(speed) / RPM_PER_RAD_S
        i_d, i_q = self._mtpa(t_abs, psi)
        u_d, u_q = self._voltage(i_d, i_q, omega_e, psi, resistance)
        weaken = np.hypot(u_d, u_q) > m.voltage_limit_V
        feasible = np.ones(torque.shape, dtype=bool)
        if weaken.any():
            dl, k = m.L_q_H - m.L_d_H, 1.5 * self.pole_pairs
            p, t, w = psi[weaken], t_abs[weaken], omega_e[weaken]
            hi = i_d[weaken]                      # |u| too high here
            lo = -p / m.L_d_H                     # ψ_d = 0: the deepest useful field weakening

            def volts(d):
                q = t / (k * (p - dl * d))
                ud, uq = self._voltage(d, q, w, p, resistance)
                return np.hypot(ud, uq), q

            feasible[weaken] = volts(lo)[0] <= m.voltage_limit_V
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                too_high = volts(mid)[0] > m.voltage_limit_V
                hi, lo = np.where(too_high, mid, hi), np.where(too_high, lo, mid)
            d = np.where(feasible[weaken], lo, hi)
            i_d = i_d.copy()
            i_q = i_q.copy()
            i_d[weaken], i_q[weaken] = d, volts(d)[1]
        feasible &= np.hypot(i_d, i_q) <= self.current_max_A * (1.0 + 1e-6)
        return i_d, np.sign(torque) * i_q, feasible

    def voltages(self, i_d, i_q, speed_rpm, flux_ratio, resistance):
        omega_e = self.pole_pairs * np.asarray(speed_rpm, dtype=float) / RPM_PER_RAD_S
        return self._voltage(np.asarray(i_d, float), np.asarray(i_q, float), omega_e,
                             self.machine.flux_linkage_Vs * np.asarray(flux_ratio, dtype=float),
                             np.asarray(resistance, dtype=float))

