"""Loss models: what turns the measured operating point into the five loss inputs of the estimator.

Both kinds give, per model step, `p_dc0` (copper dc loss at the copper reference temperature), `p_ac0` (copper ac
loss at the reference), `p_stator` (iron loss, yoke + tooth), `p_magnet` and `current` (phase current
amplitude): the rest of the model (eqs. 3-8, the sigmoid, the network) is the same for every motor.

- `LossMaps`: tables over a regular torque × speed grid, looked up at the step's mean torque
  and speed, as a machine designer's finite-element maps are.
- `ElectricalLosses`: losses from the measured d/q currents and the speed, for a motor without maps:
  f = pole_pairs·|n|/60, I² = i_d² + i_q², I = √I²,
  p_dc0 = 1.5·R_s·I² (amplitude-invariant dq currents), p_ac0 = p_dc0·k_ac·(f/f_ac)²,
  p_stator = (P_h·(f/f_fe) + P_e·(f/f_fe)²)·(1 + c_I·(I/I_max)²),
  p_magnet = P_m·(f/f_m)²·(c_0 + (1 - c_0)·I/I_max)².
  The identification refines them through the Hammerstein input nonlinearity (a static gain curve per loss input).

Each kind is one module of `bench.motor.losskinds` (the motor file's section, the float64 model, the artifact
section), beside its float32 twin in `target_sim.losses`; this module keeps what every kind shares.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

# the built-in kinds' float64 models, where the tree imports them from
from bench.motor.losskinds.electrical import ElectricalLosses  # noqa: F401
from bench.motor.losskinds.maps import MAP_TABLES, LossMaps  # noqa: F401


class LossModel(Protocol):
    """What the estimator needs of a loss model (LossMaps, ElectricalLosses)."""

    kind: str
    inputs: tuple[str, ...]

    def evaluate_columns(self, columns) -> dict[str, np.ndarray]: ...


class EstimatorMotor(Protocol):
    """What the estimator needs of a motor besides its loss model (bench.drive.motor.MotorSpec is one)."""

    i_max_A: float             # I_max of eq. 8
    max_speed_rpm: float       # ω_max of eqs. 8 and 15
    alpha_cu_per_K: float      # eqs. 3-4
    reference_C: float         # the temperature the copper losses are given at


@dataclass(frozen=True)
class MotorConstants:
    """An EstimatorMotor from a motor file or an artifact."""

    i_max_A: float
    max_speed_rpm: float
    alpha_cu_per_K: float
    reference_C: float
