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
  [F U, G] with diag(D, q_G) (Q = G diag(q_G) Gᵀ: Q's own UD factors), Bierman's scalar measurement update; P0
  and Q factored once at start; every operation over the structure known when the filter is built
  (`target_sim.ud_structure`: structural zeros skipped, U's ones not multiplied);
- `steady`: the steady-state gain K_ss of the artifact (the lab solves the Riccati equation at a nominal operating
  point), no covariance at all: x <- x + K_ss ν, a few multiply-adds.

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
filter runs in node coordinates (`target_sim.observer_coordinates`: the node temperatures y = C x and the extra
states), where Q is diag(q_nodes), a measurement's row h is what its sensor sees and F needs no product by C. Its
gain corrects the node temperatures (the next measurement of the step reads them), and after the step's last update
x moves by C⁻¹ of the summed correction and y = C x again. `covariance()` is back in the state coordinates.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from target_sim.artifact import (
    BIAS_KINDS,
    OUTPUTS,
    ModelArtifact,
    consider_held,
    consider_release,
    consider_released,
    encode_array,
    observer_gate,
    observer_state_count,
    section_version,
)
from target_sim.errors import TargetError
from target_sim.fmath import dot, matmul, matvec
from target_sim.kinds import MODEL_KINDS
from target_sim.measurements import MEASUREMENT_KINDS
from target_sim.model import F32, Float32Estimator, InputAccumulator
from target_sim.modelkinds.lti_lptn import SOURCE_JACOBIAN_NONZERO
from target_sim.observer_coordinates import NodeCoordinates
from target_sim.registry import Registry
from target_sim.ud_structure import (
    NEG_ZERO,
    BiermanSchedule,
    Pivot,
    RankOneStep,
    bierman_schedule,
    gram_schmidt_schedule,
    masked_dot,
    masked_matmul,
    pattern_product,
    rank_one_schedule,
    structural,
    upper_unit,
)


class ObserverError(TargetError):
    """An observer that cannot run on this artifact; the message says why."""


class Conventional:
    """P⁻ = F P Fᵀ + Q; P = P⁻ - K (h P⁻)."""

    def __init__(self, p0: np.ndarray, q: np.ndarray, f):
        self.f, self.q = f, q
        self.p = p0.copy()

    def predict(self, transition: np.ndarray) -> None:
        self.p = matmul(matmul(transition, self.p), transition.T) + self.q

    def _gain(self, h: np.ndarray, r) -> tuple[np.ndarray, np.ndarray, np.floating]:
        ph = matvec(self.p, h)                 # P⁻ hᵀ
        s = dot(h, ph) + r
        return ph / s, ph, s

    def innovation_variance(self, h: np.ndarray, r, index: int = 0):
        """S = h P⁻ hᵀ + R, as the update computes it (the gate's denominator, the same bits)."""
        return self._gain(h, r)[2]

    def update(self, h: np.ndarray, r, index: int = 0, held: np.ndarray | None = None) -> np.ndarray:
        """The optimal update; with `held` (consider states) P += s δ δᵀ after it, δ the optimal gain's held rows
        (the covariance of the gain with those rows zero), and that gain is returned."""
        k, _, s = self._gain(h, r)
        hp = matvec(self.p.T, h)               # h P⁻ (a row; equal to (P⁻hᵀ)ᵀ only while P⁻ is symmetric)
        self.p = self.p - k[:, None] * hp[None, :]
        if held is not None:
            rows = np.flatnonzero(held)
            delta = k[rows]
            self.p[np.ix_(rows, rows)] = self.p[np.ix_(rows, rows)] + (s * delta)[:, None] * delta[None, :]
            k = held_gain(k, held)
        return k

    def covariance(self) -> np.ndarray:
        return self.p

    def variance(self, row: np.ndarray):
        """row·(P row) in a fixed order: the variance of a linear combination of the states."""
        return dot(row, matvec(self.p, row))


class Joseph(Conventional):
    """P = (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ."""

    def update(self, h: np.ndarray, r, index: int = 0, held: np.ndarray | None = None) -> np.ndarray:
        """Joseph's form holds for any gain: with `held` (consider states) the optimal gain's held rows zero."""
        k, _, _ = self._gain(h, r)
        if held is not None:
            k = held_gain(k, held)
        f = self.f
        i_kh = np.eye(len(k), dtype=f) - k[:, None] * h[None, :]
        self.p = matmul(matmul(i_kh, self.p), i_kh.T) + (r * k)[:, None] * k[None, :]
        return k


def held_gain(gain: np.ndarray, held: np.ndarray) -> np.ndarray:
    """The gain with the rows of the held (consider) states a structural zero (-0: x + (-0)·ν is x)."""
    return structural(gain, ~held)


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
    """P = U diag(d) Uᵀ: Thornton's prediction, Bierman's update. Q enters as G diag(q) Gᵀ (Thornton's method
    takes any G; `Float32Observer` gives Q's own UD factors, unit upper triangular).

    Both run over the structure known when the filter is built (`target_sim.ud_structure`): F's structural
    nonzeros (given with F), U's unit upper triangle, G's zeros, the columns of G whose q is 0 (dropped), h's
    zeros; each schedule is computed once per pattern. Skipped products are left out of their sums; the order of
    the rest is fixed, so the C repeats it bit for bit."""

    def __init__(self, p0: np.ndarray, g: np.ndarray, q_nodes: np.ndarray, f):
        self.f = f
        self.u, self.d = ud_factor(p0, f)
        n = len(self.d)
        self.upper = upper_unit(n)
        kept = np.flatnonzero(np.asarray(q_nodes) != 0)      # a column of weight 0 adds nothing to any product
        g = np.asarray(g, dtype=f)[:, kept]
        self.g_nonzero = g != 0
        self.g = structural(g, self.g_nonzero)
        self.q_kept = np.asarray(q_nodes, dtype=f)[kept]
        self.g_columns = kept
        self._pivots: dict[bytes, list] = {}
        self._updates: dict[bytes, tuple[np.ndarray, BiermanSchedule]] = {}

    def schedule(self, f_nonzero: np.ndarray) -> tuple[Pivot, ...]:
        """The MWGS schedule of W = [F U, G] for F's structural nonzeros."""
        w_nonzero = np.concatenate([pattern_product(f_nonzero, self.upper), self.g_nonzero], axis=1)
        return gram_schmidt_schedule(w_nonzero)

    def _pivot_indices(self, f_nonzero: np.ndarray) -> list:
        key = f_nonzero.tobytes()
        if key not in self._pivots:
            self._pivots[key] = [(p.row, np.array(p.columns, dtype=np.intp),
                                  [(r.row, np.array(r.shared, dtype=np.intp)) for r in p.rows])
                                 for p in self.schedule(f_nonzero)]
        return self._pivots[key]

    def predict(self, transition: np.ndarray, f_nonzero: np.ndarray | None = None) -> None:
        """Modified weighted Gram-Schmidt of the rows of W = [F U, G] with weights diag(d, q), last row first:
        d_j = w_j·(w_j ∘ weights), u_ij = (w_i·(w_j ∘ weights))·(1/d_j) (one division per pivot),
        w_i <- w_i - u_ij w_j. `f_nonzero`: F's structural nonzeros (None: all)."""
        f, n = self.f, len(self.d)
        zero, one = f(NEG_ZERO), f(1.0)
        if f_nonzero is None:
            f_nonzero = np.ones((n, n), dtype=bool)
        fu, _ = masked_matmul(transition, self.u, f_nonzero, self.upper)
        w = np.concatenate([fu, self.g], axis=1)
        weights = np.concatenate([self.d, self.q_kept])
        u = np.eye(n, dtype=f)
        d = np.zeros(n, dtype=f)
        for j, columns, rows in self._pivot_indices(f_nonzero):
            w_j = w[j, columns]
            c = w_j * weights[columns]
            d[j] = masked_dot(w_j, c, zero)
            if not rows:
                continue
            inverse = one / d[j]
            for i, shared in rows:
                u[i, j] = masked_dot(w[i, columns[shared]], c[shared], zero) * inverse
                w[i, columns] = w[i, columns] - u[i, j] * w_j
        self.u, self.d = u, d

    def bierman(self, h: np.ndarray) -> BiermanSchedule:
        """The update's schedule for the row h (its zeros are structural)."""
        return self._bierman_entry(h)[1]

    def _bierman_entry(self, h: np.ndarray) -> tuple[np.ndarray, BiermanSchedule]:
        nonzero = np.asarray(h) != 0
        key = nonzero.tobytes()
        if key not in self._updates:
            self._updates[key] = (nonzero, bierman_schedule(nonzero))
        return self._updates[key]

    def innovation_variance(self, h: np.ndarray, r, index: int = 0):
        """S = h P⁻ hᵀ + R as Bierman's update reaches it, its final α: R + a_j b_j over the schedule's columns in
        order (b_j = d_j a_j: a column's b is changed only after its own step), the same bits."""
        nonzero, schedule = self._bierman_entry(h)
        a, a_nonzero = masked_matmul(np.asarray(h, dtype=self.f)[None, :], self.u, nonzero[None, :], self.upper)
        a = a[0]
        b = structural(self.d * a, a_nonzero[0])
        alpha = self.f(r)
        for step in schedule.steps:
            alpha = alpha + a[step.column] * b[step.column]
        return alpha

    def update(self, h: np.ndarray, r, index: int = 0, held: np.ndarray | None = None) -> np.ndarray:
        """Bierman's scalar update (Grewal and Andrews' arrangement) over h's structure: a = Uᵀhᵀ, b = d ∘ a, then
        each column j with a_j != 0 (a column with a_j = 0 changes nothing); returns the gain b·γ.

        With `held` (consider states): Bierman's update is the optimal gain's; the gain with the held rows zero,
        K = K_opt - δ, has the covariance P_opt + s δ δᵀ (s = h P⁻ hᵀ + R, the final α; δ = b_held/s), i.e.
        P_opt + γ v vᵀ with v = b on the held rows: Agee and Turner's rank-one update of U and d, which keeps d
        positive for a positive weight (`rank_one`)."""
        f = self.f
        one = f(1.0)
        nonzero, schedule = self._bierman_entry(h)
        u, d = self.u.copy(), self.d.copy()
        a, a_nonzero = masked_matmul(np.asarray(h, dtype=f)[None, :], u, nonzero[None, :], self.upper)
        a, a_nonzero = a[0], a_nonzero[0]
        b = structural(d * a, a_nonzero)
        alpha = f(r)
        gamma = one / alpha
        for step in schedule.steps:
            j = step.column
            beta = alpha
            alpha = alpha + a[j] * b[j]
            lam = -a[j] * gamma
            gamma = one / alpha
            d[j] = (beta * gamma) * d[j]
            for i in step.updated:
                before = u[i, j]
                u[i, j] = before + b[i] * lam
                b[i] = b[i] + b[j] * before
            for i in step.filled:
                b[i] = b[j] * u[i, j]          # b_i was a structural zero: -0 + b_j u_ij
        gain = b * gamma
        self.alpha = alpha            # S = h P⁻ hᵀ + R (a test checks innovation_variance against it)
        if held is not None:
            v_nonzero = held & np.asarray(schedule.gain_nonzero)
            self.rank_one(u, d, gamma, structural(b, v_nonzero), self._rank_one(v_nonzero))
            gain = held_gain(gain, held)
        self.u, self.d = u, d
        return gain

    def _rank_one(self, v_nonzero: np.ndarray) -> tuple[RankOneStep, ...]:
        key = b"r" + v_nonzero.tobytes()
        if key not in self._pivots:
            self._pivots[key] = rank_one_schedule(v_nonzero)
        return self._pivots[key]

    def rank_one_steps(self, v_nonzero: np.ndarray) -> tuple[RankOneStep, ...]:
        """The Agee-Turner schedule for v's structural nonzeros (the C generator's)."""
        return self._rank_one(np.asarray(v_nonzero, dtype=bool))

    def rank_one(self, u: np.ndarray, d: np.ndarray, c, v: np.ndarray, steps: tuple[RankOneStep, ...]) -> None:
        """U diag(d) Uᵀ + c v vᵀ into u and d in place (c > 0; Agee and Turner, Bierman 1977 ch. V), over the
        schedule, last column first: d̃_j = d_j + (c v_j) v_j, β = (c v_j)/d̃_j, c = (c d_j)/d̃_j, then for each
        row i < j: v_i -= v_j u_ij, u_ij += β v_i (a d̃_j that is not positive: β = 0 and c as it was)."""
        f = self.f
        v = v.copy()
        for step in steps:
            j = step.column
            cv = c * v[j]
            dn = d[j] + cv * v[j]
            positive = dn > f(0.0)
            beta = cv / dn if positive else f(0.0)
            c = (c * d[j]) / dn if positive else c
            d[j] = dn
            for i in step.updated:
                v[i] = v[i] - v[j] * u[i, j]
                u[i, j] = u[i, j] + beta * v[i]
            for i in step.filled:
                v[i] = -(v[j] * u[i, j])
                u[i, j] = u[i, j] + beta * v[i]

    def variance(self, row: np.ndarray):
        """row·(U D Uᵀ row) without forming P: v = Uᵀ row, then ((d_0 v_0) v_0 + (d_1 v_1) v_1) + ... (C:
        fw_obs_sigma)."""
        v = matvec(self.u.T, row)
        return dot(self.d * v, v)

    def covariance(self) -> np.ndarray:
        """U diag(d) Uᵀ in float64 (for reports; the filter itself never forms it)."""
        u = self.u.astype(np.float64)
        return (u * self.d.astype(np.float64)) @ u.T


class SteadyState:
    """The constant gain K_ss; the covariance is the artifact's steady-state P (posterior)."""

    def __init__(self, gain: np.ndarray, p_steady: np.ndarray, rows: Sequence[np.ndarray] = ()):
        self.gain, self.p = gain, p_steady
        # per measurement h P⁻ hᵀ of the steady prior, from the posterior and the gain (float64, once):
        # h P hᵀ = h P⁻ hᵀ (1 - h K), since K = P⁻hᵀ/S
        p64 = np.asarray(p_steady, dtype=np.float64)
        self.prior = [p_steady.dtype.type(float(h @ p64 @ h) / (1.0 - float(h @ np.asarray(k, dtype=np.float64))))
                      for h, k in zip((np.asarray(h, dtype=np.float64) for h in rows), gain, strict=False)]

    def predict(self, transition: np.ndarray) -> None:
        pass

    def innovation_variance(self, h: np.ndarray, r, index: int = 0):
        """S = h P⁻ hᵀ + R with the steady prior's h P⁻ hᵀ (constant: the gate of a steady filter never widens)."""
        return self.prior[index] + r

    def update(self, h: np.ndarray, r, index: int = 0, held: np.ndarray | None = None) -> np.ndarray:
        return self.gain[index]           # the held rows are already zero (Float32Observer)

    def covariance(self) -> np.ndarray:
        return self.p

    def variance(self, row: np.ndarray):
        return dot(row, matvec(self.p, row))


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
    ObserverForm("ud", "P = U D Uᵀ: Thornton's prediction, Bierman's update (Agee-Turner's for consider states)",
                 True),
    ObserverForm("steady", "constant steady-state gain, no covariance", False),
):
    OBSERVER_FORMS.register(_form.name, _form)

_COVARIANCES = {"conventional": Conventional, "joseph": Joseph}


def has_observer(artifact: ModelArtifact) -> bool:
    return isinstance(artifact.content.get("observer"), dict)


Q_NODES_TOLERANCE = 1e-6            # T Q Tᵀ against diag(q_nodes), relative: float64 rounding of the lab's transform


def measurement_entries(section: dict) -> list[dict]:
    """The section's measurements as version 2 entries (a version 1 section: its one sensor, without lag)."""
    if section_version(section) >= 2:
        return list(section["measurements"])
    sees = np.zeros(len(OUTPUTS))
    sees[OUTPUTS.index(section["node"])] = 1.0
    return [{"kind": "lagged-sensor", "name": section["column"], "columns": [section["column"]],
             "node": section["node"],
             "arrays": {"sees": encode_array(sees), "lag_pole": encode_array(0.0), "offset_C": section["offset_C"],
                        "R": section["R"]}}]


def load_measurements(section: dict, f=F32) -> list:
    """The target measurements of the section, in order (`target_sim.measurements`)."""
    out = []
    for i, entry in enumerate(measurement_entries(section)):
        kind = MEASUREMENT_KINDS[entry["kind"]]
        out.append(kind.load(entry, f"observer.measurements[{i}]", f))
    return out


def bias_input(section: dict) -> int:
    """The loss input whose column of B the section's bias heats (`BIAS_KINDS`; without a bias: the winding's, as
    the filter has always computed it and never applies)."""
    return BIAS_KINDS[section.get("bias") or "winding-heat"]


def state_count(section: dict) -> int:
    """4 model states, one lag state per lagged measurement, one bias state if the section has one."""
    return observer_state_count(section)


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
        self.bias_input = bias_input(section)
        self.bias_column = part.b[:, self.bias_input] * (est.dt if part.delta else f(1.0))
        # the filter's rows h in node coordinates: a lag state, or what the sensor sees of the nodes
        self.rows = []
        for lag, m in zip(self.lag_index, self.measurements, strict=True):
            h = np.zeros(n, dtype=f)
            if lag >= 0:
                h[lag] = f(1.0)
            else:
                h[: len(OUTPUTS)] = m.sees
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
        if self.form == "steady":
            return SteadyState(self.gain_steady, self.p_steady, self.rows)
        if self.form == "ud":
            # Q = G diag(q) Gᵀ: in node coordinates Q is diagonal, so G = I (its structural zeros skipped)
            return BiermanThornton(self.p0, np.eye(self.n, dtype=self.f), self.q_nodes, self.f)
        return _COVARIANCES[self.form](self.p0, self.q, self.f)

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
        """The constants of F in node coordinates (`target_sim.observer_coordinates`), hoisted: C (I + Δ A) C⁻¹ and
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
                full[lag, lag] = m.lag_pole
        return full

    def _propagate_extra(self) -> None:
        """The bias heats its node (B's column of the node's loss); each lag state follows what its sensor sees
        (after the model step)."""
        est, k = self.est, len(OUTPUTS)
        if self.bias_index >= 0:
            est.x = est.x + self.bias_column * self.extra[self.bias_index - k]
            est.y = est.part.output(est.x)
        for m, lag in zip(self.measurements, self.lag_index, strict=True):
            if lag >= 0:
                i = lag - k
                self.extra[i] = m.lag_pole * self.extra[i] + (self.f(1.0) - m.lag_pole) * dot(m.sees, est.y)

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
        return est.y.copy()

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
            variance = self.cov.variance(row)
            out[i] = np.sqrt(variance) if variance > 0 else f(0.0)
        return out


@dataclass(frozen=True)
class ObserverRun:
    """A whole run of the float32 observer: per model step the estimate, each node's 1-σ, the first
    measurement's innovation (NaN without a reading), every measurement's and, on request, the covariance in the
    state coordinates and the filter's own (node coordinates)."""

    rows: np.ndarray
    outputs: np.ndarray
    innovations: np.ndarray
    covariances: np.ndarray | None
    sigmas: np.ndarray | None = None
    all_innovations: np.ndarray | None = None
    filter_covariances: np.ndarray | None = None      # on request: the filter's own P' (node coordinates)
    rejected: np.ndarray | None = None                # per step and measurement: the gate rejected its reading
    flagged: np.ndarray | None = None                 # per measurement: its sensor was flagged (latched)
    flagged_steps: np.ndarray | None = None           # per step and measurement: its sensor flagged after the step


def run_observer_offline(artifact: ModelArtifact, drive: np.ndarray, measurement: np.ndarray,
                         initial: Sequence[float], form: str | None = None, keep_covariance: bool = False,
                         dtype=F32) -> ObserverRun:
    """The float32 observer over a whole dataset: `drive` as `target_sim.model.run_offline` takes it,
    `measurement` the measurements' raw channels per row ((rows,) for one channel; NaN: none), accumulated with the
    drive into the step's float32 interval mean."""
    obs = Float32Observer(artifact, form, dtype)
    obs.reset(initial)
    drive = np.asarray(drive, dtype=np.float64)
    measurement = np.asarray(measurement, dtype=np.float64)
    width, channels = len(artifact.drive_signals), sum(obs.widths)
    if measurement.ndim == 1:
        measurement = measurement[:, None]
    if drive.ndim != 2 or drive.shape[1] != width or measurement.shape != (len(drive), channels):
        raise ValueError(f"the observer needs {width} drive columns and {channels} measurement channel(s) per row, "
                         f"not {drive.shape} and {measurement.shape}")
    rows = np.column_stack([drive, measurement])
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt, width + channels)
    steps, outputs, innovations, covariances, sigmas, own, rejected, flagged = [], [], [], [], [], [], [], []
    for row, sample in enumerate(rows):
        means = acc.add(row, sample)
        if means is None:
            continue
        outputs.append(obs.step(*means[:width], z=means[width:]))
        innovations.append(obs.innovations.copy())
        rejected.append(obs.rejected.copy())
        flagged.append(obs.flagged.copy())
        sigmas.append(obs.sigma())
        if keep_covariance:
            covariances.append(np.array(obs.covariance(), dtype=np.float64))
            own.append(obs.filter_covariance())
        steps.append(row)
    every = np.array(innovations, dtype=np.float64).reshape(-1, len(obs.measurements))
    return ObserverRun(np.array(steps, dtype=np.int64), np.array(outputs, dtype=dtype).reshape(-1, 4), every[:, 0],
                       np.array(covariances) if keep_covariance else None,
                       np.array(sigmas).reshape(-1, 4), every, np.array(own) if keep_covariance else None,
                       np.array(rejected, dtype=bool).reshape(-1, len(obs.measurements)), obs.flagged.copy(),
                       np.array(flagged, dtype=bool).reshape(-1, len(obs.measurements)))
