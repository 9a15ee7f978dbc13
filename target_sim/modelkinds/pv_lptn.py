"""The parameter-varying LPTN: the network rebuilt every step from the speed and the coolant temperature
(`target_sim.network.network_matrices`) and stepped by forward Euler (eq. 51), as the paper ran it; the state is the
temperatures themselves. No section of its own: it runs from the artifact's `lptn` parameters, and only in the
network's coordinates ("physical")."""

from __future__ import annotations

from collections import Counter

import numpy as np

from target_sim import costs
from target_sim.artifact import LPTN_PARAMETERS
from target_sim.fmath import lanes, matvec
from target_sim.modelkinds import ModelKind, pole_text, register
from target_sim.network import COOLANT_REFERENCE_C, network_matrices

# The operating box over which the forward-Euler step must be stable: speed over the DBC's MotorSpeed range (rpm),
# coolant from -40 °C to 100 °C (a water-glycol circuit's working range, above the datasets' 20-60 °C). Each
# conductance of the network is monotonic in one of the two, and the eigenvalues of C^-1 G grow with every
# conductance, so the corners bound every point inside. Not up to the DBC's 150 °C: eq. 16's R_cy falls linearly
# with the coolant and reaches zero at 40 - 1/alpha_cy (151 °C for Table 1, about 120 °C at the IPM example's
# bound), where no Euler step is stable; a run that drives a model there saturates and is not clean.
PV_SPEED_CORNERS_RPM = (-1000.0, 15000.0)
PV_COOLANT_CORNERS_C = (-40.0, 100.0)


class PvNetworkPart:
    """The network rebuilt from the estimator's float32 parameters at every step."""

    def __init__(self, artifact, estimator):
        self.est = estimator

    def reset(self, y: np.ndarray) -> np.ndarray:
        """The state is the temperatures: x = y0."""
        return y.copy()

    def output(self, x: np.ndarray) -> np.ndarray:
        return x.copy()

    def pv_network(self, speed, coolant) -> tuple[np.ndarray, np.ndarray]:
        """Continuous A (4x4) and B (4x6) at this speed and coolant temperature, built in the estimator's precision
        (C: pv_network; the construction: `target_sim.network.network_matrices`)."""
        est = self.est
        p, f, one = est.p, est.f, est.one
        n_ratio = f(speed) / est.speed_max
        r_tm, r_wm, r_ma = lanes(est.conv_r0, n_ratio) * est.convection(n_ratio) + lanes(est.conv_a, n_ratio)  # 15
        r_cy = p["R_cy0"] * (one + p["alpha_cy"] * (f(coolant) - f(COOLANT_REFERENCE_C)))  # eq. 16
        return network_matrices(p, r_tm, r_wm, r_ma, r_cy, f)

    def step(self, x: np.ndarray, losses: np.ndarray, speed, coolant, ambient) -> np.ndarray:
        """x <- x + Δt·((A x) + (B u)), u = [P_y, P_w, P_t, P_m, coolant, ambient]."""
        a, b = self.pv_network(speed, coolant)
        u = np.concatenate([losses, np.array([coolant, ambient], dtype=self.est.f)])
        return x + self.est.dt * (matvec(a, x) + matvec(b, u))


_PV_C = """\
/* Float32Estimator.pv_network: continuous A (4x4) and B (4x6) of the parameter-varying LPTN. g[i][j] is the
 * conductance between nodes i, j of (yoke, winding, tooth, magnet, coolant, ambient); A[i][j] = g[i][j] / C_i off
 * the diagonal, A[i][i] = -(row sum of g[i], left to right over all six) / C_i, B = [diag(1/C) | g[:, 4:] / C_i] */
static void pv_network(float speed, float coolant, float a[4][4], float b[4][6])
{
    const float n_ratio = speed / SPEED_MAX;
    const float r_tm = R_TM0 * fw_exp(-n_ratio / B_TM) + A_TM;                      /* eq. 15 */
    const float r_wm = R_WM0 * fw_exp(-n_ratio / B_WM) + A_WM;
    const float r_ma = R_MA0 * fw_exp(-n_ratio / B_MA) + A_MA;
    const float r_cy = R_CY0 * (1.0f + ALPHA_CY * (coolant - COOLANT_REF));         /* eq. 16 */
    float g[4][6];
    float inv_c[4];
    int i, j;
    for (i = 0; i < 4; i++)
        for (j = 0; j < 6; j++) g[i][j] = 0.0f;
    g[0][1] = g[1][0] = 1.0f / R_YW;
    g[0][2] = g[2][0] = 1.0f / R_YT;
    g[1][2] = g[2][1] = 1.0f / R_WT;
    g[1][3] = g[3][1] = 1.0f / r_wm;
    g[2][3] = g[3][2] = 1.0f / r_tm;
    g[3][5] = 1.0f / r_ma;
    g[0][4] = 1.0f / r_cy;
    inv_c[0] = 1.0f / C_Y;
    inv_c[1] = 1.0f / C_W;
    inv_c[2] = 1.0f / C_T;
    inv_c[3] = 1.0f / C_M;
    for (i = 0; i < 4; i++) {
        float row_sum = g[i][0];
        for (j = 1; j < 6; j++) row_sum = row_sum + g[i][j];
        for (j = 0; j < 4; j++) a[i][j] = g[i][j] * inv_c[i];
        a[i][i] = -row_sum * inv_c[i];
        for (j = 0; j < 4; j++) b[i][j] = 0.0f;
        b[i][i] = inv_c[i];
        b[i][4] = g[i][4] * inv_c[i];
        b[i][5] = g[i][5] * inv_c[i];
    }
}
"""

