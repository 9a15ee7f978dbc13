"""The test stand's boundary conditions: coolant inlet and test-cell air temperature, as functions of time.

Both are exogenous (they do not depend on the plant's state), seeded and defined on a 1 s grid with linear
interpolation in between, so every integration step size sees the same continuous signals. One model serves
the built-in motor (STAND, a constant set point per run) and the virtual plants of motor files (their
virtual_plant.stand table, set points that change between phases):
- Coolant inlet: the conditioning unit follows the set point through a first-order lag (coolant_lag_s; none
  for a constant set point), the heat the motor rejects lifts the inlet by coolant_gain_K_per_kW times the
  nominal losses lagged by coolant_heat_lag_s, and the controller wanders by an AR(1) random walk.
- Test-cell air: ambient_C, ambient_per_coolant_K per K of coolant set point above 20 °C (warm pipes), an
  optional warming of ambient_warmup_K with time constant ambient_warmup_s, plus a correlated wander.
Built-in stand: 0.35 K/kW after 150 s, 0.1 K (1 σ) coolant wander over 120 s; 23 °C air, 0.05 K/K, warming by
1.5 K over 3000 s, 0.2 K (1 σ) wander over 300 s.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from bench.drive.motor import parametric_losses
from bench.drive.sequence import TestSequence

# the virtual_plant.stand keys of a motor file, in the order its checks and messages list them
STAND_KEYS = ("coolant_lag_s", "coolant_gain_K_per_kW", "coolant_heat_lag_s", "coolant_wander_K", "coolant_wander_s",
              "ambient_C", "ambient_per_coolant_K", "ambient_wander_K", "ambient_wander_s")


@dataclass(frozen=True)
class StandSpec:
    coolant_lag_s: float | None       # conditioning unit: first-order lag to a new set point (None: no lag)
    coolant_gain_K_per_kW: float      # the inlet rises with the heat the motor rejects ...
    coolant_heat_lag_s: float         # ... after this lag
    coolant_wander_K: float
    coolant_wander_s: float
    ambient_C: float
    ambient_per_coolant_K: float      # warm pipes: per K of coolant set point above 20 °C
    ambient_wander_K: float
    ambient_wander_s: float
    ambient_warmup_K: float = 0.0     # the test cell warms by this over the run ...
    ambient_warmup_s: float = 3000.0  # ... with this time constant

    def as_dict(self) -> dict[str, float]:
        """The built-in datasets' sidecar record, in the keys and order it has always had (there the heat lag
        is 'coolant_lag_s': its set point never changes, so it has no set-point lag)."""
        return {"coolant_gain_K_per_kW": self.coolant_gain_K_per_kW, "coolant_lag_s": self.coolant_heat_lag_s,
                "coolant_wander_K": self.coolant_wander_K, "coolant_wander_s": self.coolant_wander_s,
                "ambient_C": self.ambient_C, "ambient_per_coolant_K": self.ambient_per_coolant_K,
                "ambient_warmup_K": self.ambient_warmup_K, "ambient_warmup_s": self.ambient_warmup_s,
                "ambient_wander_K": self.ambient_wander_K, "ambient_wander_s": self.ambient_wander_s}


STAND = StandSpec(coolant_lag_s=None, coolant_gain_K_per_kW=0.35, coolant_heat_lag_s=150.0, coolant_wander_K=0.1,
                  coolant_wander_s=120.0, ambient_C=23.0, ambient_per_coolant_K=0.05, ambient_wander_K=0.2,
                  ambient_wander_s=300.0, ambient_warmup_K=1.5, ambient_warmup_s=3000.0)


def lowpass(x: np.ndarray, tau_s: float, x0: float) -> np.ndarray:
    """Exact first-order lag on a 1 s grid for a held input, starting from x0."""
    from scipy.signal import lfilter  # scipy.signal: when a dataset is generated, not when one is found current

    a = np.exp(-1.0 / tau_s)
    y, _ = lfilter([1 - a], [1, -a], x, zi=[a * x0])
    return y


def wander(rng: np.random.Generator, n: int, sigma: float, tau_s: float) -> np.ndarray:
    """A stationary AR(1) process with standard deviation sigma and correlation time tau_s."""
    from scipy.signal import lfilter

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


NominalLosses = Callable[[np.ndarray], Mapping[str, np.ndarray]]


def sequence_losses(sequence: TestSequence) -> NominalLosses:
    """The built-in motor's nominal losses along the test sequence (what the stand's coolant rise follows)."""
    return lambda t: parametric_losses(sequence.motor, *sequence.drive(t))


def environment(duration_s: float, setpoint_C: float | Callable[[np.ndarray], np.ndarray],
                nominal_losses: NominalLosses, rng: np.random.Generator, stand: StandSpec = STAND,
                start_C: float | None = None) -> Environment:
    """The stand's coolant and ambient over a run.

    setpoint_C: a constant or a function of time; nominal_losses(t): the loss components p_dc0, p_ac0, p_stator
    and p_magnet (W) at times t; start_C: the inlet before t = 0, where the set-point lag starts (default: the
    set point at 0). Draws the coolant wander, then the ambient wander, from rng.
    """
    t = np.arange(0.0, np.ceil(duration_s) + 2.0)
    nominal = nominal_losses(t + 0.5)   # mid-second operating point
    total_kW = (nominal["p_dc0"] + nominal["p_ac0"] + nominal["p_stator"] + nominal["p_magnet"]) / 1000.0
    setpoint = setpoint_C(t) if callable(setpoint_C) else setpoint_C
    coolant = setpoint
    if stand.coolant_lag_s is not None:
        start = float(np.ravel(setpoint)[0]) if start_C is None else start_C
        coolant = lowpass(np.broadcast_to(setpoint, t.shape), stand.coolant_lag_s, start)
    # the same order of operations for every stand, so each keeps its bits
    coolant = coolant + stand.coolant_gain_K_per_kW * lowpass(total_kW, stand.coolant_heat_lag_s, 0.0)
    coolant = coolant + wander(rng, len(t), stand.coolant_wander_K, stand.coolant_wander_s)
    ambient = stand.ambient_C + stand.ambient_per_coolant_K * (setpoint - 20.0)
    if stand.ambient_warmup_K:
        ambient = ambient + stand.ambient_warmup_K * (1 - np.exp(-t / stand.ambient_warmup_s))
    ambient = ambient + wander(rng, len(t), stand.ambient_wander_K, stand.ambient_wander_s)
    return Environment(t, coolant, ambient)
