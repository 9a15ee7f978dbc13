"""Loss maps as the lab knows them: tables over a regular (torque, speed) grid, as a machine designer's
finite-element maps are (the float32 look-up: `target_sim.losses.maps`).

Motor file: [losses] kind = "maps", file = "losses.csv", a CSV beside the motor file (path relative to it) with one
row per point of a full, evenly spaced torque × speed grid: the columns torque_Nm, speed_rpm, copper_dc_W,
copper_ac_W, iron_W, magnet_W, current_A (any order, a header line, comma-separated). Losses are those at the motor's
copper reference temperature; current is the phase current amplitude. The target interpolates bilinearly on an
evenly spaced grid (as a C2000 look-up does, without a search), so the grid must be evenly spaced: resample a
finite-element export onto one first.
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.motor.errors import MotorFileError
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


# file column -> LossMaps table
FILE_COLUMNS = {"copper_dc_W": "p_dc0", "copper_ac_W": "p_ac0", "iron_W": "p_stator", "magnet_W": "p_magnet",
                "current_A": "current"}
FILE_AXES = ("torque_Nm", "speed_rpm")
HEADER = (*FILE_AXES, *FILE_COLUMNS)
SPACING_TOLERANCE = 1e-6


def read_loss_maps(path: Path, where: str) -> tuple[LossMaps, str]:
    """The maps of a loss-map CSV and the file's sha256; one BenchError sentence on the first problem."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MotorFileError(f"{where}: loss-map file {path} cannot be read ({exc.strerror or exc}); losses.file is "
                         "relative to the motor file") from None
    try:
        text = raw.decode("utf-8-sig")
        data = np.genfromtxt(io.StringIO(text), delimiter=",", names=True, dtype=float, encoding=None,
                             invalid_raise=True)
    except (UnicodeDecodeError, ValueError) as exc:
        raise MotorFileError(f"loss-map file {path} is not a comma-separated table of numbers with a header line "
                         f"({str(exc).splitlines()[0][:80]})") from None
    names = data.dtype.names or ()
    missing = [c for c in HEADER if c not in names]
    if missing:
        raise MotorFileError(f"loss-map file {path} lacks the column {missing[0]!r}; it needs {', '.join(HEADER)}")
    data = np.atleast_1d(data)
    columns = {c: np.asarray(data[c], dtype=float) for c in HEADER}
    for c, v in columns.items():
        if not np.all(np.isfinite(v)):
            row = int(np.argmax(~np.isfinite(v))) + 1
            raise MotorFileError(f"loss-map file {path}, column {c}: row {row} is not a finite number")
        if c in FILE_COLUMNS and np.any(v < 0):
            raise MotorFileError(f"loss-map file {path}, column {c}: row {int(np.argmax(v < 0)) + 1} is negative; "
                             "losses and currents are magnitudes")
    torque, speed = (np.unique(columns[a]) for a in FILE_AXES)
    for axis, values in zip(FILE_AXES, (torque, speed), strict=True):
        steps = np.diff(values)
        if len(values) < 2 or not np.allclose(steps, steps[0], rtol=SPACING_TOLERANCE, atol=0):
            raise MotorFileError(f"loss-map file {path}: the {axis} points ({len(values)}) are not an evenly spaced "
                             "axis of at least two points; resample the maps onto an even grid")
    if len(columns["torque_Nm"]) != len(torque) * len(speed):
        raise MotorFileError(f"loss-map file {path} has {len(columns['torque_Nm'])} rows, a full {len(torque)} × "
                         f"{len(speed)} torque × speed grid needs {len(torque) * len(speed)} (one per point)")
    i = np.searchsorted(torque, columns["torque_Nm"])
    j = np.searchsorted(speed, columns["speed_rpm"])
    seen = np.zeros((len(torque), len(speed)), dtype=bool)
    seen[i, j] = True
    if not seen.all():
        raise MotorFileError(f"loss-map file {path} repeats a grid point and misses another; give each torque × speed "
                         "point once")
    tables = {name: np.zeros((len(torque), len(speed))) for name in MAP_TABLES}
    for column, name in FILE_COLUMNS.items():
        tables[name][i, j] = columns[column]
    return LossMaps(torque, speed, tables), hashlib.sha256(raw).hexdigest()


def loss_maps_csv(maps: LossMaps) -> str:
    """The CSV text of maps (float64 values written so they read back bit for bit), torque-major rows."""
    out = io.StringIO()
    out.write(",".join(HEADER) + "\n")
    for a, t in enumerate(maps.torque_Nm):
        for b, s in enumerate(maps.speed_rpm):
            values = [t, s, *(maps.tables[name][a, b] for name in FILE_COLUMNS.values())]
            out.write(",".join(repr(float(v)) for v in values) + "\n")
    return out.getvalue()


class LabMapsKind(LabLossKind):
    name = target.MapsKind.name
    robustness_groups = {"P_dc": (("tables", "p_dc0"),), "P_ac": (("tables", "p_ac0"),),
                         "P_stator": (("tables", "p_stator"),), "P_magnet": (("tables", "p_magnet"),)}
    keys = ("file",)
    summary = "loss maps over torque and speed"

    def from_motor_file(self, check: Checker, losses, *, motor_path: Path | None, pole_pairs: int,
                        current_max_A: float) -> tuple[LossMaps, str]:
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

    def scaled(self, model: LossMaps, factors: Mapping[str, float]) -> LossMaps:
        """Each named loss table times its factor (the current table is not a loss)."""
        unknown = set(factors) - (set(MAP_TABLES) - {"current"})
        if unknown:
            raise ValueError(f"loss maps have no loss table {', '.join(sorted(unknown))}")
        return LossMaps(model.torque_Nm, model.speed_rpm,
                        {name: table * factors.get(name, 1.0) for name, table in model.tables.items()})

    def describe(self, model: LossMaps) -> dict[str, Any]:
        return {"loss_maps_grid": {"torque_Nm": [float(model.torque_Nm[0]), float(model.torque_Nm[-1]),
                                                 len(model.torque_Nm)],
                                   "speed_rpm": [float(model.speed_rpm[0]), float(model.speed_rpm[-1]),
                                                 len(model.speed_rpm)]}}


register(LabMapsKind())
