"""Loss maps: five tables over a regular torque × speed grid, interpolated bilinearly (the losses a machine
designer's finite-element maps give). The artifact's `losses` holds `torque_axis_Nm`, `speed_axis_rpm` (evenly
spaced, increasing) and `tables.<output>` of shape (torque points, speed points)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from target_sim.losses import LOSS_OUTPUTS, CArray, LossKind, register

AXES = ("torque_axis_Nm", "speed_axis_rpm")
MAX_GRID_POINTS = 256                   # per axis: a table beyond that is no motor map (and no MCU's flash)


class LossTables:
    """The artifact's loss look-up tables over the (torque, speed) grid, interpolated in float32 (C: loss_lookup)."""

    def __init__(self, artifact, dtype=np.float32):
        self.f = f = np.dtype(dtype).type
        self.torque_axis = artifact.array("losses", "torque_axis_Nm", dtype=f)
        self.speed_axis = artifact.array("losses", "speed_axis_rpm", dtype=f)
        self.tables = np.stack([artifact.array("losses", "tables", name, dtype=f) for name in LOSS_OUTPUTS])
        self.torque_step = f(self.torque_axis[1] - self.torque_axis[0])
        self.speed_step = f(self.speed_axis[1] - self.speed_axis[0])

    def _cell(self, value, start, step, size):
        """Index of the grid cell holding value, and the fraction inside it (clamped to the grid; NaN -> 0)."""
        f = self.f
        pos = (f(value) - start) / step
        if not pos >= 0:                # C: if (!(pos >= 0.0f)) pos = 0.0f;
            pos = f(0.0)
        last = f(size - 1)
        if pos > last:                  # C: if (pos > last) pos = last;
            pos = last
        i = int(pos)                    # C: (int)pos, truncation (pos >= 0)
        if i > size - 2:
            i = size - 2
        return i, f(pos - f(i))

    def _cells(self, values, start, step, size):
        """`_cell` for lanes of trajectories (an array of values): the same operations, lane by lane."""
        f = self.f
        pos = (np.asarray(values, dtype=f) - start) / step
        pos = np.where(pos >= 0, pos, f(0.0))          # NaN -> 0, as `not pos >= 0`
        last = f(size - 1)
        pos = np.where(pos > last, last, pos)
        i = np.minimum(pos.astype(np.int64), size - 2)  # truncation (pos >= 0)
        return i, (pos - i.astype(f)).astype(f)

    def lookup(self, torque, speed) -> np.ndarray:
        """[p_dc0, p_ac0, p_stator, p_magnet, current] at one operating point (bilinear, per table:
        low = t00 + fj·(t01 - t00), high = t10 + fj·(t11 - t10), value = low + fi·(high - low)); for lanes of
        trajectories (arrays of torque and speed) (5, L...)."""
        if np.ndim(torque) or np.ndim(speed):
            i, fi = self._cells(torque, self.torque_axis[0], self.torque_step, self.torque_axis.size)
            j, fj = self._cells(speed, self.speed_axis[0], self.speed_step, self.speed_axis.size)
            t = self.tables
            t00, t01, t10, t11 = t[:, i, j], t[:, i, j + 1], t[:, i + 1, j], t[:, i + 1, j + 1]
            low = t00 + fj * (t01 - t00)
            high = t10 + fj * (t11 - t10)
            return low + fi * (high - low)
        i, fi = self._cell(torque, self.torque_axis[0], self.torque_step, self.torque_axis.size)
        j, fj = self._cell(speed, self.speed_axis[0], self.speed_step, self.speed_axis.size)
        t = self.tables[:, i:i + 2, j:j + 2]
        low = t[:, 0, 0] + fj * (t[:, 0, 1] - t[:, 0, 0])
        high = t[:, 1, 0] + fj * (t[:, 1, 1] - t[:, 1, 0])
        return low + fi * (high - low)


_C_CODE = """\
/* LossTables._cell: the grid cell holding value and the fraction inside it, clamped to the grid (NaN -> 0) */
static int grid_cell(float value, float start, float step, int size, float *fraction)
{
    const float last = (float)(size - 1);
    float pos = (value - start) / step;
    int i;
    if (!(pos >= 0.0f)) pos = 0.0f;
    if (pos > last) pos = last;
    i = (int)pos;
    if (i > size - 2) i = size - 2;
    *fraction = pos - (float)i;
    return i;
}

/* LossTables.lookup: [p_dc0, p_ac0, p_stator, p_magnet, current] at (torque, speed), bilinear per table
 * (LOSS_TABLES_ROW(k, i): row i of table k, each distinct row stored once when rows repeat) */
static void loss_lookup(float torque, float speed, float out[LOSS_TABLE_COUNT])
{
    float fi, fj;
    const int i = grid_cell(torque, TORQUE_START, TORQUE_STEP, TORQUE_POINTS, &fi);
    const int j = grid_cell(speed, SPEED_START, SPEED_STEP, SPEED_POINTS, &fj);
    int k;
    for (k = 0; k < LOSS_TABLE_COUNT; k++) {
        const float *below = LOSS_TABLES_ROW(k, i), *above = LOSS_TABLES_ROW(k, i + 1);
        const float t00 = below[j], t01 = below[j + 1];
        const float t10 = above[j], t11 = above[j + 1];
        const float low = t00 + fj * (t01 - t00);
        const float high = t10 + fj * (t11 - t10);
        out[k] = low + fi * (high - low);
    }
}
"""


