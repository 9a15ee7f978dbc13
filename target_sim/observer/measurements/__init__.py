"""The observer's measurement kinds, one module per kind (`lagged_sensor`, `flux_linkage`, `winding_resistance`), found
by name.

A kind turns the raw channels a row carries for it (a temperature reading; u_d, u_q, i_d, i_q) into a reading of
the model at one model step, in float32 with a fixed order of operations (the C version repeats it):
- `width`: how many raw channels it takes per row (the host sends them; NaN in any: no reading this step);
- `sees`: the outputs' weights (yoke, winding, tooth, magnet) of the temperature it reads;
- `lag_pole`: a first-order lag a = exp(-Δ/τ) of that temperature (the observer then carries the lag's state
  s <- a s + (1 - a) sees·y as an extra state and the reading is s); 0: no lag state;
- `reading(raw, speed, y)`: (z, R) — the reading less its offset and its variance — or None when it is not valid
  this step (below a speed, a NaN channel);
- `c_reading`, `c_scalars()`: the same reading in the firmware's generated C (`bench.firmware.observergen`), and
  the float32 constants it names.
The artifact's observer section lists its measurements in order (`observer.measurements`, section version 2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from target_sim.registry import Registry


class TargetMeasurement(Protocol):
    name: str
    columns: tuple[str, ...]
    sees: np.ndarray
    lag_pole: np.floating

    @property
    def width(self) -> int: ...

    def reading(self, raw: np.ndarray, speed, y: np.ndarray) -> tuple | None: ...

    c_reading: str

    def c_scalars(self) -> list[tuple[str, np.floating, str]]: ...


@dataclass(frozen=True)
class MeasurementKind:
    """One kind: `load(entry, where, f)` builds its target measurement from an `observer.measurements` entry;
    `temperature_channel`: its one raw channel is a temperature reading (it travels in a Measurements slot), else
    the kind names the CAN channels it computes its reading from (`can_channels`)."""

    name: str
    summary: str
    load: object
    temperature_channel: bool = False


MEASUREMENT_KINDS: Registry[MeasurementKind] = Registry("measurement kind", __name__,
                                                        first=("lagged-sensor", "flux-linkage",
                                                               "winding-resistance"))
