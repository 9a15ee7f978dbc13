"""The estimator as the target runs it: every operation in float32, from the artifact's float32 coefficients.

One model step (period Δt from the artifact) does, in order:
1. losses at the reference temperature from the look-up tables (bilinear in torque and speed, clamped);
2. the copper temperature correction of eqs. 3-5 and the stator split of eqs. 6-8, using the PREVIOUS estimate;
3. for `hammerstein`, the per-input sigmoid nonlinearity S(u) = gain·σ(weight·u + bias) + linear·u + offset
   on the normalized losses u = P/scale (eqs. 28-30; MATLAB's sigmoidnet also has the linear term and offset);
4. the temperature sources of eqs. 9-18 from the PREVIOUS estimate, the speed and the coolant temperature;
5. the linear block x <- A x + B u, y = C x (`lti-lptn`, `hammerstein`), or for `pv-lptn` the parameter-varying
   network rebuilt from the speed and coolant and stepped by forward Euler (eq. 51), as the paper ran it.

Drive samples arrive at the data rate (5 Hz) and model steps run every Δt: the inputs of model step k are the
float32 mean of the samples whose times n·T_s fall in [kΔt, (k+1)Δt), and the step runs as soon as the last
sample of that interval has arrived (`InputAccumulator`). The offline float32 reference uses this same code.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from target_sim.artifact import LOSS_TABLES, LPTN_PARAMETERS, ModelArtifact

F32 = np.float32
ONE = F32(1.0)


class LossTables:
    """The artifact's loss look-up tables over the (torque, speed) grid, interpolated in float32."""

    def __init__(self, artifact: ModelArtifact, dtype=F32):
        self.f = f = np.dtype(dtype).type
        self.torque_axis = artifact.array("losses", "torque_axis_Nm", dtype=f)
        self.speed_axis = artifact.array("losses", "speed_axis_rpm", dtype=f)
        self.tables = np.stack([artifact.array("losses", "tables", name, dtype=f) for name in LOSS_TABLES])
        self.torque_step = f(self.torque_axis[1] - self.torque_axis[0])
        self.speed_step = f(self.speed_axis[1] - self.speed_axis[0])

    def _cell(self, value, start, step, size):
        """Index of the grid cell holding value, and the fraction inside it (clamped to the grid)."""
        f = self.f
        pos = (f(value) - start) / step
        pos = min(max(pos, f(0.0)), f(size - 1))
        i = min(int(pos), size - 2)
        return i, f(pos - f(i))

    def lookup(self, torque, speed) -> np.ndarray:
        """[p_dc0, p_ac0, p_stator, p_magnet, current] at one operating point."""
        i, fi = self._cell(torque, self.torque_axis[0], self.torque_step, self.torque_axis.size)
        j, fj = self._cell(speed, self.speed_axis[0], self.speed_step, self.speed_axis.size)
        t = self.tables[:, i:i + 2, j:j + 2]
        low = t[:, 0, 0] + fj * (t[:, 0, 1] - t[:, 0, 0])
        high = t[:, 1, 0] + fj * (t[:, 1, 1] - t[:, 1, 0])
        return low + fi * (high - low)


