"""From drive data to what the estimator consumes: per-model-step inputs and the references to compare with."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.drive.motor import MAP_TABLES
from bench.errors import BenchError
from bench.motor.losses import EstimatorMotor, LossModel
from bench.thermal.estimator import StepInputs
from bench.thermal.excitation import interval_means
from target_sim.losses import DRIVE_SIGNALS, reads_currents, row_of_width, row_signals


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
    ref_yoke: np.ndarray | None = None    # measured yoke and tooth temperatures, when the data have them
    ref_tooth: np.ndarray | None = None

    def reference(self, node: str) -> np.ndarray | None:
        """The measured temperature of a node (winding, pm, yoke, tooth) at the step times, None if not measured."""
        return {"winding": self.ref_winding, "pm": self.ref_pm, "yoke": self.ref_yoke, "tooth": self.ref_tooth}[node]


def drive_matrix(dataset, columns: tuple[str, ...] = DRIVE_SIGNALS) -> np.ndarray:
    """(rows, 4) [torque, speed, coolant, ambient], what the host sends over CAN; (rows, 6) with [i_d, i_q] when
    `columns` (a model's `drive_signals`, `row_signals` of a loss model's inputs) has them."""
    if reads_currents(columns) and not dataset.has_currents:
        raise BenchError(f"{dataset.path} has no d/q current columns (i_d_A, i_q_A), which this motor's loss model "
                         "needs; map them with --mapping or use a motor with loss maps")
    return np.column_stack([dataset.column(c) for c in columns])


def initial_temperatures(dataset) -> np.ndarray:
    """The initial-state rule: every node as first measured; yoke and tooth, where the file does not measure them,
    at the first coolant sample (a machine soaked at its coolant). A file that measures them is a test bench's, and
    a hot start there (soaked at 70 °C, coolant 30 °C) would otherwise begin 40 K off in both (the motor suite's
    test profile p11). The built-in campaign measures neither: its runs start as before."""
    coolant = float(dataset.coolant_C[0])
    yoke = float(dataset.yoke_C[0]) if dataset.has("yoke_C") else coolant
    tooth = float(dataset.tooth_C[0]) if dataset.has("tooth_C") else coolant
    return np.array([yoke, float(dataset.winding_C[0]), tooth, float(dataset.pm_C[0])])


def step_inputs(drive: np.ndarray, loss_model: LossModel, motor: EstimatorMotor, dt: float,
                sample_period_s: float) -> StepInputs:
    """Interval means of the drive columns (4, or 6 with the currents) and the losses at them."""
    means = interval_means(drive, sample_period_s, dt)
    table = loss_model.evaluate_columns(dict(zip(row_of_width(means.shape[1]), means.T, strict=True)))
    return StepInputs(
        table_losses=np.column_stack([table[name] for name in MAP_TABLES]),
        speed_ratio=means[:, 1] / motor.max_speed_rpm,
        coolant=means[:, 2], ambient=means[:, 3], current_max=motor.i_max_A,
        alpha_cu=motor.alpha_cu_per_K, copper_reference=motor.reference_C)


def model_run(dataset, loss_model: LossModel, motor: EstimatorMotor, dt: float, name: str | None = None) -> ModelRun:
    drive = drive_matrix(dataset, row_signals(loss_model.inputs))
    inputs = step_inputs(drive, loss_model, motor, dt, dataset.sample_period_s)
    t_steps = float(dataset.time_s[0]) + (np.arange(len(inputs.speed_ratio)) + 1) * dt   # a file may start at t > 0
    return ModelRun(
        name=name or str(getattr(dataset, "path", "run")), dt=dt, inputs=inputs, step_time_s=t_steps,
        ref_winding=np.interp(t_steps, dataset.time_s, dataset.winding_C),
        ref_pm=np.interp(t_steps, dataset.time_s, dataset.pm_C),
        initial=initial_temperatures(dataset),
        ref_yoke=_measured(dataset, "yoke_C", t_steps), ref_tooth=_measured(dataset, "tooth_C", t_steps))


def _measured(dataset, column: str, t_steps: np.ndarray) -> np.ndarray | None:
    values = getattr(dataset, column, None)
    return None if values is None else np.interp(t_steps, dataset.time_s, values)
