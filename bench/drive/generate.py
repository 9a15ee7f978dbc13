"""The bench's own datasets: one synthetic measurement run (test sequence -> stand -> virtual motor -> sensors) per
coolant set point, written as dataset files (`bench.drive.dataset`'s format) with the sidecar that says how."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.drive.dataset import (
    SAMPLE_PERIOD_S,
    dataset_filename,
    dataset_sha256,
    default_dataset_dir,
    sidecar_path,
    write_dataset,
)
from bench.drive.plant import PLANT_STEP_S, TRUE_EFFECTS, TrueEffects, simulate
from bench.drive.seed import DEFAULT_SEED
from bench.drive.sensors import measure
from bench.drive.sequence import TestSequence
from bench.drive.stand import STAND, StandSpec, environment, sequence_losses
from bench.thermal.parameters import TABLE1_REFINED, LptnParameters

PARAMETER_SET = "table1-refined"
# Bump when anything that changes the generated numbers changes (plant, sensors, stand, sequence, motor).
GENERATOR_VERSION = "1.1.0"
COOLANT_SETPOINTS_C = (20.0, 40.0, 60.0)
ROLES = {20.0: "identification", 40.0: "validation", 60.0: "identification"}


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
    env = environment(sequence.duration_s, setpoint_C, sequence_losses(sequence), np.random.default_rng(env_ss), stand)
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


def ensure_default_datasets(out_dir: Path | None = None, seed: int | None = None) -> dict[int, Path]:
    """The three datasets (coolant 20, 40, 60 °C) in out_dir, generated where missing or stale.

    A file is reused when its sidecar names this generator version and seed and its sha256 matches.
    """
    out_dir = Path(out_dir) if out_dir is not None else default_dataset_dir()
    seed = DEFAULT_SEED if seed is None else seed
    paths = {}
    with _directory_lock(out_dir):
        for setpoint in COOLANT_SETPOINTS_C:
            path = out_dir / dataset_filename(setpoint)
            if not _is_current(path, seed, GENERATOR_VERSION):
                generate_and_write(path, setpoint, seed)
            paths[int(setpoint)] = path
    return paths


@contextmanager
def _directory_lock(directory: Path) -> Iterator[None]:
    """Holds an exclusive lock on `directory` itself (flock on its descriptor, no lock file left in it), created if
    missing: processes that fill one directory at once (parallel test workers, two commands) generate each file once,
    the others wait and then find it current. Without flock (Windows) or where the directory cannot be made or
    opened, no lock: every file is written atomically anyway, so a race costs only generating twice, and the
    writes report the directory's problem as before."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)   # releases the lock


def _is_current(path: Path, seed: int, version: str) -> bool:
    try:
        meta = json.loads(sidecar_path(path).read_text(encoding="utf-8"))
        return (meta.get("seed") == seed and meta.get("generator_version") == version
                and meta.get("sha256") == dataset_sha256(path))
    except (OSError, ValueError):
        return False


def generate_and_write(path: Path, setpoint_C: float, seed: int) -> tuple[Generated, str]:
    """Generate one dataset and write it with its sidecar; returns (Generated, sha256)."""
    sequence = TestSequence()
    result = generate(setpoint_C, seed, sequence)
    sidecar = {
        "generator": "bench.drive", "generator_version": GENERATOR_VERSION, "seed": seed,
        "coolant_setpoint_C": setpoint_C, "role": ROLES.get(setpoint_C, "extra"),
        "sample_period_s": SAMPLE_PERIOD_S, "duration_s": sequence.duration_s,
        "initial_state": "all nodes at the coolant set point",
        "phases": [{"name": p.name, "kind": p.kind, "start_s": p.start_s, "end_s": p.end_s} for p in sequence.phases],
        "preheat": {"torque_Nm": sequence.preheat.torque_Nm, "speed_rpm": sequence.preheat.speed_rpm,
                    "ramp_s": sequence.preheat.ramp_s},
        "thermal_parameters": PARAMETER_SET, "motor": sequence.motor.as_dict(),
        "vehicle": sequence.vehicle.as_dict(), "true_effects": TRUE_EFFECTS.as_dict(), "stand": STAND.as_dict(),
    }
    sha = write_dataset(path, result.columns, sidecar)
    return result, sha
