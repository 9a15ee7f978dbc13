"""Fixtures of the firmware tests: small artifacts of every kind x realization x Δt, their ELFs (built once per
session), and a drive that runs the model through the loss tables' edges; the same with an electrical loss model
(losses from the d/q currents) and a drive with currents."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from helpers import electrical_artifact_text, model_spec, synthetic_columns, with_currents

KIND_REALIZATIONS = [("lti-lptn", r) for r in ("physical", "original", "balanced", "modal")]
KIND_REALIZATIONS += [("hammerstein", r) for r in ("physical", "original", "balanced", "modal")]
KIND_REALIZATIONS += [("pv-lptn", "physical")]


def _artifact(kind: str, realization: str, dt: float):
    """A verified artifact of the packaged parameters with nominal maps (`helpers.model_spec`) at step `dt`."""
    from bench.model.builder import build_artifact
    from target_sim.artifact import verify

    spec = dataclasses.replace(model_spec(kind, realization), dt=dt)
    if realization == "delta":
        spec = dataclasses.replace(spec, reference_C=60.0)   # the deviation form's path, not just r = 0
    return verify(build_artifact(spec))


@pytest.fixture(scope="session")
def artifact_of() -> Callable:
    """artifact_of(kind, realization, dt) -> a verified artifact (packaged parameters, nominal maps)."""
    return _artifact


@pytest.fixture(scope="session")
def firmware_of(firmware_builds) -> Callable:
    """firmware_of(kind, realization, dt) -> (artifact, BuildResult), built once per run (`firmware_builds`)."""
    from bench.firmware.codegen import generate

    built: dict = {}

    def get(kind: str, realization: str, dt: float):
        key = (kind, realization, dt)
        if key not in built:
            artifact = _artifact(kind, realization, dt)
            built[key] = (artifact, firmware_builds.build(generate(artifact)))
        return built[key]

    return get


def _electrical(kind: str, realization: str, dt: float, directory):
    """`_artifact(kind, realization, dt)` with an electrical loss model (`helpers.electrical_artifact_text`)."""
    import json

    from target_sim.artifact import dumps, verify

    base = directory / f"{kind}-{realization}-{dt:g}.json"
    base.write_text(dumps(_artifact(kind, realization, dt).content), encoding="utf-8")
    return verify(json.loads(electrical_artifact_text(base)))


@pytest.fixture(scope="session")
def electrical_of(tmp_path_factory, firmware_builds) -> Callable:
    """electrical_of(kind, realization, dt) -> (artifact with an electrical loss model, BuildResult), built once per
    run (`firmware_builds`)."""
    from bench.firmware.codegen import generate

    directory = tmp_path_factory.mktemp("electrical")
    built: dict = {}

    def get(kind: str, realization: str, dt: float):
        key = (kind, realization, dt)
        if key not in built:
            artifact = _electrical(kind, realization, dt, directory)
            built[key] = (artifact, firmware_builds.build(generate(artifact)))
        return built[key]

    return get


@pytest.fixture(scope="session")
def electrical_drive() -> np.ndarray:
    return drive_rows_with_currents()


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


def drive_rows_with_currents(rows: int = 300, seed: int = 5) -> np.ndarray:
    """(rows, 6) float32 [torque, speed, coolant, ambient, i_d, i_q] at 5 Hz (CAN resolution): `drive_rows` with
    d/q currents that follow the torque (`helpers.with_currents`), and a few rows at the edges of the DBC's ranges
    and of the formulas: no current (sqrt(0)), ±3000 A, a reverse and a standing speed, a tiny current."""
    c = with_currents(synthetic_columns(rows, seed, torque_offset=150.0, speed_offset=2500.0), seed=seed)
    drive = np.column_stack([c["torque_Nm"], c["speed_rpm"], c["coolant_C"], c["ambient_C"], c["i_d_A"],
                             c["i_q_A"]])
    for row, speed, i_d, i_q in ((40, 9500.0, -3000.0, 3000.0), (41, -900.0, 0.0, 0.0), (42, 0.0, -0.1, 0.1),
                                 (43, -500.0, 3000.0, -3000.0), (44, 0.0, 0.0, 0.0), (45, 15000.0, -1234.5, 7.3)):
        if row < rows:
            drive[row, [1, 4, 5]] = speed, i_d, i_q
    return drive.astype(np.float32)