_STEP_C = """\
/* Float32Estimator.step (pv-lptn): u = [P_y, P_w, P_t, P_m, coolant, ambient];
 * forward Euler (eq. 51): x <- x + dt ((A x) + (B u)); y = x */
void fw_step(const float inputs[4], float y[4])
{
    float a[4][4], b[4][6];
    float u[6];
    float x_next[4];
    int i;
    node_losses(inputs[0], inputs[1], u);
    pv_network(inputs[1], inputs[2], a, b);
    u[4] = inputs[2];
    u[5] = inputs[3];
    for (i = 0; i < 4; i++) x_next[i] = x_state[i] + DT * (dot(a[i], x_state, 4) + dot(b[i], u, 6));
    for (i = 0; i < 4; i++) x_state[i] = x_next[i];
    for (i = 0; i < 4; i++) y_est[i] = x_state[i];
    for (i = 0; i < 4; i++) y[i] = y_est[i];
}

/* Float32Estimator.reset: the pv-lptn's state is the temperatures themselves, x = y = y0 */
void fw_reset(const float y0[4])
{
    int i;
    for (i = 0; i < 4; i++) y_est[i] = y0[i];
    for (i = 0; i < 4; i++) x_state[i] = y_est[i];
    fw_clear();
}

/* Float32Estimator.restore: x bit for bit, y = x */
void fw_restore(const float x[4])
{
    int i;
    for (i = 0; i < 4; i++) x_state[i] = x[i];
    for (i = 0; i < 4; i++) y_est[i] = x_state[i];
    fw_clear();
}
"""


def pv_network_ops() -> Counter:
    """The parameter-varying LPTN rebuilt every step (1/C precomputed) and one forward-Euler step."""
    op = costs.op_counts
    resistances = Counter({k: 3 * v for k, v in op(divide=2, multiply=1, add=1, exp=1).items()})
    coolant = op(multiply=2, add=2)
    conductances = op(divide=7)                       # 1/R of the seven branches
    a_off = op(multiply=10)                           # g_ij / C_i
    a_diag = op(add=2 + 3 + 2 + 2, multiply=4)        # row sums of the conductances, times 1/C_i
    b = op(multiply=2)                                # coolant and ambient columns
    build = resistances + coolant + conductances + a_off + a_diag + b + op(load_store=20 + 30)
    # Euler: x += dt·(A x + B u); A has 14 nonzeros, B 6
    euler = op(multiply=14 + 6 + 4, add=10 + 2 + 4 + 4, load_store=2 * 20 + 8)
    return build + euler + op(call=1)


class PvLptnKind(ModelKind):
    name = "pv-lptn"
    summary = "the parameter-varying LPTN rebuilt every step, forward Euler"
    linear_block = False
    input_nonlinearity = False
    realizations = False

    def instability(self, artifact) -> str | None:
        """The forward-Euler step I + Δt·A(speed, coolant) at the corners of PV_SPEED_CORNERS_RPM x
        PV_COOLANT_CORNERS_C, from the float32 parameters the target runs."""
        p = {name: float(artifact.array("lptn", "parameters", name)) for name in LPTN_PARAMETERS}
        speed_max = float(artifact.array("lptn", "speed_max_rpm"))
        for speed in PV_SPEED_CORNERS_RPM:
            for coolant in PV_COOLANT_CORNERS_C:
                ratio = speed / speed_max
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    r_tm, r_wm, r_ma = (p[f"R_{k}0"] * np.exp(-ratio / p[f"b_{k}"]) + p[f"a_{k}"]
                                        for k in ("tm", "wm", "ma"))
                    r_cy = p["R_cy0"] * (1.0 + p["alpha_cy"] * (coolant - COOLANT_REFERENCE_C))
                    a, _ = network_matrices(p, r_tm, r_wm, r_ma, r_cy, np.float64)
                    transition = np.eye(4) + artifact.dt * a
                poles = np.linalg.eigvals(transition) if np.all(np.isfinite(transition)) else np.array([np.inf])
                worst = poles[int(np.argmax(np.abs(poles)))]
                if not abs(worst) < 1.0:
                    return (f"artifact pv-lptn: the forward-Euler step of {artifact.dt:g} s is unstable at speed "
                            f"{speed:g} rpm and coolant {coolant:g} °C (pole z = {pole_text(worst)}, |z| = "
                            f"{abs(worst):.6g} ≥ 1), so the estimate grows without bound there; rebuild it with "
                            "'bench identify' (a shorter Δt or another kind)")
        return None

    def part(self, artifact, estimator) -> PvNetworkPart:
        return PvNetworkPart(artifact, estimator)

    def c_functions(self, artifact) -> list[str]:
        return [_PV_C]

    def c_step(self, artifact) -> str:
        return _STEP_C

    def ops(self, artifact) -> dict[str, Counter]:
        return {"linear": pv_network_ops()}

    def coefficient_count(self, artifact) -> int:
        return 4                                       # 1/C_i

    def work_floats(self, artifact) -> int:
        return 4 * 4 + 4 * 6 + 4 * 6                   # A, B and the conductances rebuilt every step


register(PvLptnKind())
