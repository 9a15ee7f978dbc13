"""The LTI LPTN: the network at its operating point, discretized, run as a fixed linear block
x <- A x + B u, y = C x over u = [P_y, P_w, P_t, P_m, ϑ_cv, ϑ_av, ϑ_a1, ϑ_a2] (losses, then the temperature sources
of eqs. 9-18 from the previous estimate). The artifact's `linear_block` holds A (4x4), B (4x8), C and C_inv (4x4)
in the realization's coordinates; the delta realization (`REALIZATIONS[...].delta`) steps
x <- x + Δ·(A x + B ũ), y = C x + r, with the sources taken relative to r = `linear_block.reference_C`.
`hammerstein` is this block behind a sigmoid."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from target_sim import costs
from target_sim.fmath import lanes, matvec
from target_sim.kinds import REALIZATIONS, is_delta
from target_sim.modelkinds import CArray, ModelKind, pole_text, register
from target_sim.network import COOLANT_REFERENCE_C

MATRICES = {"A": (4, 4), "B": (4, 8), "C": (4, 4), "C_inv": (4, 4)}
# the elements of `LinearBlockPart.source_jacobian` that are not always zero: (source, node)
SOURCE_JACOBIAN_NONZERO = ((0, 0), (1, 3), (2, 2), (2, 3), (3, 1), (3, 3))


class LinearBlockPart:
    """The linear block of one artifact in the estimator's precision, and the temperature sources it takes."""

    def __init__(self, artifact, estimator):
        self.est = est = estimator

        def arr(*keys):
            return artifact.array(*keys, dtype=est.f)

        self.delta = REALIZATIONS[artifact.realization].delta
        self.reference = arr("linear_block", "reference_C")[()] if self.delta else est.f(0.0)
        self.a, self.b = arr("linear_block", "A"), arr("linear_block", "B")
        self.c, self.c_inv = arr("linear_block", "C"), arr("linear_block", "C_inv")
        self.gains = self.source_gains(0.0, COOLANT_REFERENCE_C)   # until the first step

    def reset(self, y: np.ndarray) -> np.ndarray:
        """x0 = C^-1 y0, delta: C^-1 (y0 - r) (C: fw_reset)."""
        return matvec(self.c_inv, y - self.reference if self.delta else y)

    def output(self, x: np.ndarray) -> np.ndarray:
        """y = C x, delta: (C x) + r."""
        y = matvec(self.c, x)
        return y + self.reference if self.delta else y

    def source_gains(self, speed, coolant) -> tuple:
        """(g_tm, g_wm, g_ma, g_cy): R_xx1 / a_xx of eq. 15 at the speed and R_cy01 / R_cy0 of eq. 16 at the
        coolant temperature, what the sources weigh the previous estimate with."""
        est = self.est
        f = est.f
        n_ratio = f(speed) / est.speed_max
        g_tm, g_wm, g_ma = (lanes(est.conv_r0, n_ratio) * est.convection(n_ratio)) / lanes(est.conv_a, n_ratio)
        g_cy = est.p["alpha_cy"] * (f(coolant) - f(COOLANT_REFERENCE_C))  # R_cy01 / R_cy0 (eq. 16)
        return g_tm, g_wm, g_ma, g_cy

    def source_jacobian(self) -> np.ndarray:
        """d[ϑ_cv, ϑ_av, ϑ_a1, ϑ_a2]/d[yoke, winding, tooth, magnet] at the last step's gains: the sources are
        linear in the previous estimate, so the block's one-step map is x <- (A + B_s G C) x + ... exactly (B_s:
        B's source columns). An observer propagates its covariance with that map. Each 1/(1 + g) is one division,
        its two uses multiply by it (C: the observer's transition, bench.firmware.observergen); the elements
        outside `SOURCE_JACOBIAN_NONZERO` are zero."""
        g_tm, g_wm, g_ma, g_cy = self.gains
        one, zero = self.est.one, self.est.f(0.0)
        r_tm, r_wm, r_ma, r_cy = one / (one + g_tm), one / (one + g_wm), one / (one + g_ma), one / (one + g_cy)
        jac = np.full((4, 4), zero, dtype=self.est.f)
        jac[0, 0] = g_cy * r_cy
        jac[1, 3] = g_ma * r_ma
        jac[2, 2] = g_tm * r_tm
        jac[2, 3] = r_tm
        jac[3, 1] = r_wm
        jac[3, 3] = g_wm * r_wm
        return jac

    def temperature_sources(self, speed, coolant, ambient) -> np.ndarray:
        """[ϑ_cv, ϑ_av, ϑ_a1, ϑ_a2] of eqs. 9-18 from the estimator's previous estimate (C: temperature_sources);
        keeps the gains for `source_jacobian`."""
        est = self.est
        y, f, one = est.y, est.f, est.one
        coolant, ambient = f(coolant), f(ambient)
        self.gains = g_tm, g_wm, g_ma, g_cy = self.source_gains(speed, coolant)
        th_y, th_w, th_t, th_m = y
        return np.array([
            coolant + (g_cy * (th_y - coolant)) / (one + g_cy),
            ambient + (g_ma * (th_m - ambient)) / (one + g_ma),
            (th_m + g_tm * th_t) / (one + g_tm),
            (th_w + g_wm * th_m) / (one + g_wm),
        ], dtype=f)

    def step(self, x: np.ndarray, losses: np.ndarray, speed, coolant, ambient) -> np.ndarray:
        """x <- (A x) + (B u) row by row; delta: x <- x + Δ·((A x) + (B ũ)), ũ with the sources minus r."""
        if self.delta:
            sources = self.temperature_sources(speed, coolant, ambient) - self.reference
            increment = matvec(self.a, x) + matvec(self.b, np.concatenate([losses, sources]))
            return x + self.est.dt * increment
        u = np.concatenate([losses, self.temperature_sources(speed, coolant, ambient)])
        return matvec(self.a, x) + matvec(self.b, u)


