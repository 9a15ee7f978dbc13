"""A temperature sensor on the machine (a stator NTC): it reads a mix of nodes through a first-order lag, plus an
offset and noise.

It sees node + gradient·(node - yoke) (an end-winding NTC sits between the winding's hot spot and the yoke: a
negative gradient), lags it with τ (the artifact stores a = exp(-Δ/τ), 0 without lag) and reads it plus offset_C.
The reading is z - offset_C with the constant variance R.
"""

from __future__ import annotations

import numpy as np

from target_sim.artifact import OUTPUTS, decode_array
from target_sim.observer.measurements import MEASUREMENT_KINDS, MeasurementKind
from target_sim.xcp.variables import OFFSET_SYMBOL, R_SYMBOL

# the generated C of `reading` (bench.firmware.observergen; _K is the measurement's index there); its offset and R
# are variables an XCP master calibrates (target_sim.xcp.variables)
C_READING = f"""\
/* LaggedSensor.reading: a finite reading less its offset, with the variance R */
static int obs_reading_K(const float raw[1], float speed, float *value, float *r)
{{
    (void)speed;
    if (!obs_finite(raw[0])) return 0;
    *value = raw[0] - {OFFSET_SYMBOL}_K;
    *r = {R_SYMBOL}_K;
    return 1;
}}
"""


class LaggedSensor:
    def __init__(self, entry: dict, where: str, f):
        arrays = entry["arrays"]

        def arr(key):
            return decode_array(arrays[key], f"{where}.arrays.{key}", f)

        self.name = str(entry.get("name", entry["columns"][0]))
        self.columns = tuple(entry["columns"])
        self.sees = arr("sees")
        self.lag_pole = arr("lag_pole")[()]
        self.offset = arr("offset_C")[()]
        self.r = arr("R")[()]

    @property
    def width(self) -> int:
        return 1

    def c_scalars(self) -> list[tuple[str, np.floating, str]]:
        """(C name, float32 value, comment) of the constants `C_READING` names (the generator suffixes them)."""
        return [(OFFSET_SYMBOL, self.offset, "its offset (deg C)"), (R_SYMBOL, self.r, "its variance R (deg C^2)")]

    c_reading = C_READING

    def reading(self, raw: np.ndarray, speed, y: np.ndarray) -> tuple | None:
        z = raw[0]
        if not np.isfinite(z):
            return None
        return z - self.offset, self.r


def sees(node: str, gradient: float = 0.0) -> np.ndarray:
    """The outputs' weights of a sensor on `node` with a gradient toward the yoke."""
    w = np.zeros(len(OUTPUTS))
    w[OUTPUTS.index(node)] += 1.0 + gradient
    w[OUTPUTS.index("yoke")] -= gradient
    return w


MEASUREMENT_KINDS.register("lagged-sensor", MeasurementKind(
    "lagged-sensor", "a temperature sensor: node + gradient·(node - yoke), first-order lag, offset", LaggedSensor,
    temperature_channel=True))
