"""Loss maps as the lab knows them: tables over a regular (torque, speed) grid, as a machine designer's
finite-element maps are (the float32 look-up: `target_sim.losses.maps`).

Motor file: [losses] kind = "maps", file = "losses.csv", a CSV beside the motor file (path relative to it) with one
row per point of a full, evenly spaced torque × speed grid (`bench.motor.mapsfile`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.motor.losskinds import Checker, LabLossKind, register
from target_sim.losses import LOSS_OUTPUTS
from target_sim.losses import maps as target
from target_sim.losses.maps import AXES

MAP_TABLES = LOSS_OUTPUTS


@dataclass(frozen=True, eq=False)
class LossMaps:
    """Look-up tables over a regular (torque, speed) grid; tables are indexed [torque, speed].

    p_dc0, p_ac0: copper losses at ϑ_ref (W); p_stator: iron losses, yoke + tooth (W); p_magnet (W);
    current: phase current amplitude (A).
    """

    torque_Nm: np.ndarray
    speed_rpm: np.ndarray
    tables: dict[str, np.ndarray]

    kind = target.MapsKind.name
    inputs = target.MapsKind.inputs             # the operating-point columns the look-up reads

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


class LabMapsKind(LabLossKind):
    name = target.MapsKind.name
    keys = ("file",)
    summary = "loss maps over torque and speed"

    def from_motor_file(self, check: Checker, losses, *, motor_path: Path | None, pole_pairs: int,
                        current_max_A: float) -> tuple[LossMaps, str]:
        from bench.motor.mapsfile import read_loss_maps

        maps_path = Path(check.text(losses, "losses.file"))
        if not maps_path.is_absolute() and motor_path is not None:
            maps_path = motor_path.parent / maps_path
        return read_loss_maps(maps_path, check.where)

    def artifact_section(self, model: LossMaps, encode) -> dict[str, Any]:
        return {AXES[0]: encode(model.torque_Nm), AXES[1]: encode(model.speed_rpm),
                "tables": {name: encode(model.tables[name]) for name in MAP_TABLES}}

    def from_artifact(self, artifact, current_max_A: float) -> LossMaps:
        def f64(*keys):
            return artifact.array("losses", *keys, dtype=np.float64)

        return LossMaps(f64(AXES[0]), f64(AXES[1]), {n: f64("tables", n) for n in MAP_TABLES})

    def describe(self, model: LossMaps) -> dict[str, Any]:
        return {"loss_maps_grid": {"torque_Nm": [float(model.torque_Nm[0]), float(model.torque_Nm[-1]),
                                                 len(model.torque_Nm)],
                                   "speed_rpm": [float(model.speed_rpm[0]), float(model.speed_rpm[-1]),
                                                 len(model.speed_rpm)]}}


register(LabMapsKind())
