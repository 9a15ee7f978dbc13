"""A temperature sensor column (a stator NTC): node + gradient·(node - yoke), first-order lag τ, offset, noise.

Its readings are the column less its offset; its variance is the tuned R. With τ > 0 the observer carries the
lag's state (a = exp(-Δ/τ)), so a lagging sensor no longer reads as a model error of its node.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.errors import UsageError
from bench.model.measures import LabMeasurementKind, register, step_means
from target_sim.artifact import OUTPUTS, decode_array, encode_array
from target_sim.measurements.lagged_sensor import sees

START_R_C2 = 0.1    # where the tuning starts a sensor's variance (°C²)


@dataclass(frozen=True)
class Sensor:
    node: str = "winding"
    column: str = "winding_C"
    offset_C: float = 0.0
    lag_s: float = 0.0
    gradient: float = 0.0
    kind: str = "lagged-sensor"

    @property
    def name(self) -> str:
        return self.column

    @property
    def columns(self) -> tuple[str, ...]:
        return (self.column,)

    @property
    def index(self) -> int:
        return OUTPUTS.index(self.node)

    @property
    def sees(self) -> np.ndarray:
        return sees(self.node, self.gradient)

    def lag_pole(self, dt: float) -> float:
        return math.exp(-dt / self.lag_s) if self.lag_s > 0 else 0.0

    def readings(self, dataset, dt: float, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        z = step_means(dataset, self.columns, dt, steps)[:, 0] - self.offset_C
        return z, np.zeros_like(z), np.ones_like(z)

    def entry(self, dt: float, r_scale: float) -> dict:
        return {"kind": self.kind, "name": self.name, "columns": list(self.columns), "node": self.node,
                "gradient": self.gradient, "lag_s": self.lag_s, "offset": self.offset_C,
                "arrays": {"sees": encode_array(self.sees), "lag_pole": encode_array(self.lag_pole(dt)),
                           "offset_C": encode_array(self.offset_C), "R": encode_array(r_scale)}}

    def describe(self) -> dict:
        return {"kind": self.kind, "node": self.node, "column": self.column, "offset_C": self.offset_C,
                "lag_s": self.lag_s, "gradient": self.gradient}

    def calibration_text(self) -> str | None:
        return None


class LabLaggedSensorKind(LabMeasurementKind):
    name = "lagged-sensor"
    start_r = START_R_C2     # R is the sensor's variance itself

    def from_entry(self, entry: dict, dt: float) -> Sensor:
        lag_pole = float(decode_array(entry["arrays"]["lag_pole"], "lag_pole", np.float64))
        lag_s = float(dt / -np.log(lag_pole)) if lag_pole > 0 else 0.0
        return Sensor(entry["node"], entry["columns"][0],
                      float(decode_array(entry["arrays"]["offset_C"], "offset_C", np.float64)), lag_s,
                      float(entry.get("gradient", 0.0)))

    def stored_r(self, entry: dict) -> float:
        return float(decode_array(entry["arrays"]["R"], "R", np.float64))

    def add_arguments(self, parser) -> None:
        parser.add_argument("--measure", default="winding_C", metavar="COLUMN",
                            help="the sensor's dataset column (default winding_C; none: no sensor)")
        parser.add_argument("--node", choices=OUTPUTS, default="winding", help="the model node the sensor sees "
                            "(default winding)")
        parser.add_argument("--offset", type=float, default=0.0,
                            help="the sensor's offset in K, subtracted from each reading")
        parser.add_argument("--lag", type=float, default=0.0, help="the sensor's time constant in s (a lag state "
                            "of the filter; default 0: none)")
        parser.add_argument("--gradient", type=float, default=0.0,
                            help="the sensor reads node + GRADIENT·(node - yoke) (default 0)")

    def from_arguments(self, args, artifact, datasets) -> Sensor | None:
        if args.measure == "none":
            return None
        if not 0 <= args.lag < 1e5:
            raise UsageError("--lag must be a non-negative number of seconds")
        return Sensor(args.node, args.measure, args.offset, args.lag, args.gradient)


register(LabLaggedSensorKind())
