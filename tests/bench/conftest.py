"""Fixtures of the CAN bench tests: small datasets and artifacts of every kind, run-unique udp_multicast buses."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from target_sim.transport import BusConfig, resolve

ROOT = Path(__file__).resolve().parents[2]


def synthetic_columns(rows: int, seed: int = 5) -> dict[str, np.ndarray]:
    """A drive-like dataset at 5 Hz: torque and speed steps and ramps, slow coolant/ambient drift."""
    rng = np.random.default_rng(seed)
    t = np.arange(rows) * 0.2
    torque = np.round(np.clip(np.cumsum(rng.normal(0, 15, rows)), -600, 600), 1)
    speed = np.round(np.clip(np.abs(np.cumsum(rng.normal(0, 80, rows))), 0, 9000), 0)
    coolant = np.round(40 + 2 * np.sin(t / 60.0), 1)
    ambient = np.round(25 + 0.5 * np.sin(t / 90.0), 1)
    winding = np.round(40 + 30 * (1 - np.exp(-t / 300.0)), 1)
    surface = np.round(40 + 10 * (1 - np.exp(-t / 900.0)), 1)
    return {"time_s": t, "torque_Nm": torque, "speed_rpm": speed, "coolant_C": coolant, "ambient_C": ambient,
            "winding_C": winding, "rotor_surface_C": surface, "pm_C": np.round(surface + 5.0, 1)}


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory) -> Path:
    from bench.drive.dataset import write_dataset

    path = tmp_path_factory.mktemp("data") / "small.csv"
    write_dataset(path, synthetic_columns(600), {"coolant_setpoint_C": 40.0, "note": "synthetic test data"})
    return path


@pytest.fixture(scope="session")
def artifacts(tmp_path_factory) -> dict[str, Path]:
    """lti (balanced), original (lti, the paper's polynomial realization), pv, hammerstein (a real sigmoid)."""
    from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps
    from bench.model.builder import ModelSpec, SigmoidInputs, build_artifact
    from bench.thermal.parameters import TABLE1_REFINED
    from target_sim.artifact import dumps

    maps = nominal_loss_maps()
    sigmoid = SigmoidInputs.from_vector([900.0, 3000.0, 700.0, 120.0],
                                        np.r_[np.full(4, 2.0), np.zeros(4), np.full(4, 0.3), np.full(4, 0.8),
                                              np.zeros(4)])
    specs = {
        "lti": ModelSpec("lti-lptn", TABLE1_REFINED, 0.5, "zoh", "balanced", maps, VIRTUAL_MOTOR),
        "original": ModelSpec("lti-lptn", TABLE1_REFINED, 0.5, "zoh", "original", maps, VIRTUAL_MOTOR),
        "modal": ModelSpec("lti-lptn", TABLE1_REFINED, 0.5, "zoh", "modal", maps, VIRTUAL_MOTOR),
        "pv": ModelSpec("pv-lptn", TABLE1_REFINED, 0.5, "euler", "physical", maps, VIRTUAL_MOTOR),
        "hammerstein": ModelSpec("hammerstein", TABLE1_REFINED, 0.5, "zoh", "balanced", maps, VIRTUAL_MOTOR,
                                 sigmoid=sigmoid),
    }
    out = tmp_path_factory.mktemp("artifacts")
    paths = {}
    for name, spec in specs.items():
        paths[name] = out / f"{name}.json"
        paths[name].write_text(dumps(build_artifact(spec)), encoding="utf-8")
    return paths


@pytest.fixture
def udp_bus() -> BusConfig:
    """A udp_multicast bus no other test (or run) shares, on the machine-local group `auto` uses."""
    return resolve(BusConfig("udp_multicast"), session_unique=True)


def subprocess_env() -> dict[str, str]:
    env = dict(os.environ)
    env["MPLBACKEND"] = "Agg"
    env["PYTHONUNBUFFERED"] = "1"
    return env


def run_cli(*argv: str, cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *argv], cwd=cwd or ROOT, env=subprocess_env(), capture_output=True,
                          text=True, timeout=timeout)