class Float32Estimator:
    """The target's model: load once, `reset` with initial temperatures, then `step` every Δt.

    `dtype` is float32 on the target; float64 gives the same code in double precision from the artifact's
    float64 coefficients (the double-precision reference of the parameter-varying LPTN).
    """

    def __init__(self, artifact: ModelArtifact, dtype=F32):
        self.f = f = np.dtype(dtype).type
        self.one = f(1.0)

        def arr(*keys):
            return artifact.array(*keys, dtype=f)

        self.artifact = artifact
        self.kind = artifact.kind
        self.dt = f(artifact.dt)
        self.luts = LossTables(artifact, f)
        self.p = {name: arr("lptn", "parameters", name)[()] for name in LPTN_PARAMETERS}
        self.speed_max = arr("lptn", "speed_max_rpm")[()]
        self.current_max = arr("losses", "current_max_A")[()]
        self.alpha_cu = arr("losses", "alpha_cu_per_K")[()]
        self.copper_ref = arr("losses", "copper_reference_C")[()]
        if self.kind != "pv-lptn":
            self.a, self.b = arr("linear_block", "A"), arr("linear_block", "B")
            self.c, self.c_inv = arr("linear_block", "C"), arr("linear_block", "C_inv")
        if self.kind == "hammerstein":
            self.sigmoid = {k: arr("input_nonlinearity", k)
                            for k in ("scale_W", "weight", "bias", "gain", "linear", "offset")}
        self.x = np.zeros(4, dtype=f)
        self.y = np.zeros(4, dtype=f)

    def reset(self, temperatures: Sequence[float]) -> None:
        """Start from physical temperatures [yoke, winding, tooth, magnet] (°C): x0 = C^-1 y0."""
        self.y = np.asarray(temperatures, dtype=self.f).copy()
        self.x = self.y.copy() if self.kind == "pv-lptn" else self.c_inv @ self.y

    def restore(self, state: Sequence[float]) -> None:
        """Continue from a checkpointed state vector x (the realization's coordinates), bit for bit: y = C x is
        what `step` left after the model step the checkpoint was taken at."""
        self.x = np.asarray(state, dtype=self.f).copy()
        self.y = self.x.copy() if self.kind == "pv-lptn" else self.c @ self.x

    def node_losses(self, torque, speed) -> np.ndarray:
        """[P_y, P_w, P_t, P_m] in W from the tables and the previous winding estimate (eqs. 3-8)."""
        p_dc0, p_ac0, p_stator, p_magnet, current = self.luts.lookup(torque, speed)
        p, f, one = self.p, self.f, self.one
        factor = one + self.alpha_cu * (self.y[1] - self.copper_ref)
        p_w = p_dc0 * factor + p_ac0 / factor
        i_ratio, n_ratio = current / self.current_max, f(speed) / self.speed_max
        k_s = p["k_0"] + p["k_1"] * i_ratio + p["k_2"] * n_ratio + p["k_3"] * i_ratio * n_ratio
        return np.array([k_s * p_stator, p_w, (one - k_s) * p_stator, p_magnet], dtype=f)

    def input_nonlinearity(self, losses: np.ndarray) -> np.ndarray:
        s = self.sigmoid
        u = losses / s["scale_W"]
        out = s["gain"] / (self.one + np.exp(-(s["weight"] * u + s["bias"]))) + s["linear"] * u + s["offset"]
        return out * s["scale_W"]

    def temperature_sources(self, speed, coolant, ambient) -> np.ndarray:
        """[ϑ_cv, ϑ_av, ϑ_a1, ϑ_a2] of eqs. 9-18 from the previous estimate."""
        p, y, f, one = self.p, self.y, self.f, self.one
        n_ratio = f(speed) / self.speed_max
        coolant, ambient = f(coolant), f(ambient)
        g_tm = p["R_tm0"] * np.exp(-n_ratio / p["b_tm"]) / p["a_tm"]
        g_wm = p["R_wm0"] * np.exp(-n_ratio / p["b_wm"]) / p["a_wm"]
        g_ma = p["R_ma0"] * np.exp(-n_ratio / p["b_ma"]) / p["a_ma"]
        g_cy = p["alpha_cy"] * (coolant - f(40.0))  # R_cy01 / R_cy0 (eq. 16)
        th_y, th_w, th_t, th_m = y
        return np.array([
            coolant + g_cy * (th_y - coolant) / (one + g_cy),
            ambient + g_ma * (th_m - ambient) / (one + g_ma),
            (th_m + g_tm * th_t) / (one + g_tm),
            (th_w + g_wm * th_m) / (one + g_wm),
        ], dtype=f)

    def pv_network(self, speed, coolant) -> tuple[np.ndarray, np.ndarray]:
        """Continuous A (4x4) and B (4x6) of the parameter-varying LPTN, built in float32."""
        p, f, one = self.p, self.f, self.one
        n_ratio = f(speed) / self.speed_max
        r_wm = p["R_wm0"] * np.exp(-n_ratio / p["b_wm"]) + p["a_wm"]
        r_tm = p["R_tm0"] * np.exp(-n_ratio / p["b_tm"]) + p["a_tm"]
        r_ma = p["R_ma0"] * np.exp(-n_ratio / p["b_ma"]) + p["a_ma"]
        r_cy = p["R_cy0"] * (one + p["alpha_cy"] * (f(coolant) - f(40.0)))
        g = np.zeros((4, 6), dtype=f)  # conductances from node i to node j (y, w, t, m, coolant, ambient)
        for i, j, res in ((0, 1, p["R_yw"]), (0, 2, p["R_yt"]), (1, 2, p["R_wt"]), (1, 3, r_wm), (2, 3, r_tm)):
            g[i, j] = g[j, i] = one / res
        g[3, 5], g[0, 4] = one / r_ma, one / r_cy
        inv_c = one / np.array([p["C_y"], p["C_w"], p["C_t"], p["C_m"]], dtype=f)
        a = g[:, :4] * inv_c[:, None]
        a[np.diag_indices(4)] = -g.sum(axis=1, dtype=f) * inv_c
        b = np.zeros((4, 6), dtype=f)
        b[np.diag_indices(4)] = inv_c
        b[:, 4:] = g[:, 4:] * inv_c[:, None]
        return a, b

    def step(self, torque, speed, coolant, ambient) -> np.ndarray:
        """One model step with the interval-mean inputs; returns [yoke, winding, tooth, magnet] in °C."""
        losses = self.node_losses(torque, speed)
        if self.kind == "hammerstein":
            losses = self.input_nonlinearity(losses)
        if self.kind == "pv-lptn":
            a, b = self.pv_network(speed, coolant)
            u = np.concatenate([losses, np.array([coolant, ambient], dtype=self.f)])
            self.x = self.x + self.dt * (a @ self.x + b @ u)
            self.y = self.x.copy()
        else:
            u = np.concatenate([losses, self.temperature_sources(speed, coolant, ambient)])
            self.x = self.a @ self.x + self.b @ u
            self.y = self.c @ self.x
        return self.y.copy()


