"""The observer as the target runs it: a discrete Kalman filter on the linear block, in float32.

The model step (`target_sim.model.Float32Estimator.step`) is the filter's prediction of the state. The filter adds
the covariance: the block's one-step map is x <- F x + (inputs), with F = A + B_s G C in shift form and
F = I + Δ·(A + B_s G C) in delta form, where G = d(sources)/d(estimate) at the step's speed and coolant (the
temperature sources of eqs. 9-18 are linear in the previous estimate; `LinearBlockPart.source_jacobian`). The
losses' dependence on the winding estimate (eqs. 3-5) is left out of F. A measurement z of one node (a winding
sensor: the artifact's `observer.node`, lag ignored) then corrects the state: innovation ν = (z - offset) - y_node,
x <- x + K ν, and the corrected estimate feeds the next step's losses, sigmoid and sources. A row without a
measurement (NaN) predicts only.

The covariance is kept in one of four forms (`OBSERVER_FORMS`), equal in exact arithmetic, not in float32:
- `conventional`: P⁻ = F P Fᵀ + Q, K = P⁻hᵀ/(h P⁻ hᵀ + R), P = P⁻ - K (h P⁻), no symmetrization;
- `joseph`: the same prediction, P = (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ;
- `ud`: P = U D Uᵀ (U unit upper triangular), Thornton's modified weighted Gram-Schmidt prediction over
  [F U, C⁻¹] with diag(D, q) (Q = C⁻¹ diag(q) C⁻ᵀ, q the process noise per node), Bierman's scalar measurement
  update; P0 factored once at start;
- `steady`: the steady-state gain K_ss of the artifact (the lab solves the Riccati equation at a nominal operating
  point), no covariance at all: x <- x + K_ss ν, a few multiply-adds.

Every operation has a fixed order and a float32 rounding (`fmath.matmul`, `fmath.dot`, elementwise ufuncs), so a C
version can repeat it bit for bit. Coordinates are the realization's: Q, P0 and P_ss are stored in them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from target_sim.artifact import OUTPUTS, ModelArtifact
from target_sim.errors import TargetError
from target_sim.fmath import dot, matmul, matvec
from target_sim.kinds import MODEL_KINDS
from target_sim.model import F32, Float32Estimator, InputAccumulator
from target_sim.registry import Registry


class ObserverError(TargetError):
    """An observer that cannot run on this artifact; the message says why."""


class Conventional:
    """P⁻ = F P Fᵀ + Q; P = P⁻ - K (h P⁻)."""

    def __init__(self, p0: np.ndarray, q: np.ndarray, f):
        self.f, self.q = f, q
        self.p = p0.copy()

    def predict(self, transition: np.ndarray) -> None:
        self.p = matmul(matmul(transition, self.p), transition.T) + self.q

    def _gain(self, h: np.ndarray, r) -> tuple[np.ndarray, np.ndarray]:
        ph = matvec(self.p, h)                 # P⁻ hᵀ
        s = dot(h, ph) + r
        return ph / s, ph

    def update(self, h: np.ndarray, r) -> np.ndarray:
        k, _ = self._gain(h, r)
        hp = matvec(self.p.T, h)               # h P⁻ (a row; equal to (P⁻hᵀ)ᵀ only while P⁻ is symmetric)
        self.p = self.p - k[:, None] * hp[None, :]
        return k

    def covariance(self) -> np.ndarray:
        return self.p


class Joseph(Conventional):
    """P = (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ."""

    def update(self, h: np.ndarray, r) -> np.ndarray:
        k, _ = self._gain(h, r)
        f = self.f
        i_kh = np.eye(len(k), dtype=f) - k[:, None] * h[None, :]
        self.p = matmul(matmul(i_kh, self.p), i_kh.T) + (r * k)[:, None] * k[None, :]
        return k


def ud_factor(m: np.ndarray, f) -> tuple[np.ndarray, np.ndarray]:
    """(U, d) with M = U diag(d) Uᵀ, U unit upper triangular, for a symmetric positive definite M, column by column
    from the last (C: fw_ud_factor)."""
    n = m.shape[0]
    u = np.eye(n, dtype=f)
    d = np.zeros(n, dtype=f)
    for j in range(n - 1, -1, -1):
        s = m[j, j]
        for k in range(j + 1, n):
            s = s - (d[k] * u[j, k]) * u[j, k]
        d[j] = s
        if not s > 0:           # not positive definite in this precision: the column carries nothing
            d[j] = f(0.0)
            continue
        for i in range(j - 1, -1, -1):
            s = m[i, j]
            for k in range(j + 1, n):
                s = s - (d[k] * u[i, k]) * u[j, k]
            u[i, j] = s / d[j]
    return u, d


class BiermanThornton:
    """P = U diag(d) Uᵀ: Thornton's prediction, Bierman's update. Q enters as G diag(q) Gᵀ with G = C⁻¹ and q the
    process noise per node (Thornton's method takes any G), so Q itself is never factored."""

    def __init__(self, p0: np.ndarray, g: np.ndarray, q_nodes: np.ndarray, f):
        self.f = f
        self.u, self.d = ud_factor(p0, f)
        self.g, self.q_nodes = g, q_nodes

    def predict(self, transition: np.ndarray) -> None:
        """Modified weighted Gram-Schmidt of the rows of W = [F U, G] with weights diag(d, q), last row first."""
        f, n = self.f, len(self.d)
        w = np.concatenate([matmul(transition, self.u), self.g], axis=1)
        weights = np.concatenate([self.d, self.q_nodes])
        u = np.eye(n, dtype=f)
        d = np.zeros(n, dtype=f)
        for j in range(n - 1, -1, -1):
            c = w[j] * weights
            d[j] = dot(w[j], c)
            for i in range(j):
                u[i, j] = dot(w[i], c) / d[j]
                w[i] = w[i] - u[i, j] * w[j]
        self.u, self.d = u, d

    def update(self, h: np.ndarray, r) -> np.ndarray:
        """Bierman's scalar update (Grewal and Andrews' arrangement); returns the gain."""
        f, n = self.f, len(self.d)
        one = f(1.0)
        u, d = self.u.copy(), self.d.copy()
        a = matvec(u.T, h)                     # Uᵀ hᵀ
        b = d * a
        alpha = f(r)
        gamma = one / alpha
        for j in range(n):
            beta = alpha
            alpha = alpha + a[j] * b[j]
            lam = -a[j] * gamma
            gamma = one / alpha
            d[j] = (beta * gamma) * d[j]
            for i in range(j):
                held = u[i, j]
                u[i, j] = held + b[i] * lam
                b[i] = b[i] + b[j] * held
        self.u, self.d = u, d
        return b * gamma

    def covariance(self) -> np.ndarray:
        """U diag(d) Uᵀ in float64 (for reports; the filter itself never forms it)."""
        u = self.u.astype(np.float64)
        return (u * self.d.astype(np.float64)) @ u.T


class SteadyState:
    """The constant gain K_ss; the covariance is the artifact's steady-state P (posterior)."""

    def __init__(self, gain: np.ndarray, p_steady: np.ndarray):
        self.gain, self.p = gain, p_steady

    def predict(self, transition: np.ndarray) -> None:
        pass

    def update(self, h: np.ndarray, r) -> np.ndarray:
        return self.gain

    def covariance(self) -> np.ndarray:
        return self.p


@dataclass(frozen=True)
class ObserverForm:
    """One way to keep the filter's covariance."""

    name: str
    summary: str
    propagates: bool          # a covariance is propagated every step (else the steady-state gain)


OBSERVER_FORMS: Registry[ObserverForm] = Registry("observer form")
for _form in (
    ObserverForm("conventional", "P = P⁻ - K h P⁻ (no symmetrization)", True),
    ObserverForm("joseph", "P = (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ", True),
    ObserverForm("ud", "P = U D Uᵀ: Thornton's prediction, Bierman's update", True),
    ObserverForm("steady", "constant steady-state gain, no covariance", False),
):
    OBSERVER_FORMS.register(_form.name, _form)

_COVARIANCES = {"conventional": Conventional, "joseph": Joseph}


def has_observer(artifact: ModelArtifact) -> bool:
    return isinstance(artifact.content.get("observer"), dict)


class Float32Observer:
    """The estimator of `artifact` with its observer (`form`: the artifact's deployed one unless given).

    `step(..., z)` runs the model step, propagates the covariance and, when z is a number, corrects with it;
    returns [yoke, winding, tooth, magnet]. `sigma()` is each node's 1-σ (from C P Cᵀ)."""

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

        self.node = OUTPUTS.index(section["node"])
        self.h = est.part.c[self.node].copy()
        self.q, self.r, self.p0 = arr("Q"), arr("R")[()], arr("P0")
        self.q_nodes = arr("q_nodes_C2")
        self.offset = arr("offset_C")[()]
        self.gain_steady, self.p_steady = arr("K_ss"), arr("P_ss")
        self.identity = np.eye(4, dtype=f)
        self.innovation = f(np.nan)
        self.cov = self._covariance()

    def _covariance(self):
        if self.form == "steady":
            return SteadyState(self.gain_steady, self.p_steady)
        if self.form == "ud":
            return BiermanThornton(self.p0, self.est.part.c_inv, self.q_nodes, self.f)
        return _COVARIANCES[self.form](self.p0, self.q, self.f)

    def reset(self, temperatures: Sequence[float]) -> None:
        self.est.reset(temperatures)
        self.cov = self._covariance()
        self.innovation = self.f(np.nan)

    def transition(self) -> np.ndarray:
        """F of the step just taken: A + (B_s G) C, delta: I + Δ·(A + (B_s G) C) (C: fw_transition)."""
        part = self.est.part
        a_eff = part.a + matmul(matmul(part.b[:, 4:], part.source_jacobian()), part.c)
        return self.identity + self.est.dt * a_eff if part.delta else a_eff

    def step(self, torque, speed, coolant, ambient, i_d=0.0, i_q=0.0, z=float("nan")) -> np.ndarray:
        est = self.est
        est.step(torque, speed, coolant, ambient, i_d, i_q)
        self.cov.predict(self.transition())
        z = self.f(z)
        self.innovation = self.f(np.nan)
        if np.isfinite(z):
            self.innovation = nu = (z - self.offset) - est.y[self.node]
            gain = self.cov.update(self.h, self.r)
            est.x = est.x + gain * nu
            est.y = est.part.output(est.x)
        return est.y.copy()

    def covariance(self) -> np.ndarray:
        return self.cov.covariance()

    def sigma(self) -> np.ndarray:
        """Each node's 1-σ (°C), from C P Cᵀ in float64."""
        c = self.est.part.c.astype(np.float64)
        p = np.asarray(self.covariance(), dtype=np.float64)
        return np.sqrt(np.maximum(np.diag(c @ p @ c.T), 0.0))


@dataclass(frozen=True)
class ObserverRun:
    """A whole run of the float32 observer: per model step the estimate, the innovation (NaN without a
    measurement) and, on request, the covariance in the state coordinates."""

    rows: np.ndarray
    outputs: np.ndarray
    innovations: np.ndarray
    covariances: np.ndarray | None


def run_observer_offline(artifact: ModelArtifact, drive: np.ndarray, measurement: np.ndarray,
                         initial: Sequence[float], form: str | None = None, keep_covariance: bool = False,
                         dtype=F32) -> ObserverRun:
    """The float32 observer over a whole dataset: `drive` as `target_sim.model.run_offline` takes it, `measurement`
    one value per row (NaN: none), accumulated with the drive into the step's float32 interval mean."""
    obs = Float32Observer(artifact, form, dtype)
    obs.reset(initial)
    drive = np.asarray(drive, dtype=np.float64)
    width = len(artifact.drive_signals)
    if drive.ndim != 2 or drive.shape[1] != width or len(measurement) != len(drive):
        raise ValueError(f"the observer needs {width} drive columns and one measurement per row, not "
                         f"{drive.shape} and {len(measurement)}")
    rows = np.column_stack([drive, np.asarray(measurement, dtype=np.float64)])
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt, width + 1)
    steps, outputs, innovations, covariances = [], [], [], []
    for row, sample in enumerate(rows):
        means = acc.add(row, sample)
        if means is None:
            continue
        inputs, z = means[:width], means[width]
        outputs.append(obs.step(*inputs, z=z))
        innovations.append(obs.innovation)
        if keep_covariance:
            covariances.append(np.array(obs.covariance(), dtype=np.float64))
        steps.append(row)
    return ObserverRun(np.array(steps, dtype=np.int64), np.array(outputs, dtype=dtype).reshape(-1, 4),
                       np.array(innovations, dtype=np.float64),
                       np.array(covariances) if keep_covariance else None)
