"""Loss models: what turns the measured operating point into the five loss inputs of the estimator.

Both kinds give, per model step, `p_dc0` (copper dc loss at the copper reference temperature), `p_ac0` (copper ac
loss at the reference), `p_stator` (iron loss, yoke + tooth), `p_magnet` and `current` (phase current
amplitude): the rest of the model (eqs. 3-8, the sigmoid, the network) is the same for every motor.

- `LossMaps` (bench.drive.motor): tables over a regular torque × speed grid, looked up at the step's mean torque
  and speed, as a machine designer's finite-element maps are.
- `ElectricalLosses`: losses from the measured d/q currents and the speed, for a motor without maps:
  f = pole_pairs·|n|/60, I² = i_d² + i_q², I = √I²,
  p_dc0 = 1.5·R_s·I² (amplitude-invariant dq currents), p_ac0 = p_dc0·k_ac·(f/f_ac)²,
  p_stator = (P_h·(f/f_fe) + P_e·(f/f_fe)²)·(1 + c_I·(I/I_max)²),
  p_magnet = P_m·(f/f_m)²·(c_0 + (1 - c_0)·I/I_max)².
  The identification refines them through the Hammerstein input nonlinearity (a static gain curve per loss input).

The target computes the same formulas in float32 in the same order (`target_sim.model.ElectricalLossStage`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

# Operating-point columns each loss model reads from the step means, by dataset column name.
MAPS_INPUTS = ("torque_Nm", "speed_rpm")
ELECTRICAL_INPUTS = ("speed_rpm", "i_d_A", "i_q_A")


@dataclass(frozen=True)
class ElectricalLosses:
    """Losses from d/q currents and speed (formulas in the module docstring); powers in W, frequencies in Hz."""

    pole_pairs: float
    stator_resistance_ohm: float
    ac_factor: float
    ac_reference_Hz: float
    iron_hysteresis_W: float
    iron_eddy_W: float
    iron_reference_Hz: float
    iron_current_factor: float
    magnet_W: float
    magnet_reference_Hz: float
    magnet_no_load_share: float
    current_max_A: float

    kind = "electrical"
    inputs = ELECTRICAL_INPUTS

    def evaluate_columns(self, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """p_dc0, p_ac0, p_stator, p_magnet, current (W, A) at the given speed (rpm) and currents (A)."""
        speed = np.abs(np.asarray(columns["speed_rpm"], dtype=float))
        i_d = np.asarray(columns["i_d_A"], dtype=float)
        i_q = np.asarray(columns["i_q_A"], dtype=float)
        f = self.pole_pairs * speed / 60.0
        i2 = i_d * i_d + i_q * i_q
        current = np.sqrt(i2)
        ratio = current / self.current_max_A
        p_dc0 = 1.5 * self.stator_resistance_ohm * i2
        f_ac = f / self.ac_reference_Hz
        p_ac0 = p_dc0 * (self.ac_factor * (f_ac * f_ac))
        f_fe = f / self.iron_reference_Hz
        p_stator = (self.iron_hysteresis_W * f_fe + self.iron_eddy_W * (f_fe * f_fe)) * (
            1.0 + self.iron_current_factor * (ratio * ratio))
        f_m = f / self.magnet_reference_Hz
        m = self.magnet_no_load_share + (1.0 - self.magnet_no_load_share) * ratio
        p_magnet = (self.magnet_W * (f_m * f_m)) * (m * m)
        return {"p_dc0": p_dc0, "p_ac0": p_ac0, "p_stator": p_stator, "p_magnet": p_magnet, "current": current}

    def coefficients(self) -> dict[str, float]:
        return asdict(self)
