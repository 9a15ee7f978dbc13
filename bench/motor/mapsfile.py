"""Loss maps as a CSV file: one row per point of a full, evenly spaced torque × speed grid.

Columns (any order, a header line, comma-separated): torque_Nm, speed_rpm, copper_dc_W, copper_ac_W, iron_W,
magnet_W, current_A. Losses are those at the motor's copper reference temperature; current is the phase
current amplitude. The target interpolates bilinearly on an evenly spaced grid (as a C2000 look-up does, without
a search), so the grid must be evenly spaced: resample a finite-element export onto one first.
"""

from __future__ import annotations

import hashlib
import io
from pathlib import Path

import numpy as np

from bench.motor.errors import MotorFileError
from bench.motor.losskinds.maps import MAP_TABLES, LossMaps

# file column -> LossMaps table
FILE_COLUMNS = {"copper_dc_W": "p_dc0", "copper_ac_W": "p_ac0", "iron_W": "p_stator", "magnet_W": "p_magnet",
                "current_A": "current"}
AXES = ("torque_Nm", "speed_rpm")
HEADER = (*AXES, *FILE_COLUMNS)
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
    torque, speed = (np.unique(columns[a]) for a in AXES)
    for axis, values in zip(AXES, (torque, speed), strict=True):
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
