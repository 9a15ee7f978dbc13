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

The target computes the same formulas in float32 in the same order (`target_sim.model.ElectricalLossStage`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np

# Operating-point columns each loss model reads from the step means, by dataset column name.
MAPS_INPUTS = ("torque_Nm", "speed_rpm")
ELECTRICAL_INPUTS = ("speed_rpm", "i_d_A", "i_q_A")


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


MAP_TABLES = ("p_dc0", "p_ac0", "p_stator", "p_magnet", "current")


@dataclass(frozen=True, eq=False)
class LossMaps:
    """Look-up tables over a regular (torque, speed) grid; tables are indexed [torque, speed].

    p_dc0, p_ac0: copper losses at ϑ_ref (W); p_stator: iron losses, yoke + tooth (W); p_magnet (W);
    current: phase current amplitude (A).
    """

    torque_Nm: np.ndarray
    speed_rpm: np.ndarray
    tables: dict[str, np.ndarray]

    kind = "maps"
    inputs = ("torque_Nm", "speed_rpm")   # the operating-point columns the look-up reads

    def evaluate_columns(self, columns) -> dict[str, np.ndarray]:
        """The tables at the operating points of `columns` (a mapping with torque_Nm and speed_rpm)."""
        return self.evaluate(columns["torque_Nm"], columns["speed_rpm"])

    def __post_init__(self) -> None:
        shape = (len(self.torque_Nm), len(self.speed_rpm))
        if set(self.tables) != set(MAP_TABLES):
            raise ValueError(f"loss maps need the tables {', '.join(MAP_TABLES)}")
        for name, table in self.tables.items():
            if np.shape(table) != shape:
                raise ValueError(f"table {name} has shape {np.shape(table)}, the grid is {shape}")
        for axis in (self.torque_Nm, self.speed_rpm):
            if len(axis) < 2 or np.any(np.diff(axis) <= 0):
                raise ValueError("loss-map axes must be strictly increasing with at least two points")

    def evaluate(self, torque, speed_rpm) -> dict[str, np.ndarray]:
        """Bilinear interpolation of every table, vectorized; points outside the grid are clamped to it."""
        tq, sp = np.broadcast_arrays(np.asarray(torque, dtype=float), np.asarray(speed_rpm, dtype=float))
        i, fi = _cell(self.torque_Nm, tq)
        j, fj = _cell(self.speed_rpm, sp)
        out = {}
        for name, t in self.tables.items():
            low = t[i, j] * (1 - fj) + t[i, j + 1] * fj
            high = t[i + 1, j] * (1 - fj) + t[i + 1, j + 1] * fj
            out[name] = low * (1 - fi) + high * fi
        return out

    def to_dict(self) -> dict:
        """Plain lists, for the model artifact (JSON)."""
        return {"torque_Nm": self.torque_Nm.tolist(), "speed_rpm": self.speed_rpm.tolist(),
                "tables": {k: np.asarray(self.tables[k]).tolist() for k in MAP_TABLES}}

    @classmethod
    def from_dict(cls, data: dict) -> LossMaps:
        return cls(np.asarray(data["torque_Nm"], dtype=float), np.asarray(data["speed_rpm"], dtype=float),
                   {k: np.asarray(data["tables"][k], dtype=float) for k in MAP_TABLES})


def _cell(axis: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the grid cell holding x (clamped) and the fraction across it."""
    x = np.clip(x, axis[0], axis[-1])
    i = np.clip(np.searchsorted(axis, x, side="right") - 1, 0, len(axis) - 2)
    return i, (x - axis[i]) / (axis[i + 1] - axis[i])
