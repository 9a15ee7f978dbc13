"""The observer as the target runs it: a discrete Kalman filter on the linear block, in float32.

The model step (`target_sim.model.Float32Estimator.step`) is the filter's prediction of the state; the time update
(`target_sim.observer.transition`) propagates the covariance with F of that step. A measurement z of one node (a
winding sensor: the artifact's `observer.node`, lag ignored) then corrects the state: innovation
ν = (z - offset) - y_node, x <- x + K ν, and the corrected estimate feeds the next step's losses, sigmoid and sources.
A row without a measurement (NaN) predicts only.

The pieces: the covariance in one of four forms (`OBSERVER_FORMS` of `target_sim.observer.forms`: conventional,
joseph, ud, steady); the extra states, lags and bias, and each measurement's row h (`target_sim.observer.layout`);
the states a measurement's update holds (`target_sim.observer.consider`); the innovation gate
(`target_sim.observer.gate`).

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

from target_sim.artifact import OUTPUTS, ModelArtifact, observer_gate
from target_sim.fmath import matvec
from target_sim.kinds import MODEL_KINDS
from target_sim.model import F32, Float32Estimator
from target_sim.observer.consider import ConsiderStates
from target_sim.observer.coordinates import NodeCoordinates
from target_sim.observer.forms import OBSERVER_FORMS, covariance_form
from target_sim.observer.gate import InnovationGate
from target_sim.observer.layout import AugmentedLayout
from target_sim.observer.section import ObserverError, has_observer, load_measurements
from target_sim.observer.transition import Transition
from target_sim.observer.ud import BiermanThornton
from target_sim.observer.ud_structure import NEG_ZERO, structural

Q_NODES_TOLERANCE = 1e-6            # T Q Tᵀ against diag(q_nodes), relative: float64 rounding of the lab's transform


def node_covariances(artifact: ModelArtifact, coordinates: NodeCoordinates, f) -> tuple[np.ndarray, ...]:
    """The section's q_nodes, P0, K_ss and P_ss in node coordinates, in the precision f (ObserverError when the
    section's Q is not diag(q_nodes) there)."""
    def float64(key):
        return artifact.array("observer", key, dtype=np.float64)

    q_nodes = artifact.array("observer", "q_nodes_C2", dtype=f)
    error = coordinates.process_noise_error(float64("Q"), float64("q_nodes_C2"))
    if not error <= Q_NODES_TOLERANCE:
        raise ObserverError(f"the observer's Q is not C⁻¹ diag(q_nodes_C2) C⁻ᵀ (off by {error:.3g} of the "
                            "largest q); write the section with 'bench observer'")
    n = len(q_nodes)
    p0 = coordinates.covariance(float64("P0"), f)
    gain_steady = coordinates.vectors(float64("K_ss").reshape(-1, n), f)
    p_steady = coordinates.covariance(float64("P_ss"), f)
    return q_nodes, p0, gain_steady, p_steady


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
        steady = self.form == "steady"
        f = self.f = est.f
        self.measurements = load_measurements(section, f)
        self.n = n = artifact.array("observer", "Q").shape[0]
        self.coordinates = NodeCoordinates(est.part.c, n)
        self.q_nodes, self.p0, gain_steady, self.p_steady = node_covariances(artifact, self.coordinates, f)
        self.q = np.diag(self.q_nodes).astype(f)        # Q in node coordinates
        self.consider = ConsiderStates(section, self.measurements, n, steady, f)
        self.gain_steady = self.consider.steady_gain(gain_steady)
        self.layout = AugmentedLayout(self.measurements, section, est, n)
        self.transition = Transition(est, self.coordinates, self.layout)
        self.c_inv = self.coordinates.c_inv.astype(f)
        self.gate = InnovationGate(observer_gate(section), len(self.measurements), steady, f)
        self.extra = np.zeros(n - len(OUTPUTS), dtype=f)
        self.innovations = np.full(len(self.measurements), np.nan, dtype=f)
        self.cov = self._covariance()

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

    def _covariance(self):
        return covariance_form(self.form, self.p0, self.q, self.q_nodes, self.gain_steady, self.p_steady,
                               self.layout.rows, self.f)

    def reset(self, temperatures: Sequence[float]) -> None:
        """The model at `temperatures`; each lag state at the temperature its sensor sees, the bias 0."""
        self.est.reset(temperatures)
        self.reset_lags()
        self.cov = self._covariance()
        self.innovations = np.full(len(self.measurements), np.nan, dtype=self.f)
        self.gate.clear()

    def reset_lags(self) -> None:
        """Each lag state at the temperature its sensor sees of the current estimate, the bias 0 (a restore
        without the filter's checkpoint)."""
        self.extra = self.layout.initial_extra(self.est.y)

    def checkpoint(self) -> np.ndarray:
        """The filter's state beyond the model's x, float32 bit for bit, in the order of the ObserverCheckpoint
        frames (DBC 1.7.0): the extra states (lags in measurement order, then the bias), then the covariance in the
        deployed form, in the filter's node coordinates: UD d_0..d_{n-1} then U above the diagonal row by row;
        conventional and Joseph P row by row; the steady-state gain nothing; then, for the steady form with a gate,
        each measurement's rejections in a row (its re-admission depends on them: `InnovationGate.rejects`)."""
        return np.concatenate([self.extra, self.cov.checkpoint(), self.gate.checkpoint()]).astype(self.f)

    def checkpoint_size(self) -> int:
        return len(self.checkpoint())

    def restore_checkpoint(self, values: Sequence[float]) -> None:
        """The extra states and covariance from `checkpoint()`'s values (ValueError when the count differs)."""
        values = np.asarray(values, dtype=self.f)
        if len(values) != self.checkpoint_size():
            raise ValueError(f"an observer checkpoint of this filter has {self.checkpoint_size()} elements, "
                             f"not {len(values)}")
        extra_end = self.n - len(OUTPUTS)
        cov_end = extra_end + len(self.cov.checkpoint())
        self.extra = values[:extra_end].copy()
        self.cov.restore(values[extra_end:cov_end])
        self.gate.restore(values[cov_end:])

    def step(self, torque, speed, coolant, ambient, i_d=0.0, i_q=0.0, z=float("nan")) -> np.ndarray:
        """One model step, its time update and each valid reading's update; the corrected node temperatures."""
        self.est.step(torque, speed, coolant, ambient, i_d, i_q)
        self._time_update()
        return self._measurement_update(self.f(speed), z)

    def _time_update(self) -> None:
        """F of the model step just taken, the extra states after it, the covariance's prediction."""
        transition = self.transition.matrix()
        self.layout.propagate(self.extra, self.est)
        self.cov.predict(transition, self.transition.nonzero)

    def _measurement_update(self, speed, z) -> np.ndarray:
        """Each measurement with a valid reading in `z` corrects the nodes in turn; then x moves by C⁻¹ of the
        step's summed correction, once, and y = C x again, as every step ends (a restore from x goes on bit for
        bit). Returns the corrected node temperatures."""
        est, f, k = self.est, self.f, len(OUTPUTS)
        self.innovations = np.full(len(self.measurements), np.nan, dtype=f)
        self.gate.new_step()
        correction = np.full(k, NEG_ZERO, dtype=f)     # the step's node corrections, summed (-0: none yet)
        corrected = False
        for index, (m, raw) in enumerate(zip(self.measurements, self.layout.split(z), strict=True)):
            reading = m.reading(raw, speed, est.y)
            if reading is None:
                continue
            step = self._update(index, *reading)
            if step is not None:
                correction = correction + step
                corrected = True
        if corrected:
            est.x = est.x + matvec(self.c_inv, correction)
            est.y = est.part.output(est.x)
        return self.layout.reported(self.extra, est.y)

    def _update(self, index: int, value, r) -> np.ndarray | None:
        """The index-th measurement's correction with its reading `value` of variance `r`: the gain (node
        coordinates) moves the nodes (the next measurement reads them) and the extra states, each state the update
        holds (consider states) not at all. Returns the nodes' correction; None when the gate rejects the reading
        (this measurement predicts only, its innovation NaN) or the update holds every node."""
        est, k, h = self.est, len(OUTPUTS), self.layout.rows[index]
        nu = value - self.layout.predicted(index, self.extra, est.y)
        if self.gate.threshold is not None and self.gate.rejects(index, nu,
                                                                 self.cov.innovation_variance(h, r, index)):
            return None
        self.innovations[index] = nu
        held = self.consider.holds(index, self.cov)
        gain = self.cov.update(h, r, index, held)
        moves = gain * nu
        if held is not None:        # a held row's step is a structural zero (-0: y + -0 is y; the C skips it)
            moves = structural(moves, ~held)
        if self.n > k:
            self.extra = self.extra + moves[k:]
        if held is not None and held[:k].all():
            return None             # no node moves: x and y stay as they are (the C moves nothing)
        step = moves[:k]
        est.y = est.y + step
        return step

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
            if i == self.layout.bias_output:      # the reported node: its output plus the bias
                row[self.layout.bias_index] = f(1.0)
            variance = self.cov.variance(row)
            out[i] = np.sqrt(variance) if variance > 0 else f(0.0)
        return out