class InputAccumulator:
    """Collects 5 Hz drive samples and releases the float32 interval mean when a model step is due."""

    def __init__(self, sample_period_s: float, dt_s: float):
        self.sample_us = int(round(sample_period_s * 1e6))
        self.dt_us = int(round(dt_s * 1e6))
        self.sum = np.zeros(4, dtype=F32)
        self.count = 0

    def model_step_of(self, row: int) -> int:
        return row * self.sample_us // self.dt_us

    def add(self, row: int, sample: Sequence[float]) -> np.ndarray | None:
        """Add row `row`; return the inputs of its model step if this row completes the interval."""
        self.sum += np.asarray(sample, dtype=F32)
        self.count += 1
        if self.model_step_of(row + 1) == self.model_step_of(row):
            return None
        mean = self.sum / F32(self.count)
        self.sum = np.zeros(4, dtype=F32)
        self.count = 0
        return mean

    def clear(self) -> None:
        self.sum[:] = 0
        self.count = 0


def run_offline(artifact: ModelArtifact, drive: np.ndarray, initial: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """The float32 reference over a whole dataset: drive is (rows, 4) [torque, speed, coolant, ambient].

    Returns (rows_with_a_step, outputs): the row after which each model step ran and its (steps, 4) outputs,
    exactly what the target replies over CAN.
    """
    model = Float32Estimator(artifact)
    model.reset(initial)
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt)
    rows, outputs = [], []
    for row, sample in enumerate(np.asarray(drive, dtype=F32)):
        inputs = acc.add(row, sample)
        if inputs is not None:
            outputs.append(model.step(*inputs))
            rows.append(row)
    return np.array(rows, dtype=np.int64), np.array(outputs, dtype=F32).reshape(-1, 4)
