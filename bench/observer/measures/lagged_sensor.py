"""A temperature sensor column (a stator NTC): node + gradient·(node - yoke), first-order lag τ, offset, noise.

Its readings are the column less its offset; its variance is the tuned R. With τ > 0 the observer carries the
lag's state (a = exp(-Δ/τ)), so a lagging sensor no longer reads as a model error of its node. Each of τ, g and the
offset is given, or `auto`: estimated from the training files' references of its node and the yoke
(`bench.observer.measures.sensor_fit`).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field

import numpy as np

from bench.drive.dataset import BY_NAME as DATASET_COLUMNS
from bench.errors import UsageError
from bench.observer.measures import LabMeasurementKind, register, step_means
from target_sim.artifact import OUTPUTS, decode_array, encode_array
from target_sim.observer.measurements.lagged_sensor import sees

# the dataset schema's column of a stator sensor (an NTC, an end-winding thermocouple): where a user's own sensor
# column is mapped to (`bench.drive.dataset`)
SENSOR_COLUMN = "ntc_C"

START_R_C2 = 0.1    # where the tuning starts a sensor's variance (°C²)
AUTO = "auto"       # the value of --lag, --gradient and --offset that asks for the estimate from the training files


@dataclass(frozen=True)
class Sensor:
    node: str = "winding"
    column: str = "winding_C"
    offset_C: float = 0.0
    lag_s: float = 0.0
    gradient: float = 0.0
    kind: str = "lagged-sensor"
    # the estimate of its values from the training files (`sensor_fit.SensorFit.calibration`), empty when all given
    calibration: dict = field(default_factory=dict, compare=False)
    warnings: tuple[str, ...] = field(default=(), compare=False)

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
                "lag_s": self.lag_s, "gradient": self.gradient,
                **({"calibration": self.calibration} if self.calibration else {})}

    def calibration_text(self) -> str | None:
        cal = self.calibration
        if not cal:
            return None
        held = [n for n in ("lag", "gradient", "offset") if n not in cal["estimated"]]
        return (f"sensor {self.column}: lag {self.lag_s:.4g} s, gradient {self.gradient:.4g}, offset "
                f"{self.offset_C:.3g} K (estimated {', '.join(cal['estimated'])}"
                f"{'; held ' + ', '.join(held) if held else ''}) against {cal['reference']} on {cal['steps']} steps "
                f"of {cal['files']} file(s); residual RMS {cal['residual_rms_K']:.2f} K, max "
                f"{cal['residual_max_K']:.2f} K{''.join('; ' + n for n in cal['notes'])}")


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
        parser.add_argument("--measure", type=_sensor_column, default="winding_C", metavar="COLUMN",
                            help=f"the sensor's dataset column (default winding_C; none: no sensor); a sensor of your "
                                 f"own (an end-winding thermocouple) is mapped onto {SENSOR_COLUMN} with --mapping")
        parser.add_argument("--node", choices=OUTPUTS, default="winding", help="the model node the sensor sees "
                            "(default winding)")
        parser.add_argument("--offset", type=_number_or_auto, default=0.0, metavar="K|auto",
                            help="the sensor's offset in K, subtracted from each reading (default 0; auto: estimated "
                                 "from the training files)")
        parser.add_argument("--lag", type=_number_or_auto, default=0.0, metavar="S|auto",
                            help="the sensor's time constant in s (a lag state of the filter; default 0: none; auto: "
                                 "estimated from the training files)")
        parser.add_argument("--gradient", type=_number_or_auto, default=0.0, metavar="G|auto",
                            help="the sensor reads node + G·(node - yoke) (default 0; auto: estimated from the "
                                 "training files' node and yoke_C references)")

    def from_arguments(self, args, artifact, datasets) -> Sensor | None:
        if args.measure == "none":
            return None
        if args.lag != AUTO and not 0 <= args.lag < 1e5:
            raise UsageError("--lag must be a non-negative number of seconds or auto")
        values = (args.lag, args.gradient, args.offset)
        if AUTO not in values:
            return Sensor(args.node, args.measure, args.offset, args.lag, args.gradient)
        from bench.observer.measures.sensor_fit import fit_sensor

        lag, gradient, offset = (None if v == AUTO else v for v in values)
        fit = fit_sensor(datasets, artifact.dt, args.measure, args.node, lag, gradient, offset)
        return Sensor(args.node, args.measure, fit.offset_C, fit.lag_s, fit.gradient, calibration=fit.calibration(),
                      warnings=fit.warnings)


def _sensor_column(text: str) -> str:
    """--measure: a column of the dataset schema (the loader reads no other), or none."""
    if text == "none" or text in DATASET_COLUMNS:
        return text
    raise UsageError(f"--measure {text} is no dataset column (a file's other columns are not read): map your sensor's "
                     f"column onto {SENSOR_COLUMN} with --mapping (a mapping file's [columns] {text} = "
                     f"\"{SENSOR_COLUMN}\") and pass --measure {SENSOR_COLUMN}")


def _number_or_auto(text: str) -> float | str:
    """A number, or `auto` (estimated from the training files)."""
    if text.strip().lower() == AUTO:
        return AUTO
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a number nor auto") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


register(LabLaggedSensorKind())
