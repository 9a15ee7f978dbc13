"""Fixtures of the firmware tests: small artifacts of every kind x realization x Δt, their ELFs (built once per
session), and a drive that runs the model through the loss tables' edges."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from helpers import model_spec, synthetic_columns

KIND_REALIZATIONS = [("lti-lptn", r) for r in ("physical", "original", "balanced", "modal")]
KIND_REALIZATIONS += [("hammerstein", r) for r in ("physical", "original", "balanced", "modal")]
KIND_REALIZATIONS += [("pv-lptn", "physical")]


def _artifact(kind: str, realization: str, dt: float):
    """A verified artifact of the packaged parameters with nominal maps (`helpers.model_spec`) at step `dt`."""
    from bench.model.builder import build_artifact
    from target_sim.artifact import verify

    spec = dataclasses.replace(model_spec(kind, realization), dt=dt)
    return verify(build_artifact(spec))


@pytest.fixture(scope="session")
def artifact_of() -> Callable:
    """artifact_of(kind, realization, dt) -> a verified artifact (packaged parameters, nominal maps)."""
    return _artifact


@pytest.fixture(scope="session")
def firmware_of() -> Callable:
    """firmware_of(kind, realization, dt) -> (artifact, BuildResult), built once per session."""
    from bench.firmware.codegen import generate
    from bench.firmware.toolchain import build_firmware

    built: dict = {}

    def get(kind: str, realization: str, dt: float):
        key = (kind, realization, dt)
        if key not in built:
            artifact = _artifact(kind, realization, dt)
            built[key] = (artifact, build_firmware(generate(artifact)))
        return built[key]

    return get


@pytest.fixture(scope="session")
def drive() -> np.ndarray:
    return drive_rows()


@pytest.fixture(scope="session")
def initial() -> np.ndarray:
    """Initial temperatures [yoke, winding, tooth, magnet] (°C)."""
    return np.array([41.0, 52.5, 44.0, 47.5], dtype=np.float32)


def drive_rows(rows: int = 300, seed: int = 5) -> np.ndarray:
    """(rows, 4) float32 [torque, speed, coolant, ambient] at 5 Hz: a synthetic drive (CAN resolution) with a
    few rows beyond the loss grid (torque ±700 Nm, speed 9500 rpm, reverse speed) so the clamps run too."""
    c = synthetic_columns(rows, seed, torque_offset=150.0, speed_offset=2500.0)
    drive = np.column_stack([c["torque_Nm"], c["speed_rpm"], c["coolant_C"], c["ambient_C"]])
    for row, torque, speed in ((40, 700.0, 9500.0), (41, -700.0, 9500.0), (42, 640.0, 9000.0),
                               (43, -640.0, 0.0), (44, 0.0, -20.0)):
        if row < rows:
            drive[row, :2] = torque, speed
    return drive.astype(np.float32)
