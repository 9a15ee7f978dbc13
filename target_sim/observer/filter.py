"""The observer as the target runs it: a discrete Kalman filter on the linear block, in float32.

The model step (`target_sim.model.Float32Estimator.step`) is the filter's prediction of the state. The filter adds
the covariance: the block's one-step map is x <- F x + (inputs), with F = A + B_s G C in shift form and
F = I + Δ·(A + B_s G C) in delta form, where G = d(sources)/d(estimate) at the step's speed and coolant (the
temperature sources of eqs. 9-18 are linear in the previous estimate; `LinearBlockPart.source_jacobian`). The
losses' dependence on the winding estimate (eqs. 3-5) is left out of F. A measurement z of one node (a winding
sensor: the artifact's `observer.node`, lag ignored) then corrects the state: innovation ν = (z - offset) - y_node,
x <- x + K ν, and the corrected estimate feeds the next step's losses, sigmoid and sources. A row without a
measurement (NaN) predicts only.

The covariance is kept in one of four forms (`OBSERVER_FORMS` of `target_sim.observer.forms`: conventional, joseph,
ud, steady).

Consider states (the section's `consider`, `target_sim.artifact.CONSIDER_KINDS`): a measurement that does not read
the kind's node holds it (and the kind's bias state): the gain's held rows are -0, K = K_opt - δ, and each form
keeps the covariance of that gain, P_opt + s δ δᵀ (s = h P⁻ hᵀ + R): `joseph` by its own formula (valid for any
gain), `conventional` by adding s δ δᵀ over the held rows to its optimal update, `ud` by Agee and Turner's rank-one
update (P_opt + γ v vᵀ, v = P⁻hᵀ on the held rows, γ = 1/s) after Bierman's, `steady` with the lab's consider
steady state (the held rows of K_ss set to -0 here, exactly).

The innovation gate (the section's optional `gate`, `target_sim.artifact.observer_gate`; absent: none, every
valid reading updates as before): a reading with ν·ν > sigma²·S (S = h P⁻ hᵀ + R as the form's update computes it,
`innovation_variance`; the steady form: its steady prior's h P⁻ hᵀ, from P_ss and K_ss, + R) is rejected: that
measurement predicts only this step (its innovation NaN). Rejections are counted per measurement; `flag_after` of one
measurement in a row flag its sensor (latched until a reset or restore). Re-admission: the propagated forms'
covariance grows while a sensor is rejected, so a sensor that truly moved passes again; the steady form admits the
next reading after `flag_after` rejections in a row.

Every operation has a fixed order and a float32 rounding (`fmath.matmul`, `fmath.dot`, elementwise ufuncs), so a C
version can repeat it bit for bit. The artifact stores Q, P0, K_ss and P_ss in the realization's coordinates; the
filter runs in node coordinates (`target_sim.observer.coordinates`: the node temperatures y = C x and the extra
states), where Q is diag(q_nodes), a measurement's row h is what its sensor sees and F needs no product by C. Its
gain corrects the node temperatures (the next measurement of the step reads them), and after the step's last update
x moves by C⁻¹ of the summed correction and y = C x again. `covariance()` is back in the state coordinates.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from target_sim.artifact import (
    BIAS_KINDS,
    OUTPUT_BIAS_KINDS,
    OUTPUTS,
    ModelArtifact,
    consider_held,
    consider_release,
    consider_released,
    observer_gate,
)
from target_sim.fmath import dot, matvec
from target_sim.kinds import MODEL_KINDS
from target_sim.model import F32, Float32Estimator
from target_sim.modelkinds.lti_lptn import SOURCE_JACOBIAN_NONZERO
from target_sim.observer.coordinates import NodeCoordinates
from target_sim.observer.forms import OBSERVER_FORMS, Conventional, covariance_form
from target_sim.observer.section import ObserverError, bias_input, has_observer, load_measurements
from target_sim.observer.ud import BiermanThornton
from target_sim.observer.ud_structure import NEG_ZERO, held_gain, masked_dot, masked_matmul, pattern_product, structural

Q_NODES_TOLERANCE = 1e-6            # T Q Tᵀ against diag(q_nodes), relative: float64 rounding of the lab's transform


class Float32Observer:
    """The estimator of `artifact` with its observer (`form`: the artifact's deployed one unless given).

    `step(..., z)` runs the model step, propagates the covariance and corrects with every measurement that has a
    valid reading this step; z holds the raw channels of the measurements in order (a number when there is one
    channel; NaN: none); returns [yoke, winding, tooth, magnet]. `sigma()` is each node's 1-σ (from C P Cᵀ)."""

    def __init__(self, artifact: ModelArtifact, form: str | None = None, dtype=F32):
        if not MODEL_KINDS[artifact.kind].linear_block:
            raise ObserverError(f"an observer needs a linear block; a {artifact.kind} artifact has none")
        if not has_observer(artifact):
            raise ObserverError("the artifact has no observer section; add one with 'bench observer'")
        self.est = est = Float32Estimator(artifact, dtype)
        section = artifact.content["observer"]
        self.form = OBSERVER_FORMS[form or section["form"]].name
        f = self.f = est.f

        def arr(key):
            return artifact.array("observer", key, dtype=f)

        self.measurements = load_measurements(section, f)
        self.node = OUTPUTS.index(section["node"])
        part = est.part
        self.n = n = artifact.array("observer", "Q").shape[0]
        self.coordinates = NodeCoordinates(part.c, n)
        to_nodes = self.coordinates.covariance
        self.q_nodes = arr("q_nodes_C2")
        self.q = np.diag(self.q_nodes).astype(f)        # Q in node coordinates
        error = self.coordinates.process_noise_error(artifact.array("observer", "Q", dtype=np.float64),
                                                     artifact.array("observer", "q_nodes_C2", dtype=np.float64))
        if not error <= Q_NODES_TOLERANCE:
            raise ObserverError(f"the observer's Q is not C⁻¹ diag(q_nodes_C2) C⁻ᵀ (off by {error:.3g} of the "
                                "largest q); write the section with 'bench observer'")
        self.p0 = to_nodes(artifact.array("observer", "P0", dtype=np.float64), f)
        self.gain_steady = self.coordinates.vectors(artifact.array("observer", "K_ss", dtype=np.float64)
                                                    .reshape(-1, n), f)
        self.p_steady = to_nodes(artifact.array("observer", "P_ss", dtype=np.float64), f)
        # consider states: per measurement the states its update holds (node coordinates), None: none
        held = consider_held(section.get("consider"), np.array([m.sees for m in self.measurements]),
                             section.get("bias"), n)
        self.held = [row if row.any() else None for row in held]
        # the key-on release (the section's consider_release_C2; None: held always): while the magnet's variance
        # before an update exceeds it, a measurement holds only `released` (the magnet and a magnet bias free); the
        # steady form has no covariance to ask and holds always
        release = consider_release(section)
        self.release = None if release is None or self.form == "steady" else f(release)
        self.released = [None if h is None else (row if row.any() else None)
                         for h, row in zip(self.held, consider_released(held, section.get("bias")), strict=True)]
        self.magnet_row = np.zeros(n, dtype=f)
        self.magnet_row[OUTPUTS.index("magnet")] = f(1.0)
        for index, row in enumerate(self.held):
            if row is not None:      # the lab wrote them zero up to rounding; the target holds them exactly
                self.gain_steady[index] = held_gain(self.gain_steady[index], row)
        # the augmented layout: lag states after the model's, then the bias
        self.lag_index, nxt = [], len(OUTPUTS)
        for m in self.measurements:
            self.lag_index.append(nxt if m.lag_pole > 0 else -1)
            nxt += 1 if m.lag_pole > 0 else 0
        self.bias_index = nxt if section.get("bias") else -1
        # an output bias (`OUTPUT_BIAS_KINDS`): added to its node's output, heats nothing (-1: none, or a heat bias)
        self.bias_output = BIAS_KINDS[section["bias"]] if section.get("bias") in OUTPUT_BIAS_KINDS else -1
        self.bias_input = bias_input(section)
        self.bias_column = part.b[:, self.bias_input] * (est.dt if part.delta else f(1.0))
        if self.bias_output >= 0:
            self.bias_column = np.zeros_like(self.bias_column)
        # the filter's rows h in node coordinates: a lag state, or what the sensor sees of the nodes
        self.rows = []
        for lag, m in zip(self.lag_index, self.measurements, strict=True):
            h = np.zeros(n, dtype=f)
            if lag >= 0:
                h[lag] = f(1.0)
            else:
                h[: len(OUTPUTS)] = m.sees
                if self.bias_output >= 0:
                    h[self.bias_index] = m.sees[self.bias_output]
            self.rows.append(h)
        self.h = self.rows[0]
        self.offset = getattr(self.measurements[0], "offset", f(0.0))
        self.r = getattr(self.measurements[0], "r", f(np.nan))
        self.widths = [m.width for m in self.measurements]
        self.extra = np.zeros(n - len(OUTPUTS), dtype=f)
        self.innovations = np.full(len(self.measurements), np.nan, dtype=f)
        self.innovation = f(np.nan)
        self._transition_structure()
        self.cov = self._covariance()
        gate = observer_gate(section)
        # the gate: ν² > sigma² S rejects a reading (None: every valid reading updates)
        self.gate_threshold = None if gate is None else f(gate[0]) * f(gate[0])
        self.flag_after = None if gate is None else gate[1]
        self.clear_gate()

    def set_process_noise(self, index: int, value: float) -> None:
        """Calibrate Q's diagonal element `index` (node coordinates; XCP DOWNLOAD): the next prediction adds it,
        and a RESET keeps it. An element that is 0 stays 0 (no column of G carries it: the filter's structure)."""
        if float(self.q_nodes[index]) == 0.0 or self.form == "steady":
            raise ObserverError(f"Q[{index},{index}] is not calibratable in this {self.form} filter")
        value = self.f(value)
        self.q_nodes = self.q_nodes.copy()     # the artifact's array is shared: never written in place
        self.q_nodes[index] = value
        self.q[index, index] = value           # the conventional and Joseph forms add this very matrix
        if isinstance(self.cov, BiermanThornton):
            self.cov.q_kept[list(self.cov.g_columns).index(index)] = value

    def clear_gate(self) -> None:
        """No reading rejected yet, no sensor flagged (a reset, and so a restore: the counts start again, in C too)."""
        count = len(self.measurements)
        self.rejections = np.zeros(count, dtype=np.int64)       # each measurement's rejected readings
        self.consecutive = np.zeros(count, dtype=np.int64)      # ... rejected in a row, up to now
        self.flagged = np.zeros(count, dtype=bool)              # ... flag_after in a row at least once (latched)
        self.rejected = np.zeros(count, dtype=bool)             # ... rejected this step

    def gate(self, index: int, nu, s) -> bool:
        """Whether the gate rejects the index-th measurement's reading of innovation ν and variance S
        (ν·ν > sigma²·S in the filter's precision, the C's comparison), counting it."""
        readmit = self.form == "steady" and self.consecutive[index] >= self.flag_after
        if self.gate_threshold is None or not nu * nu > self.gate_threshold * s or readmit:
            # re-admission: a propagated covariance grows while a sensor's readings are rejected (S widens until a
            # sensor that truly moved passes); the steady form's S never widens, so after flag_after rejections in
            # a row its next reading is admitted (the flag stays)
            self.consecutive[index] = 0
            return False
        self.rejected[index] = True
        self.rejections[index] += 1
        self.consecutive[index] += 1
        if self.consecutive[index] >= self.flag_after:
            self.flagged[index] = True
        return True

    def holds(self, index: int) -> np.ndarray | None:
        """The states the index-th measurement's update holds now: its consider states, or while the magnet's
        variance exceeds the key-on release (`innovation_variance` of the magnet's unit row with R = 0, the C's
        obs_magnet_variance, the same bits) those with the magnet free."""
        held = self.held[index]
        if held is None or self.release is None or not held[OUTPUTS.index("magnet")]:
            return held
        if self.cov.innovation_variance(self.magnet_row, self.f(0.0)) > self.release:
            return self.released[index]
        return held

    def _covariance(self):
        return covariance_form(self.form, self.p0, self.q, self.q_nodes, self.gain_steady, self.p_steady, self.rows,
                               self.f)

    def reset(self, temperatures: Sequence[float]) -> None:
        """The model at `temperatures`; each lag state at the temperature its sensor sees, the bias 0."""
        self.est.reset(temperatures)
        self.extra = np.zeros(self.n - len(OUTPUTS), dtype=self.f)
        for m, lag in zip(self.measurements, self.lag_index, strict=True):
            if lag >= 0:
                self.extra[lag - len(OUTPUTS)] = dot(m.sees, self.est.y)
        self.cov = self._covariance()
        self.innovations = np.full(len(self.measurements), np.nan, dtype=self.f)
        self.innovation = self.f(np.nan)
        self.clear_gate()

    def reset_lags(self) -> None:
        """Each lag state at the temperature its sensor sees of the current estimate, the bias 0 (a restore
        without the filter's checkpoint)."""
        self.extra = np.zeros(self.n - len(OUTPUTS), dtype=self.f)
        for m, lag in zip(self.measurements, self.lag_index, strict=True):
            if lag >= 0:
                self.extra[lag - len(OUTPUTS)] = dot(m.sees, self.est.y)

    def checkpoint(self) -> np.ndarray:
        """The filter's state beyond the model's x, float32 bit for bit, in the order of the ObserverCheckpoint
        frames (DBC 1.7.0): the extra states (lags in measurement order, then the bias), then the covariance in the
        deployed form, in the filter's node coordinates: UD d_0..d_{n-1} then U above the diagonal row by row;
        conventional and Joseph P row by row; the steady-state gain nothing; then, for the steady form with a gate,
        each measurement's rejections in a row (its re-admission depends on them: `gate`)."""
        parts = [self.extra]
        cov = self.cov
        if isinstance(cov, BiermanThornton):
            parts += [cov.d, cov.u[np.triu_indices(self.n, 1)]]
        elif isinstance(cov, Conventional):
            parts.append(cov.p.reshape(-1))
        if self._counts_in_checkpoint():
            parts.append(self.consecutive.astype(self.f))
        return np.concatenate(parts).astype(self.f)

    def _counts_in_checkpoint(self) -> bool:
        return self.form == "steady" and self.gate_threshold is not None

    def checkpoint_size(self) -> int:
        return len(self.checkpoint())

    def restore_checkpoint(self, values: Sequence[float]) -> None:
        """The extra states and covariance from `checkpoint()`'s values (ValueError when the count differs)."""
        values = np.asarray(values, dtype=self.f)
        if len(values) != self.checkpoint_size():
            raise ValueError(f"an observer checkpoint of this filter has {self.checkpoint_size()} elements, "
                             f"not {len(values)}")
        k = self.n - len(OUTPUTS)
        self.extra = values[:k].copy()
        rest = values[k:]
        cov = self.cov
        if isinstance(cov, BiermanThornton):
            cov.d = rest[: self.n].copy()
            u = np.eye(self.n, dtype=self.f)
            u[np.triu_indices(self.n, 1)] = rest[self.n:]
            cov.u = u
        elif isinstance(cov, Conventional):
            cov.p = rest.reshape(self.n, self.n).copy()
        if self._counts_in_checkpoint():
            # a count that is not one (a forged element: NaN, negative, huge) is 0, as the C's conversion guard
            counts = rest[len(rest) - len(self.consecutive):]
            self.consecutive = np.array([int(v) if 0 < v < 1e9 else 0 for v in counts], dtype=np.int64)

    def _transition_structure(self) -> None:
        """The constants of F in node coordinates (`target_sim.observer.coordinates`), hoisted: C (I + Δ A) C⁻¹ and
        Δ C B_s (shift form: C A C⁻¹ and C B_s), the bias's column C Δ B; and F's structural nonzeros: those of
        the first, of (C B_s) J from the Jacobian's pattern, the bias's column, each lag row's sees·F[:4]."""
        part, k, n, f = self.est.part, len(OUTPUTS), self.n, self.f
        coords = self.coordinates
        dt = float(self.est.dt)
        a64 = part.a.astype(np.float64)
        self.a_step = coords.similar(np.eye(k) + dt * a64 if part.delta else a64, f)
        self.b_sources = coords.outputs_of(part.b[:, 4:].astype(np.float64) * (dt if part.delta else 1.0), f)
        self.b_sources_nonzero = self.b_sources != 0
        self.jacobian_nonzero = np.zeros((4, 4), dtype=bool)
        for source, node in SOURCE_JACOBIAN_NONZERO:
            self.jacobian_nonzero[source, node] = True
        self.bj_nonzero = pattern_product(self.b_sources_nonzero, self.jacobian_nonzero)
        self.a_step = structural(self.a_step, self.a_step != 0)
        self.bias_node = coords.outputs_of(self.bias_column.astype(np.float64)[:, None], f)[:, 0]
        self.c_inv = coords.c_inv.astype(f)
        nonzero = np.zeros((n, n), dtype=bool)
        nonzero[:k, :k] = (self.a_step != 0) | self.bj_nonzero
        if self.bias_index >= 0:
            nonzero[:k, self.bias_index] = self.bias_node != 0
            nonzero[self.bias_index, self.bias_index] = True
        self.sees_nonzero = [m.sees != 0 for m in self.measurements]
        for lag, sees_nonzero in zip(self.lag_index, self.sees_nonzero, strict=True):
            if lag >= 0:
                nonzero[lag] = pattern_product(sees_nonzero[None, :], nonzero[:k])[0]
                nonzero[lag, lag] = True
                if self.bias_output >= 0 and sees_nonzero[self.bias_output]:
                    nonzero[lag, self.bias_index] = True
        self.f_nonzero = nonzero

    def transition(self) -> np.ndarray:
        """F of the step just taken in node coordinates, augmented (C: obs_predict), over its structural nonzeros
        (-0 elsewhere): the block's C (I + Δ A) C⁻¹ + (Δ C B_s) J (shift form: C A C⁻¹ + (C B_s) J), J the
        sources' Jacobian at the step's gains; the bias's column C Δ B; each lag row (1 - a)·(sees·F[:4]) and a
        on its diagonal."""
        part, f, k = self.est.part, self.f, len(OUTPUTS)
        bj, _ = masked_matmul(self.b_sources, part.source_jacobian(), self.b_sources_nonzero, self.jacobian_nonzero)
        block = self.a_step + bj                    # A's structural zeros are -0: the sum is bj there
        if self.n == k:
            return block
        full = np.full((self.n, self.n), f(NEG_ZERO), dtype=f)
        full[:k, :k] = block
        if self.bias_index >= 0:
            full[:k, self.bias_index] = structural(self.bias_node, self.bias_node != 0)
            full[self.bias_index, self.bias_index] = f(1.0)
        for m, lag, sees_nonzero in zip(self.measurements, self.lag_index, self.sees_nonzero, strict=True):
            if lag >= 0:
                row, _ = masked_matmul(m.sees[None, :], full[:k], sees_nonzero[None, :], self.f_nonzero[:k])
                full[lag] = (f(1.0) - m.lag_pole) * row[0]
                if self.bias_output >= 0 and sees_nonzero[self.bias_output]:   # it sees the output bias too
                    full[lag, self.bias_index] = (f(1.0) - m.lag_pole) * m.sees[self.bias_output]
                full[lag, lag] = m.lag_pole
        return full

    def _propagate_extra(self) -> None:
        """The bias heats its node (B's column of the node's loss); each lag state follows what its sensor sees
        (after the model step)."""
        est, k = self.est, len(OUTPUTS)
        if self.bias_index >= 0 and self.bias_output < 0:
            est.x = est.x + self.bias_column * self.extra[self.bias_index - k]
            est.y = est.part.output(est.x)
        for m, lag in zip(self.measurements, self.lag_index, strict=True):
            if lag >= 0:
                i = lag - k
                self.extra[i] = m.lag_pole * self.extra[i] + (self.f(1.0) - m.lag_pole) * self.seen(m)

    def seen(self, m) -> np.floating:
        """What measurement m sees of the estimate: sees·y, plus its weight of an output bias's node times the bias."""
        view = dot(m.sees, self.est.y)
        if self.bias_output >= 0:
            view = view + m.sees[self.bias_output] * self.extra[self.bias_index - len(OUTPUTS)]
        return view

    def reported(self) -> np.ndarray:
        """The estimate the target reports: the model's y, with an output bias added to its node."""
        y = self.est.y.copy()
        if self.bias_output >= 0:
            y[self.bias_output] = y[self.bias_output] + self.extra[self.bias_index - len(OUTPUTS)]
        return y

    def _raw(self, z) -> list[np.ndarray]:
        raw = np.atleast_1d(np.asarray(z, dtype=self.f))
        if len(raw) == 1 and sum(self.widths) > 1:
            raw = np.full(sum(self.widths), raw[0], dtype=self.f)   # a lone NaN: no measurement at all
        parts, at = [], 0
        for w in self.widths:
            parts.append(raw[at: at + w])
            at += w
        return parts

    def step(self, torque, speed, coolant, ambient, i_d=0.0, i_q=0.0, z=float("nan")) -> np.ndarray:
        est, f, k = self.est, self.f, len(OUTPUTS)
        est.step(torque, speed, coolant, ambient, i_d, i_q)
        transition = self.transition()
        self._propagate_extra()
        if isinstance(self.cov, BiermanThornton):
            self.cov.predict(transition, self.f_nonzero)
        else:
            self.cov.predict(transition)
        self.innovations = np.full(len(self.measurements), np.nan, dtype=f)
        correction = np.full(k, NEG_ZERO, dtype=f)     # the step's node corrections, summed (-0: none yet)
        corrected = False
        self.rejected[:] = False
        for index, (m, raw) in enumerate(zip(self.measurements, self._raw(z), strict=True)):
            reading = m.reading(raw, f(speed), est.y)
            if reading is None:
                continue
            value, r = reading
            lag = self.lag_index[index]
            predicted = self.extra[lag - k] if lag >= 0 else masked_dot(m.sees[self.sees_nonzero[index]],
                                                                      est.y[self.sees_nonzero[index]], f(NEG_ZERO))
            if lag < 0 and self.bias_output >= 0:
                predicted = predicted + m.sees[self.bias_output] * self.extra[self.bias_index - k]
            nu = value - predicted
            if self.gate_threshold is not None and self.gate(index, nu, self.cov.innovation_variance(
                    self.rows[index], r, index)):
                continue                          # rejected: this measurement predicts only (innovation NaN)
            self.innovations[index] = nu
            gain = self.cov.update(self.rows[index], r, index, self.holds(index))      # in node coordinates
            step = gain[:k] * nu
            est.y = est.y + step                  # the next measurement reads the corrected nodes
            correction = correction + step
            corrected = True
            if self.n > k:
                self.extra = self.extra + gain[k:] * nu
        if corrected:
            # x by C⁻¹ of the whole correction, once; y = C x again, as every step ends (a restore from x goes on
            # bit for bit)
            est.x = est.x + matvec(self.c_inv, correction)
            est.y = est.part.output(est.x)
        self.innovation = self.innovations[0]
        return self.reported()

    def covariance(self) -> np.ndarray:
        """The covariance in the state coordinates (float64: T⁻¹ P' T⁻ᵀ of the filter's node-coordinate P')."""
        return self.coordinates.state_covariance(self.cov.covariance())

    def filter_covariance(self) -> np.ndarray:
        """The filter's own covariance P' (node coordinates) in float64, as its form keeps it: its symmetry is the
        form's, not that of a transform."""
        return np.array(self.cov.covariance(), dtype=np.float64)

    def sigma(self) -> np.ndarray:
        """Each node's 1-σ (°C): sqrt of the node's diagonal element of P (node coordinates), in the filter's
        precision with a fixed order (C: fw_obs_report): c the node's unit row; the UD form takes v = Uᵀ c and
        σ² = ((d_0 v_0) v_0 + (d_1 v_1) v_1) + ... (P itself is never formed), the others σ² = c·(P c); a negative
        σ² (a covariance that lost definiteness) is 0."""
        f = self.f
        out = np.zeros(len(OUTPUTS), dtype=f)
        for i in range(len(OUTPUTS)):
            row = np.zeros(self.n, dtype=f)
            row[i] = f(1.0)
            if i == self.bias_output:      # the reported node: its output plus the bias
                row[self.bias_index] = f(1.0)
            variance = self.cov.variance(row)
            out[i] = np.sqrt(variance) if variance > 0 else f(0.0)
        return out

