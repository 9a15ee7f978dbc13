"""One synthetic measurement run: test sequence -> stand -> virtual motor -> sensors, for one coolant set point."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.drive.dataset import DEFAULT_SEED
from bench.drive.plant import PLANT_STEP_S, TRUE_EFFECTS, TrueEffects, simulate
from bench.drive.sensors import SAMPLE_PERIOD_S, measure
from bench.drive.sequence import TestSequence
from bench.drive.stand import STAND, StandSpec, environment
from bench.thermal.parameters import TABLE1_REFINED, LptnParameters

PARAMETER_SET = "table1-refined"


@dataclass(frozen=True, eq=False)
class Generated:
    """Measured columns (the dataset) and the true signals behind them, at the 5 Hz sample times."""

    setpoint_C: float
    seed: int
    columns: dict[str, np.ndarray]
    truth: dict[str, np.ndarray]


def sample_times(duration_s: float, sample_period_s: float = SAMPLE_PERIOD_S) -> np.ndarray:
    """k·T_s for k = 0..N, computed as k / f_s so whole seconds are exact (torque steps there)."""
    per_second = round(1.0 / sample_period_s)
    return np.arange(int(round(duration_s * per_second)) + 1) / per_second


def seed_sequence(seed: int, setpoint_C: float) -> np.random.SeedSequence:
    """Independent, reproducible streams per (seed, set point); set points in 0.1 K above absolute zero."""
    if seed < 0:
        raise ValueError("the seed must be a non-negative integer")
    return np.random.SeedSequence([int(seed), int(round((setpoint_C + 273.15) * 10))])


def generate(setpoint_C: float, seed: int = DEFAULT_SEED, sequence: TestSequence | None = None,
             params: LptnParameters = TABLE1_REFINED, effects: TrueEffects = TRUE_EFFECTS,
             stand: StandSpec = STAND, plant_step_s: float = PLANT_STEP_S) -> Generated:
    sequence = sequence or TestSequence()
    env_ss, sensor_ss = seed_sequence(seed, setpoint_C).spawn(2)
    env = environment(sequence, setpoint_C, np.random.default_rng(env_ss), stand)
    t = sample_times(sequence.duration_s)
    run = simulate(sequence, env.coolant, env.ambient, float(t[-1]), [setpoint_C] * 4, plant_step_s,
                   params, effects)  # machine soaked at the set point
    stride = int(round(SAMPLE_PERIOD_S / plant_step_s))
    states = run.states[::stride]
    torque, speed = sequence.drive(t)
    truth = {"time_s": t, "torque_Nm": torque, "speed_rpm": speed, "coolant_C": env.coolant(t),
             "ambient_C": env.ambient(t), "yoke_C": states[:, 0], "winding_C": states[:, 1],
             "tooth_C": states[:, 2], "magnet_C": states[:, 3]}
    measured = measure(truth, np.random.default_rng(sensor_ss))
    return Generated(setpoint_C, seed, {"time_s": t, **measured}, truth)
