"""The estimator as the target runs it: every operation in float32, from the artifact's float32 coefficients.

One model step (period Δt from the artifact) does, in order:
1. losses at the reference temperature from the artifact's loss model (`target_sim.losses`: look-up tables
   bilinear in torque and speed, clamped, or the electrical formulas over the d/q currents and the speed);
2. the copper temperature correction of eqs. 3-5 and the stator split of eqs. 6-8, using the PREVIOUS estimate;
3. the model kind's part (`target_sim.modelkinds`, one module per kind): for `hammerstein` the per-input sigmoid
   nonlinearity S(u) = gain·σ(weight·u + bias) + linear·u + offset on the normalized losses u = P/scale
   (eqs. 28-30), then for `lti-lptn` and `hammerstein` the temperature sources of eqs. 9-18 from the PREVIOUS
   estimate, the speed and the coolant temperature, and the linear block x <- A x + B u, y = C x; for `pv-lptn`
   the parameter-varying network rebuilt from the speed and coolant and stepped by forward Euler (eq. 51), as
   the paper ran it.

Drive samples arrive at the data rate (5 Hz) and model steps run every Δt: the inputs of model step k are the
float32 mean of the samples whose times n·T_s fall in [kΔt, (k+1)Δt), and the step runs as soon as the last
sample of that interval has arrived (`InputAccumulator`). The offline float32 reference uses this same code.

The firmware engine runs the same computation as generated C (`bench firmware export`, fw_model.c), and the two
must agree bit for bit, so every operation here has a fixed order and a float32 rounding the C repeats: products
and sums written out left to right with explicit parentheses (the comments name the C function that mirrors each
method), matrix-vector products by `fmath.matvec` (no BLAS), exp by `fmath.exp_f32` (no np.exp), clamps written
as comparisons that send NaN the same way in both. Where this file or a kind's module changes an operation,
fw_model.c must change with it (bench/firmware/codegen.py, the kind's C fragment), and tests/bench/firmware checks
that they still agree.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from target_sim.artifact import LPTN_PARAMETERS, ModelArtifact
from target_sim.fmath import exp_f32, lanes
from target_sim.kinds import MODEL_KINDS
from target_sim.losses import LOSS_KINDS

F32 = np.float32
ONE = F32(1.0)


class Float32Estimator:
    """The target's model: load once, `reset` with initial temperatures, then `step` every Δt.

    Lanes: `reset` with (4, L) temperatures and `step` with (L,) inputs run L trajectories side by side (the
    robustness study's seeds), every lane bit for bit the one-trajectory run (`target_sim.fmath.matvec`).

    The front of the step (the loss model, eqs. 3-8) is here; the rest is the model kind's part
    (`target_sim.modelkinds`: the linear block with its sources, the sigmoid, the PV network), whose attributes
    and methods read as the estimator's own (`a`, `temperature_sources`, `input_nonlinearity`, ...).

    `dtype` is float32 on the target; float64 gives the same code in double precision from the artifact's
    float64 coefficients (the double-precision reference of the parameter-varying LPTN), with np.exp for exp.
    """

    def __init__(self, artifact: ModelArtifact, dtype=F32):
        self.f = f = np.dtype(dtype).type
        self.one = f(1.0)
        self.exp = exp_f32 if f is F32 else np.exp   # float32: the firmware's own exp, bit for bit

        def arr(*keys):
            return artifact.array(*keys, dtype=f)

        self.artifact = artifact
        self.kind = artifact.kind
        self.dt = f(artifact.dt)
        self.loss_kind = LOSS_KINDS[artifact.loss_model]
        self.luts = self.loss_kind.evaluator(artifact, f)   # target_sim.losses: the kind's own float32 code
        self.p = p = {name: arr("lptn", "parameters", name)[()] for name in LPTN_PARAMETERS}
        self.speed_max = arr("lptn", "speed_max_rpm")[()]
        self.current_max = arr("losses", "current_max_A")[()]
        self.alpha_cu = arr("losses", "alpha_cu_per_K")[()]
        self.copper_ref = arr("losses", "copper_reference_C")[()]
        # the three speed-dependent convection resistances (eq. 15), vectorized: [tm, wm, ma] (C: in this order)
        self.conv_b = np.array([p["b_tm"], p["b_wm"], p["b_ma"]], dtype=f)
        self.conv_r0 = np.array([p["R_tm0"], p["R_wm0"], p["R_ma0"]], dtype=f)
        self.conv_a = np.array([p["a_tm"], p["a_wm"], p["a_ma"]], dtype=f)
        self.model_kind = MODEL_KINDS[artifact.kind]
        self.part = self.model_kind.part(artifact, self)
        self.x = np.zeros(4, dtype=f)
        self.y = np.zeros(4, dtype=f)

    def reset(self, temperatures: Sequence[float]) -> None:
        """Start from physical temperatures [yoke, winding, tooth, magnet] (°C); the kind says the state
        (x0 = C^-1 y0, delta: C^-1 (y0 - r), pv-lptn: y0; C: fw_reset)."""
        self.y = np.asarray(temperatures, dtype=self.f).copy()
        self.x = self.part.reset(self.y)

    def restore(self, state: Sequence[float]) -> None:
        """Continue from a checkpointed state vector x (the realization's coordinates), bit for bit: y = C x (+ r)
        is what `step` left after the model step the checkpoint was taken at (C: fw_restore)."""
        self.x = np.asarray(state, dtype=self.f).copy()
        self.y = self.part.output(self.x)

    def output(self) -> np.ndarray:
        """The temperatures of the state: y = C x, delta: (C x) + r, pv-lptn: x."""
        return self.part.output(self.x)

    def node_losses(self, torque, speed, i_d=0.0, i_q=0.0) -> np.ndarray:
        """[P_y, P_w, P_t, P_m] in W from the loss model and the previous winding estimate (eqs. 3-8; C:
        node_losses)."""
        return self.corrected_losses(self.loss_lookup(torque, speed, i_d, i_q), speed)

    def loss_lookup(self, torque, speed, i_d=0.0, i_q=0.0) -> np.ndarray:
        """[p_dc0, p_ac0, p_stator, p_magnet, current] of the loss model at the operating point (it reads the
        values its kind names, in their order)."""
        point = {"torque_Nm": torque, "speed_rpm": speed, "i_d_A": i_d, "i_q_A": i_q}
        return self.luts.lookup(*(point[name] for name in self.loss_kind.inputs))

    def corrected_losses(self, lookup: np.ndarray, speed) -> np.ndarray:
        """[P_y, P_w, P_t, P_m]: the copper temperature correction at the previous winding estimate (eqs. 3-5) and
        the stator split (eqs. 6-8) of the looked-up losses."""
        p_dc0, p_ac0, p_stator, p_magnet, current = lookup
        p, f, one = self.p, self.f, self.one
        factor = one + self.alpha_cu * (self.y[1] - self.copper_ref)                 # eqs. 3-5
        p_w = (p_dc0 * factor) + (p_ac0 / factor)
        i_ratio, n_ratio = current / self.current_max, f(speed) / self.speed_max
        k_s = ((p["k_0"] + p["k_1"] * i_ratio) + p["k_2"] * n_ratio) + (p["k_3"] * i_ratio) * n_ratio   # eqs. 6-8
        return np.array([k_s * p_stator, p_w, (one - k_s) * p_stator, p_magnet], dtype=f)

    def convection(self, n_ratio) -> np.ndarray:
        """[e_tm, e_wm, e_ma] = exp(-n_ratio / b) of eq. 15, for the kinds' sources and networks (C: the three
        fw_exp calls, in this order); lanes of trajectories give (3, L...)."""
        return self.exp(-n_ratio / lanes(self.conv_b, n_ratio))

    def step(self, torque, speed, coolant, ambient, i_d=0.0, i_q=0.0) -> np.ndarray:
        """One model step with the interval-mean inputs (the d/q currents only for an electrical loss model);
        returns [yoke, winding, tooth, magnet] in °C (C: fw_step): the node losses, then the kind's step and
        output."""
        losses = self.node_losses(torque, speed, i_d, i_q)
        self.x = self.part.step(self.x, losses, speed, coolant, ambient)
        self.y = self.part.output(self.x)
        return self.y.copy()


class InputAccumulator:
    """Collects 5 Hz drive samples and releases the float32 interval mean when a model step is due.

    sum <- sum + sample elementwise in float32, mean = sum / float32(count) (C: fw_accumulate, fw_mean); when an
    interval ends is integer row logic that stays here (and in the node). `accumulate`, `mean` and `clear` are the
    sum alone, the interface the model firmware offers too (`target_sim.firmware.FirmwareEstimator`)."""

    def __init__(self, sample_period_s: float, dt_s: float, width: int = 4):
        self.sample_us = int(round(sample_period_s * 1e6))
        self.dt_us = int(round(dt_s * 1e6))
        self.width = width   # 4 drive values, 6 with the d/q currents
        self.sum = np.zeros(width, dtype=F32)
        self.count = 0

    def model_step_of(self, row: int) -> int:
        return row * self.sample_us // self.dt_us

    def ends_interval(self, row: int) -> bool:
        """Row `row` is the last sample of its model step's interval."""
        return self.model_step_of(row + 1) != self.model_step_of(row)

    def add(self, row: int, sample: Sequence[float]) -> np.ndarray | None:
        """Add row `row`; return the inputs of its model step if this row completes the interval."""
        self.accumulate(sample)
        if not self.ends_interval(row):
            return None
        return self.mean()

    def accumulate(self, sample: Sequence[float]) -> None:
        """sum <- sum + sample (C: fw_accumulate)."""
        self.sum += np.asarray(sample, dtype=F32)
        self.count += 1

    def mean(self) -> np.ndarray | None:
        """sum / float32(count), then cleared; None when nothing was accumulated (C: fw_mean)."""
        if not self.count:
            return None
        mean = self.sum / F32(self.count)
        self.clear()
        return mean

    def clear(self) -> None:
        self.sum = np.zeros(self.width, dtype=F32)
        self.count = 0


def run_offline(artifact: ModelArtifact, drive: np.ndarray, initial: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """The float32 reference over a whole dataset: drive is (rows, 4) [torque, speed, coolant, ambient], or
    (rows, 6) with [i_d, i_q] after them for an electrical loss model (`artifact.drive_signals`).

    Returns (rows_with_a_step, outputs): the row after which each model step ran and its (steps, 4) outputs,
    exactly what the target replies over CAN.
    """
    model = Float32Estimator(artifact)
    model.reset(initial)
    width = len(artifact.drive_signals)
    drive = np.asarray(drive)
    if drive.ndim != 2 or drive.shape[1] != width:
        raise ValueError(f"the {artifact.loss_model} loss model needs {width} drive columns "
                         f"({', '.join(artifact.drive_signals)}), not {drive.shape}")
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt, width)
    rows, outputs = [], []
    for row, sample in enumerate(np.asarray(drive, dtype=F32)):
        inputs = acc.add(row, sample)
        if inputs is not None:
            outputs.append(model.step(*inputs))
            rows.append(row)
    return np.array(rows, dtype=np.int64), np.array(outputs, dtype=F32).reshape(-1, 4)