_SOURCES_C = """\
/* Float32Estimator.temperature_sources: [th_cv, th_av, th_a1, th_a2] of eqs. 9-18 from the previous estimate;
 * g_xx = R_xx1 / a_xx with R_xx1 = R_xx0 exp(-n/n_max / b_xx) (eq. 15), g_cy = R_cy01 / R_cy0 (eq. 16) */
static void temperature_sources(float speed, float coolant, float ambient, float src[4])
{
    const float n_ratio = speed / SPEED_MAX;
    const float g_tm = (R_TM0 * fw_exp(-n_ratio / B_TM)) / A_TM;
    const float g_wm = (R_WM0 * fw_exp(-n_ratio / B_WM)) / A_WM;
    const float g_ma = (R_MA0 * fw_exp(-n_ratio / B_MA)) / A_MA;
    const float g_cy = ALPHA_CY * (coolant - COOLANT_REF);
    src[0] = coolant + (g_cy * (y_est[0] - coolant)) / (1.0f + g_cy);
    src[1] = ambient + (g_ma * (y_est[3] - ambient)) / (1.0f + g_ma);
    src[2] = (y_est[3] + g_tm * y_est[2]) / (1.0f + g_tm);
    src[3] = (y_est[1] + g_wm * y_est[3]) / (1.0f + g_wm);
}
"""

_STEP_SHIFT_C = """\
/* Float32Estimator.step (lti-lptn, hammerstein): u = [P_y, P_w, P_t, P_m, th_cv, th_av, th_a1, th_a2];
 * x <- (A x) + (B u) row by row; y = C x */
void fw_step(const float inputs[4], float y[4])
{{
    float u[8];
    float x_next[4];
    int i;
    node_losses(inputs[0], inputs[1], u);
{nonlinearity}    temperature_sources(inputs[1], inputs[2], inputs[3], &u[4]);
    for (i = 0; i < 4; i++) x_next[i] = dot(LB_A[i], x_state, 4) + dot(LB_B[i], u, 8);
    for (i = 0; i < 4; i++) x_state[i] = x_next[i];
    for (i = 0; i < 4; i++) y_est[i] = dot(LB_C[i], x_state, 4);
    for (i = 0; i < 4; i++) y[i] = y_est[i];
}}

/* Float32Estimator.reset: y = y0, x = C_inv y0 */
void fw_reset(const float y0[4])
{{
    int i;
    for (i = 0; i < 4; i++) y_est[i] = y0[i];
    for (i = 0; i < 4; i++) x_state[i] = dot(LB_C_INV[i], y_est, 4);
    fw_clear();
}}

/* Float32Estimator.restore: x bit for bit, y = C x */
void fw_restore(const float x[4])
{{
    int i;
    for (i = 0; i < 4; i++) x_state[i] = x[i];
    for (i = 0; i < 4; i++) y_est[i] = dot(LB_C[i], x_state, 4);
    fw_clear();
}}
"""

_STEP_DELTA_C = """\
/* Float32Estimator.step, delta realization: u = [P_y, P_w, P_t, P_m, th_cv - r, th_av - r, th_a1 - r, th_a2 - r];
 * increment = (A x) + (B u) row by row; x <- x + DT increment; y = (C x) + r */
void fw_step(const float inputs[4], float y[4])
{{
    float u[8];
    float increment[4];
    int i;
    node_losses(inputs[0], inputs[1], u);
{nonlinearity}    temperature_sources(inputs[1], inputs[2], inputs[3], &u[4]);
    for (i = 4; i < 8; i++) u[i] = u[i] - LB_REF;
    for (i = 0; i < 4; i++) increment[i] = dot(LB_A[i], x_state, 4) + dot(LB_B[i], u, 8);
    for (i = 0; i < 4; i++) x_state[i] = x_state[i] + DT * increment[i];
    for (i = 0; i < 4; i++) y_est[i] = dot(LB_C[i], x_state, 4) + LB_REF;
    for (i = 0; i < 4; i++) y[i] = y_est[i];
}}

/* Float32Estimator.reset, delta realization: y = y0, x = C_inv (y0 - r) */
void fw_reset(const float y0[4])
{{
    float deviation[4];
    int i;
    for (i = 0; i < 4; i++) y_est[i] = y0[i];
    for (i = 0; i < 4; i++) deviation[i] = y_est[i] - LB_REF;
    for (i = 0; i < 4; i++) x_state[i] = dot(LB_C_INV[i], deviation, 4);
    fw_clear();
}}

/* Float32Estimator.restore, delta realization: x bit for bit, y = (C x) + r */
void fw_restore(const float x[4])
{{
    int i;
    for (i = 0; i < 4; i++) x_state[i] = x[i];
    for (i = 0; i < 4; i++) y_est[i] = dot(LB_C[i], x_state, 4) + LB_REF;
    fw_clear();
}}
"""


