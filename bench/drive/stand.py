"""The test stand's boundary conditions: coolant inlet and test-cell air temperature, as functions of time.

Both are exogenous (they do not depend on the plant's state), seeded and defined on a 1 s grid with linear
interpolation in between, so every integration step size sees the same continuous signals.
- Coolant inlet: the conditioning unit holds the set point, but the heat the motor rejects lifts the inlet
  by 0.35 K/kW after a 150 s lag (computed from the nominal losses), and the controller wanders by a
  0.1 K (1 σ) random walk with a 120 s correlation time.
- Test-cell air: 23 °C, 0.05 K per K of coolant set point above 20 °C (warm pipes), warming by 1.5 K over
  the run with a 3000 s time constant, plus a 0.2 K (1 σ), 300 s correlated wander.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import lfilter

from bench.drive.motor import parametric_losses
from bench.drive.sequence import TestSequence


@dataclass(frozen=True)
class StandSpec:
    coolant_gain_K_per_kW: float = 0.35
    coolant_lag_s: float = 150.0
    coolant_wander_K: float = 0.1
    coolant_wander_s: float = 120.0
    ambient_C: float = 23.0
    ambient_per_coolant_K: float = 0.05
    ambient_warmup_K: float = 1.5
    ambient_warmup_s: float = 3000.0
    ambient_wander_K: float = 0.2
    ambient_wander_s: float = 300.0

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


STAND = StandSpec()


def _lowpass(x: np.ndarray, tau_s: float, x0: float) -> np.ndarray:
    """Exact first-order lag on a 1 s grid for a held input."""
    a = np.exp(-1.0 / tau_s)
    y, _ = lfilter([1 - a], [1, -a], x, zi=[a * x0])
    return y


def _wander(rng: np.random.Generator, n: int, sigma: float, tau_s: float) -> np.ndarray:
    """A stationary AR(1) process with standard deviation sigma and correlation time tau_s."""
    a = np.exp(-1.0 / tau_s)
    e = rng.standard_normal(n) * sigma * np.sqrt(1 - a * a)
    x0 = rng.standard_normal() * sigma
    y, _ = lfilter([1.0], [1, -a], e, zi=[a * x0])
    return y


@dataclass(frozen=True, eq=False)
class Environment:
    """Coolant inlet and ambient temperature on a 1 s grid, interpolated linearly."""

    time_s: np.ndarray
    coolant_C: np.ndarray
    ambient_C: np.ndarray

    def coolant(self, t):
        return np.interp(t, self.time_s, self.coolant_C)

    def ambient(self, t):
        return np.interp(t, self.time_s, self.ambient_C)


def environment(sequence: TestSequence, setpoint_C: float, rng: np.random.Generator,
                stand: StandSpec = STAND) -> Environment:
    t = np.arange(0.0, np.ceil(sequence.duration_s) + 2.0)
    torque, speed = sequence.drive(t + 0.5)   # mid-second operating point
    nominal = parametric_losses(sequence.motor, torque, speed)
    total_kW = (nominal["p_dc0"] + nominal["p_ac0"] + nominal["p_stator"] + nominal["p_magnet"]) / 1000.0
    coolant = setpoint_C + stand.coolant_gain_K_per_kW * _lowpass(total_kW, stand.coolant_lag_s, 0.0)
    coolant = coolant + _wander(rng, len(t), stand.coolant_wander_K, stand.coolant_wander_s)
    ambient = (stand.ambient_C + stand.ambient_per_coolant_K * (setpoint_C - 20.0)
               + stand.ambient_warmup_K * (1 - np.exp(-t / stand.ambient_warmup_s))
               + _wander(rng, len(t), stand.ambient_wander_K, stand.ambient_wander_s))
    return Environment(t, coolant, ambient)
