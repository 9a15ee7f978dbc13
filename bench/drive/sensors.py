"""The test stand's instruments, sampled at 5 Hz: additive Gaussian noise, then quantization.

| signal | source | noise (1 σ) | resolution |
|---|---|---|---|
| torque | in-line torque transducer | 0.3 Nm | 0.1 Nm |
| speed | encoder | 0.5 rpm while turning, none at standstill | 1 rpm |
| coolant inlet | PT100 in the inlet pipe | 0.05 K | 0.1 °C |
| ambient | PT100 in the test cell | 0.1 K | 0.1 °C |
| winding | thermocouple in the end winding (the winding node) | 0.15 K | 0.1 °C |
| rotor surface | telemetry thermocouple on the rotor surface | 0.2 K | 0.1 °C |

The virtual rotor surface runs exactly 5 K below the magnet node, the assumption behind the paper's PM
reference: pm_C = rotor_surface_C + 5 °C is then the magnet temperature plus sensor noise.
Resolutions match the CAN signals of the DBC, so a dataset value crosses the bus unchanged. Noise comes
from one numpy Generator per dataset, so a seed reproduces every bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# the PM reference's offset and the sample period (bench.drive.dataset.SAMPLE_PERIOD_S) belong to the file format
from bench.drive.dataset import PM_OFFSET_K


@dataclass(frozen=True)
class Sensor:
    noise: float
    resolution: float


SENSORS: dict[str, Sensor] = {
    "torque_Nm": Sensor(0.3, 0.1),
    "speed_rpm": Sensor(0.5, 1.0),
    "coolant_C": Sensor(0.05, 0.1),
    "ambient_C": Sensor(0.1, 0.1),
    "winding_C": Sensor(0.15, 0.1),
    "rotor_surface_C": Sensor(0.2, 0.1),
}


def quantize(x, resolution: float) -> np.ndarray:
    """Round to the resolution; + 0.0 turns -0.0 into 0.0 so files never show '-0.0'."""
    return np.round(np.asarray(x, dtype=float) / resolution) * resolution + 0.0


def measure(truth: dict[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Measured columns from true signals at the sample times.

    truth holds torque_Nm, speed_rpm, coolant_C, ambient_C, winding_C and magnet_C. The draw order is fixed
    (one block per sensor, in SENSORS order), which keeps datasets bit-for-bit reproducible.
    """
    true = dict(truth)
    true["rotor_surface_C"] = np.asarray(truth["magnet_C"]) - PM_OFFSET_K
    out = {}
    for name, sensor in SENSORS.items():
        x = np.asarray(true[name], dtype=float)
        noise = rng.standard_normal(x.shape) * sensor.noise
        if name == "speed_rpm":
            noise = np.where(x != 0, noise, 0.0)
        out[name] = quantize(x + noise, sensor.resolution)
    out["pm_C"] = quantize(out["rotor_surface_C"] + PM_OFFSET_K, SENSORS["rotor_surface_C"].resolution)
    return out