def temperature_sources_ops() -> Counter:
    """Eqs. 9-18: three speed-dependent conductance ratios, the coolant factor and four sources."""
    op = costs.op_counts
    ratio = op(divide=1)
    conductances = Counter({k: 3 * v for k, v in op(divide=2, multiply=1, add=1, exp=1).items()})
    coolant = op(multiply=1, add=1)
    sources = op(multiply=2, add=6, divide=2) + op(multiply=2, add=4, divide=2)
    return ratio + conductances + coolant + sources + op(load_store=12 + 4)


class LtiLptnKind(ModelKind):
    name = "lti-lptn"
    summary = "the LPTN at its operating point, discretized (LTI)"
    linear_block = True
    input_nonlinearity = False
    realizations = True
    c_nonlinearity: ClassVar[str] = ""    # fw_step's line between node_losses and the sources (hammerstein's call)

    def fields(self, content: Mapping[str, Any]) -> list[tuple[str, ...]]:
        fields = [("linear_block", m) for m in MATRICES]
        if is_delta(self.name, content["realization"]):
            fields.append(("linear_block", "reference_C"))
        return fields

    def shapes(self, content: Mapping[str, Any]) -> dict[tuple[str, ...], tuple[int, ...]]:
        return {("linear_block", m): shape for m, shape in MATRICES.items()}

    def instability(self, artifact) -> str | None:
        """The transition matrix (A; delta: I + Δt·A) must have every pole inside the unit circle in float64, the
        model the artifact describes. The float32 rounding of a stable block may still be unstable (the `original`
        realization at Δt 0.5 s, the paper's Fig. 6): that loads, so the bench can show it, and any run of it that
        saturates is not clean."""
        a = artifact.array("linear_block", "A", dtype=np.float64)
        delta = is_delta(self.name, artifact.realization)
        transition = np.eye(len(a)) + artifact.dt * a if delta else a
        poles = np.linalg.eigvals(transition)
        worst = poles[int(np.argmax(np.abs(poles)))]
        if abs(worst) < 1.0:
            return None
        step = " (the delta realization's step I + Δt·A)" if delta else ""
        return (f"artifact linear_block.A{step} is unstable: pole z = {pole_text(worst)} (|z| = {abs(worst):.6g} ≥ 1), "
                "so every model step multiplies that mode by at least that much and the estimate grows without bound; "
                "rebuild it with 'bench identify'")

    def part(self, artifact, estimator) -> LinearBlockPart:
        return LinearBlockPart(artifact, estimator)

    def c_functions(self, artifact) -> list[str]:
        return [_SOURCES_C]

    def c_step(self, artifact) -> str:
        template = _STEP_DELTA_C if is_delta(self.name, artifact.realization) else _STEP_SHIFT_C
        return template.format(nonlinearity=self.c_nonlinearity)

    def c_scalars(self, artifact) -> list[tuple[str, tuple[str, ...] | np.float32, str]]:
        if not is_delta(self.name, artifact.realization):
            return []
        return [("LB_REF", ("linear_block", "reference_C"),
                 "linear_block.reference_C: the delta states' reference temperature")]

    def c_arrays(self, artifact) -> list[CArray]:
        return [CArray(f"LB_{m.upper()}", (("linear_block", m),), f"linear_block.{m} ({artifact.realization} "
                       "realization)", shape) for m, shape in MATRICES.items()]

    def ops(self, artifact) -> dict[str, Counter]:
        """The sources, then x <- A x + B u (one add per row joins the two products) and y = C x."""
        a, b, c = (artifact.array("linear_block", m) for m in ("A", "B", "C"))
        linear = (costs.matvec(a) + costs.matvec(b) + costs.op_counts(add=a.shape[0]) + costs.matvec(c)
                  + costs.op_counts(call=1))
        return {"sources": temperature_sources_ops(), "linear": linear}

    def coefficient_count(self, artifact) -> int:
        """The nonzero coefficients of A, B, C and C_inv."""
        return sum(int(np.count_nonzero(artifact.array("linear_block", m))) for m in MATRICES)


register(LtiLptnKind())
