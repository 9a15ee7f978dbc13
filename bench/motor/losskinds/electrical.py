"""The electrical loss model as the lab knows it: losses from the measured d/q currents and the speed, for a motor
without maps (formulas: `target_sim.losses.electrical`, whose float32 code this float64 model equals in order):
f = pole_pairs·|n|/60, I² = i_d² + i_q², I = √I², p_dc0 = 1.5·R_s·I² (amplitude-invariant dq currents),
p_ac0 = p_dc0·k_ac·(f/f_ac)², p_stator = (P_h·(f/f_fe) + P_e·(f/f_fe)²)·(1 + c_I·(I/I_max)²),
p_magnet = P_m·(f/f_m)²·(c_0 + (1 - c_0)·I/I_max)². The identification refines them through the Hammerstein input
nonlinearity (a static gain curve per loss input).

Motor file: [losses] kind = "electrical" with the coefficients of `KEYS` (stator_resistance_ohm per phase at
copper_reference_C; magnet_no_load_share from 0 to 1); the data need i_d_A and i_q_A columns.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.motor.losskinds import Checker, LabLossKind, register
from target_sim.losses import electrical as target
from target_sim.losses.electrical import COEFFICIENTS

KEYS = ("stator_resistance_ohm", "ac_factor", "ac_reference_Hz", "iron_hysteresis_W", "iron_eddy_W",
        "iron_reference_Hz", "iron_current_factor", "magnet_W", "magnet_reference_Hz", "magnet_no_load_share")
# keys that must be > 0 (the others >= 0; the share also <= 1)
POSITIVE = ("stator_resistance_ohm", "ac_reference_Hz", "iron_reference_Hz", "magnet_reference_Hz")


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

    kind = target.ElectricalKind.name
    inputs = target.ElectricalKind.inputs

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



# the coefficients each loss input is proportional to (`LabElectricalKind.scaled`)
SCALED_COEFFICIENTS = {"p_dc0": ("stator_resistance_ohm",), "p_stator": ("iron_hysteresis_W", "iron_eddy_W"),
                       "p_magnet": ("magnet_W",)}


class LabElectricalKind(LabLossKind):
    name = target.ElectricalKind.name
    keys = KEYS
    summary = "losses from the d/q currents and the speed"
    robustness_groups = {"R_s": (("stator_resistance_ohm",),), "ac_factor": (("ac_factor",),),
                         "P_iron": (("iron_hysteresis_W",), ("iron_eddy_W",)), "P_magnet": (("magnet_W",),)}

    def from_motor_file(self, check: Checker, losses, *, motor_path: Path | None, pole_pairs: int,
                        current_max_A: float) -> tuple[ElectricalLosses, None]:
        values = {k: check.number(losses, f"losses.{k}", positive=k in POSITIVE, low=0.0,
                                  high=1.0 if k == "magnet_no_load_share" else None) for k in KEYS}
        return ElectricalLosses(pole_pairs=float(pole_pairs), current_max_A=current_max_A, **values), None

    def artifact_section(self, model: ElectricalLosses, encode) -> dict[str, Any]:
        coefficients = model.coefficients()
        return {name: encode(coefficients[name]) for name in COEFFICIENTS}

    def from_artifact(self, artifact, current_max_A: float) -> ElectricalLosses:
        return ElectricalLosses(**{n: float(artifact.array("losses", n, dtype=np.float64)) for n in COEFFICIENTS},
                                current_max_A=current_max_A)

    def describe(self, model: ElectricalLosses) -> dict[str, Any]:
        return {"loss_coefficients": model.coefficients()}

    def scaled(self, model: ElectricalLosses, factors: Mapping[str, float]) -> ElectricalLosses:
        """p_stator scales with both iron coefficients, p_magnet with magnet_W."""
        unknown = set(factors) - set(SCALED_COEFFICIENTS)
        if unknown:
            raise ValueError(f"the electrical loss model cannot scale {', '.join(sorted(unknown))}")
        return replace(model, **{key: getattr(model, key) * factor
                                 for name, factor in factors.items() for key in SCALED_COEFFICIENTS[name]})


register(LabElectricalKind())
