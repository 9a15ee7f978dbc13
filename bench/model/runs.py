"""From drive data to what the estimator consumes: per-model-step inputs and the references to compare with."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.drive.motor import MAP_TABLES, LossMaps, MotorSpec
from bench.thermal.estimator import StepInputs
from bench.thermal.excitation import interval_means


@dataclass(frozen=True)
class ModelRun:
    """One dataset prepared for a model step Δt: inputs per step, measured references at the step times."""

    name: str
    dt: float
    inputs: StepInputs
    step_time_s: np.ndarray     # (steps,) the time each output refers to: (k+1)·Δt
    ref_winding: np.ndarray     # measured winding temperature at step_time_s (linear interpolation)
    ref_pm: np.ndarray
    initial: np.ndarray         # y0 = [yoke, winding, tooth, magnet] at t = 0


def drive_matrix(dataset) -> np.ndarray:
    """(rows, 4) [torque, speed, coolant, ambient]: what the host sends over CAN."""
    return np.column_stack([dataset.torque_Nm, dataset.speed_rpm, dataset.coolant_C, dataset.ambient_C])


def initial_temperatures(dataset) -> np.ndarray:
    """The initial-state rule: yoke and tooth at the first coolant sample, winding and PM as first measured."""
    coolant = float(dataset.coolant_C[0])
    return np.array([coolant, float(dataset.winding_C[0]), coolant, float(dataset.pm_C[0])])


def step_inputs(drive: np.ndarray, loss_maps: LossMaps, motor: MotorSpec, dt: float,
                sample_period_s: float) -> StepInputs:
    means = interval_means(drive, sample_period_s, dt)
    table = loss_maps.evaluate(means[:, 0], means[:, 1])
    return StepInputs(
        table_losses=np.column_stack([table[name] for name in MAP_TABLES]),
        speed_ratio=means[:, 1] / motor.max_speed_rpm,
        coolant=means[:, 2], ambient=means[:, 3], current_max=motor.i_max_A)


def model_run(dataset, loss_maps: LossMaps, motor: MotorSpec, dt: float, name: str | None = None) -> ModelRun:
    drive = drive_matrix(dataset)
    inputs = step_inputs(drive, loss_maps, motor, dt, dataset.sample_period_s)
    t_steps = (np.arange(len(inputs.speed_ratio)) + 1) * dt
    return ModelRun(
        name=name or str(getattr(dataset, "path", "run")), dt=dt, inputs=inputs, step_time_s=t_steps,
        ref_winding=np.interp(t_steps, dataset.time_s, dataset.winding_C),
        ref_pm=np.interp(t_steps, dataset.time_s, dataset.pm_C),
        initial=initial_temperatures(dataset))