class MapsKind(LossKind):
    name = "maps"
    inputs = ("torque_Nm", "speed_rpm")
    summary = "losses from loss maps over torque and speed"
    c_function = "loss_lookup"
    c_words = "tables"
    c_code = _C_CODE

    def fields(self, losses: Mapping[str, Any]) -> list[tuple[str, ...]]:
        return [(axis,) for axis in AXES] + [("tables", name) for name in LOSS_OUTPUTS]

    def shapes(self, losses: Mapping[str, Any]) -> dict[tuple[str, ...], tuple[int, ...]]:
        grid = []
        shapes: dict[tuple[str, ...], tuple[int, ...]] = {}
        for axis in AXES:
            entry = losses.get(axis)
            shape = entry.get("shape") if isinstance(entry, dict) else None
            size = shape[0] if isinstance(shape, list) and len(shape) == 1 and type(shape[0]) is int else 0
            shapes[(axis,)] = (max(size, 2),)  # at least two points per axis
            grid.append(max(size, 2))
        shapes.update({("tables", name): tuple(grid) for name in LOSS_OUTPUTS})
        return shapes

    def problem(self, artifact) -> str | None:
        for axis in AXES:
            steps = np.diff(artifact.array("losses", axis, dtype=np.float64))
            if not np.all(steps > 0) or not np.allclose(steps, steps[0], rtol=1e-6):
                return f"artifact field losses.{axis} is not an increasing, evenly spaced grid"
        return None

    def evaluator(self, artifact, dtype=np.float32) -> LossTables:
        return LossTables(artifact, dtype)

    def c_scalars(self, artifact) -> list[tuple[str, tuple[str, ...] | np.float32, str]]:
        tables = LossTables(artifact)       # the reference's own derived constants (grid steps), in float32
        return [("TORQUE_START", ("losses", "torque_axis_Nm", 0), "losses.torque_axis_Nm[0]"),
                ("TORQUE_STEP", tables.torque_step, "torque_axis_Nm[1] - torque_axis_Nm[0] in float32"),
                ("SPEED_START", ("losses", "speed_axis_rpm", 0), "losses.speed_axis_rpm[0]"),
                ("SPEED_STEP", tables.speed_step, "speed_axis_rpm[1] - speed_axis_rpm[0] in float32")]

    def c_declarations(self, artifact) -> tuple[list[str], list[CArray]]:
        grid = artifact.array("losses", "tables", LOSS_OUTPUTS[0]).shape
        defines = [f"#define TORQUE_POINTS {grid[0]}", f"#define SPEED_POINTS {grid[1]}",
                   f"#define LOSS_TABLE_COUNT {len(LOSS_OUTPUTS)}"]
        tables = CArray("LOSS_TABLES", tuple(("losses", "tables", name) for name in LOSS_OUTPUTS),
                        f"losses.tables [{', '.join(LOSS_OUTPUTS)}][torque][speed]", shared_rows=True)
        return defines, [tables]

    def c_problem(self, artifact) -> str | None:
        sizes = []
        for axis in AXES:
            values = artifact.array("losses", axis)
            if values.ndim != 1 or not 2 <= values.size <= MAX_GRID_POINTS:
                return (f"artifact field losses.{axis} has shape {list(values.shape)}; the firmware generator needs "
                        f"2 to {MAX_GRID_POINTS} grid points")
            sizes.append(values.size)
        for name in LOSS_OUTPUTS:
            shape = artifact.array("losses", "tables", name).shape
            if shape != tuple(sizes):
                return (f"artifact field losses.tables.{name} has shape {list(shape)}, the firmware generator needs "
                        f"{sizes} (the grid's)")
        return None

    def ops(self, op: Callable[..., Counter]) -> Counter:
        """Bilinear look-up of the five loss tables at (torque, speed)."""
        tables = len(LOSS_OUTPUTS)
        per_axis = op(table=1, add=2, multiply=1)  # (v - start) * (1/step), fraction = pos - i
        interpolate = op(multiply=3 * tables, add=6 * tables, load_store=4 * tables + tables)
        return per_axis + per_axis + interpolate + op(call=1)

    def coefficient_count(self, artifact) -> int:
        count = sum(artifact.array("losses", "tables", name).size for name in LOSS_OUTPUTS)
        return count + sum(artifact.array("losses", axis).size for axis in AXES)


register(MapsKind())
