"""The virtual 200 kW out-runner PMSM: its specification and its finite-element-like loss maps.

The paper's machine is proprietary, so this one is made up, but sized like it: 200 kW peak, a liquid-cooled
stator inside an outer rotor. Its losses come from a small parametric model of the kind FE loss maps are
fitted with (I²R copper, frequency-squared ac copper, Steinmetz/Bertotti iron, f²·I² magnet eddy losses);
`nominal_loss_maps` samples that model at the copper reference temperature 20 °C on a regular torque-speed
grid, which is what a machine designer hands over and what an estimator interpolates.

Torque -> current (maximum torque per ampere, then field weakening): the torque-producing current grows a
little faster than torque (saturation), and above base speed a demagnetizing d-axis current grows with
speed; the phase current amplitude is their root sum of squares.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from bench.motor.losses import MAP_TABLES, LossMaps  # noqa: F401  (re-exported: the maps are the motor's)

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)


@dataclass(frozen=True)
class MotorSpec:
    """Single source of truth for the virtual motor. Powers in W, torque in Nm, speed in rpm, current in A."""

    rated_power_W: float = 200e3          # peak = rated power of the paper's machine
    peak_torque_Nm: float = 640.0         # out-runner: high torque, modest speed
    max_speed_rpm: float = 9000.0         # ω_max of eq. 15 (speed ratio = speed / max speed)
    i_max_A: float = 800.0                # phase current amplitude at peak torque, I_max of eq. 8
    alpha_cu_per_K: float = 0.0039        # eqs. 3-4
    reference_C: float = 20.0             # ϑ_ref of eqs. 3-4: the maps' temperature
    # torque -> current
    saturation: float = 0.25              # i_q = I_max·τ(1 + s τ²)/(1 + s), τ = |T|/T_peak
    magnet_torque_share: float = 0.6      # the rest is reluctance torque, which a weaker magnet does not reduce
    field_weakening: float = 0.45         # i_d = I_max·k_fw·(1 - n_base/n) above base speed
    # copper
    phase_resistance_ohm: float = 0.012   # per phase at 20 °C: P_dc = 1.5 R I² (11.5 kW at I_max)
    ac_factor: float = 0.6                # P_ac / P_dc at max speed (skin and proximity effect ∝ f²)
    ac_pm_W: float = 250.0                # strand eddy losses from the magnet field at max speed, no load
    # stator iron (yoke + tooth) at base speed, no load; hysteresis ∝ f, eddy ∝ f², both ∝ B²
    iron_hysteresis_W: float = 450.0
    iron_eddy_W: float = 300.0
    armature_flux: float = 0.45           # load flux: B² ∝ (1 - c_d·i_d/I_max)² + (c_q·τ)²
    demagnetization: float = 0.9          # c_d
    # magnet eddy losses at max speed and I_max: ∝ f²·(c0 + (1 - c0)·I/I_max)²
    magnet_W: float = 600.0
    magnet_no_load_share: float = 0.3     # c0: slot harmonics (no load) vs armature MMF harmonics

    @property
    def base_speed_rpm(self) -> float:
        """Corner speed where the constant-torque region meets the constant-power region."""
        return self.rated_power_W / self.peak_torque_Nm * RPM_PER_RAD_S

    def torque_limit(self, speed_rpm):
        """Envelope: |T| ≤ min(T_peak, P / ω)."""
        omega = np.maximum(np.abs(np.asarray(speed_rpm, dtype=float)), 1e-9) / RPM_PER_RAD_S
        return np.minimum(self.peak_torque_Nm, self.rated_power_W / omega)

    def as_dict(self) -> dict[str, float]:
        return {**asdict(self), "base_speed_rpm": self.base_speed_rpm}


VIRTUAL_MOTOR = MotorSpec()


def current_components(spec: MotorSpec, torque, speed_rpm, magnet_flux=1.0):
    """(i_q, i_d) in A. With a weaker magnet (magnet_flux < 1) the same torque needs more current."""
    tau = np.abs(torque) / spec.peak_torque_Nm
    torque_per_amp = 1.0 + spec.magnet_torque_share * (magnet_flux - 1.0)
    i_q = spec.i_max_A * tau * (1 + spec.saturation * tau * tau) / (1 + spec.saturation) / torque_per_amp
    n = np.abs(speed_rpm)
    i_d = spec.i_max_A * spec.field_weakening * np.maximum(0.0, 1.0 - spec.base_speed_rpm / np.maximum(n, 1e-9))
    return i_q, i_d


def phase_current(spec: MotorSpec, torque, speed_rpm):
    """Phase current amplitude (A) from torque and speed at the nominal magnet temperature."""
    i_q, i_d = current_components(spec, torque, speed_rpm)
    return np.sqrt(i_q * i_q + i_d * i_d)


def parametric_losses(spec: MotorSpec, torque, speed_rpm, magnet_flux=1.0) -> dict[str, np.ndarray]:
    """The loss model behind the maps, at the copper reference temperature.

    magnet_flux is the magnet's remanence relative to 20 °C (1 for the maps; the plant passes its
    temperature-dependent value). Returns p_dc0, p_ac0, p_stator, p_magnet (W) and current (A).
    """
    torque = np.asarray(torque, dtype=float)
    speed_rpm = np.asarray(speed_rpm, dtype=float)
    i_q, i_d = current_components(spec, torque, speed_rpm, magnet_flux)
    i2 = i_q * i_q + i_d * i_d
    current = np.sqrt(i2)
    w = np.abs(speed_rpm) / spec.max_speed_rpm
    f = np.abs(speed_rpm) / spec.base_speed_rpm
    tau = np.abs(torque) / spec.peak_torque_Nm
    p_dc0 = 1.5 * spec.phase_resistance_ohm * i2
    p_ac0 = w * w * (spec.ac_factor * p_dc0 + spec.ac_pm_W * magnet_flux**2)
    b2 = (magnet_flux * (1 - spec.demagnetization * i_d / spec.i_max_A)) ** 2 + (spec.armature_flux * tau) ** 2
    p_stator = (spec.iron_hysteresis_W * f + spec.iron_eddy_W * f * f) * b2
    c0 = spec.magnet_no_load_share
    p_magnet = spec.magnet_W * w * w * (c0 * magnet_flux + (1 - c0) * current / spec.i_max_A) ** 2
    return {"p_dc0": p_dc0, "p_ac0": p_ac0, "p_stator": p_stator, "p_magnet": p_magnet, "current": current}


def nominal_loss_maps(spec: MotorSpec = VIRTUAL_MOTOR, torque_points: int = 21, speed_points: int = 16) -> LossMaps:
    """The 'finite-element' maps: the parametric model at 20 °C on a torque × speed grid (±T_peak, 0..n_max)."""
    torque = np.linspace(-spec.peak_torque_Nm, spec.peak_torque_Nm, torque_points)
    speed = np.linspace(0.0, spec.max_speed_rpm, speed_points)
    tq, sp = np.meshgrid(torque, speed, indexing="ij")
    return LossMaps(torque, speed, parametric_losses(spec, tq, sp))
