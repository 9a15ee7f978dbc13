"""The UD filter's kernels as straight-line C: the transition F (node coordinates), Thornton's prediction and
Bierman's update of `target_sim.observer` unrolled over the structure the filter has when it is built
(`target_sim.observer.ud_structure`).

Every element that is always zero is left out (no variable, no product), a product by an exact one is not
written, the constants (A, B, C, the Jacobian's pattern, G, q, h) are literals, and every kept sum has the
reference's left-to-right order, so the C equals the Python reference bit for bit. -ffp-contract=off keeps
products and sums apart (no fused multiply-add). The locals are the compiler's to keep in registers: no loop
counters, no index arithmetic, no loads of zeros.

    obs_predict(void)              Transition.matrix + BiermanThornton.predict: F, F U, the MWGS
    obs_update_<k>(r, nu, corr.)   BiermanThornton.update for the k-th measurement's row h, then the correction
                                   (1: it moved a node)
    obs_output(void)               LinearBlockPart.output: y = C x (+ r)
    fw_obs_sigma(void)             Float32Observer.sigma: each node's 1-σ (BiermanThornton.variance)
    obs_move_state(correction)     Float32Observer._measurement_update's x <- x + C⁻¹ (the step's node correction)
    steady_c                       the steady-state-gain form's (SteadyState): no prediction, the gain K_ss
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from bench.firmware.literals import c_float
from target_sim.artifact import OUTPUTS
from target_sim.observer import Float32Observer
from target_sim.xcp.variables import LAG_SYMBOL, Q_SYMBOL

# the Jacobian's elements as target_sim.modelkinds.lti_lptn.LinearBlockPart.source_jacobian computes them, from
# r_x = 1 / (1 + g_x) (obs_gains: g_tm, g_wm, g_ma, g_cy, as temperature_sources keeps them)
GAINS = ("g_tm", "g_wm", "g_ma", "g_cy")
JACOBIAN_C = {(0, 0): "g_cy * r_cy", (1, 3): "g_ma * r_ma", (2, 2): "g_tm * r_tm", (2, 3): "r_tm",
              (3, 1): "r_wm", (3, 3): "g_wm * r_wm"}


@dataclass(frozen=True)
class Value:
    """A float32 value of the generated C: a local's name or a literal; `one`: exactly 1 (its products are not
    written)."""

    expr: str
    one: bool = False


ONE = Value(c_float(1.0), one=True)
C_NEG_ZERO = c_float(-0.0)


def literal(value) -> Value:
    value = np.float32(value)
    return ONE if value == 1.0 else Value(c_float(value))


def product(a: Value, b: Value) -> str:
    """a·b, or the other factor when one of them is exactly 1."""
    if a.one:
        return b.expr
    if b.one:
        return a.expr
    return f"{a.expr} * {b.expr}"


def total(terms: list[str]) -> str:
    """The left-to-right sum of the kept products (C's + is left-associative); -0 when there is none (the
    reference's structural zero)."""
    return " + ".join(terms) if terms else C_NEG_ZERO


class Lines:
    """The function body: each local declared where it is first assigned; the loads (`load`) come first, only
    those the body uses (an unused local is a warning, and -Werror)."""

    def __init__(self):
        self.lines: list[str] = []
        self.loads: list[tuple[str, str]] = []
        self.declared: set[str] = set()

    def load(self, name: str, expr: str) -> Value:
        self.declared.add(name)
        self.loads.append((name, f"    const float {name} = {expr};"))
        return Value(name)

    def comment(self, text: str) -> None:
        self.lines.append(f"    /* {text} */")

    def set(self, name: str, expr: str) -> Value:
        kind = "" if name in self.declared else "float "
        self.declared.add(name)
        self.lines.append(f"    {kind}{name} = {expr};")
        return Value(name)

    def raw(self, text: str) -> None:
        self.lines.append(f"    {text}")

    def text(self) -> str:
        body = "\n".join(self.lines)
        used = set(re.findall(r"\b\w+\b", body))
        return "\n".join([line for name, line in self.loads if name in used] + [body])


def _transition(obs: Float32Observer, out: Lines) -> list[list[Value | None]]:
    """F's elements (None: a structural zero) as Transition.matrix computes them."""
    n, k = obs.n, len(OUTPUTS)
    out.comment("F in node coordinates: C (I + dt A) C^-1 + (dt C B_s) J (shift form: C A C^-1 + (C B_s) J), J the "
                "sources' Jacobian (Transition.matrix)")
    for index, gain in enumerate(GAINS):
        out.load(gain, f"obs_gains[{index}]")
    for gain in GAINS:
        out.load(f"r_{gain[2:]}", f"{ONE.expr} / ({ONE.expr} + {gain})")
    jac: dict[tuple[int, int], Value] = {}
    for (s, node), expr in JACOBIAN_C.items():
        if obs.transition.jacobian_nonzero[s, node]:
            jac[s, node] = out.set(f"jac{s}_{node}", expr)
    bj: dict[tuple[int, int], Value] = {}
    for i in range(k):
        for j in range(k):
            terms = [product(literal(obs.transition.b_sources[i, s]), jac[s, j]) for s in range(k)
                     if obs.transition.b_sources_nonzero[i, s] and obs.transition.jacobian_nonzero[s, j]]
            if terms:
                bj[i, j] = out.set(f"bj{i}_{j}", total(terms))
    f: list[list[Value | None]] = [[None] * n for _ in range(n)]
    for i in range(k):
        for j in range(k):
            constant = obs.transition.a_step[i, j]
            if constant != 0 and (i, j) in bj:
                f[i][j] = out.set(f"f{i}_{j}", f"{literal(constant).expr} + ({bj[i, j].expr})")
            elif constant != 0:
                f[i][j] = literal(constant)
            elif (i, j) in bj:
                f[i][j] = bj[i, j]
    if obs.layout.bias_index >= 0:
        for i in range(k):
            if obs.transition.bias_node[i] != 0:
                f[i][obs.layout.bias_index] = literal(obs.transition.bias_node[i])
        f[obs.layout.bias_index][obs.layout.bias_index] = ONE
    for index, (m, lag) in enumerate(zip(obs.measurements, obs.layout.lag_index, strict=True)):
        if lag < 0:
            continue
        # the lag pole is calibratable (XCP): read from its variable at every step, 1 - a computed as the reference's
        pole = f"{LAG_SYMBOL}_{index}"
        gain = out.load(f"gain{lag}", f"{ONE.expr} - {pole}")
        for j in range(n):
            terms = [product(literal(m.sees[i]), f[i][j]) for i in range(k) if m.sees[i] != 0 and f[i][j] is not None]
            if terms and j != lag:
                f[lag][j] = out.set(f"f{lag}_{j}", product(gain, Value(f"({total(terms)})")))
        output = obs.layout.bias_output
        if output >= 0 and m.sees[output] != 0:     # the sensor sees the output bias too (Transition.matrix)
            f[lag][obs.layout.bias_index] = out.set(f"f{lag}_{obs.layout.bias_index}",
                                                    product(gain, literal(m.sees[output])))
        f[lag][lag] = out.load(f"pole{lag}", pole)
    return f


def _check_structure(obs: Float32Observer, f: list[list[Value | None]]) -> None:
    """The C's zeros are the reference's (a generator bug otherwise)."""
    mine = np.array([[value is not None for value in row] for row in f])
    if not np.array_equal(mine, obs.transition.nonzero):
        raise AssertionError("the generated transition's structure differs from Transition.nonzero")


def predict_c(obs: Float32Observer) -> str:
    """obs_predict: F, W = [F U, G] and Thornton's MWGS (BiermanThornton.predict), into obs_u and obs_d."""
    cov, n = obs.cov, obs.n
    out = Lines()
    f = _transition(obs, out)
    _check_structure(obs, f)
    out.comment("the covariance's factors U (unit upper triangular) and d of the last step")
    old_u = {(i, j): out.load(f"uo{i}_{j}", f"obs_u[{i}][{j}]") for j in range(n) for i in range(j)}
    old_d = [out.load(f"do{i}", f"obs_d[{i}]") for i in range(n)]
    out.comment("W = [F U, G]: (F U)_ij over k <= j (U_jj = 1), then G's kept columns")
    w: list[list[Value | None]] = [[None] * (n + len(cov.g_columns)) for _ in range(n)]
    for i in range(n):
        for j in range(n):
            terms = [f[i][m].expr if m == j else product(f[i][m], old_u[m, j])
                     for m in range(j + 1) if f[i][m] is not None]
            if terms:
                w[i][j] = out.set(f"w{i}_{j}", total(terms))
        for m in range(len(cov.g_columns)):
            if cov.g_nonzero[i, m]:
                w[i][n + m] = literal(cov.g[i, m])
    # Q's kept diagonal, calibratable (XCP): read from its variable at every prediction
    weights = old_d + [out.load(f"q{col}", f"{Q_SYMBOL}[{col}]") for col in cov.g_columns]
    out.comment("modified weighted Gram-Schmidt, last row first: d_j = w_j (w_j o weights), "
                "u_ij = (w_i (w_j o weights)) / d_j, w_i -= u_ij w_j")
    for pivot in cov.schedule(obs.transition.nonzero):
        j, columns = pivot.row, pivot.columns
        c = {col: out.set(f"c{j}_{col}", product(w[j][col], weights[col])) for col in columns}
        d_j = out.set(f"d{j}", total([product(w[j][col], c[col]) for col in columns]))
        out.raw(f"obs_d[{j}] = {d_j.expr};")
        if not pivot.rows:
            continue
        inverse = out.set(f"inv{j}", f"{ONE.expr} / {d_j.expr}")
        for row in pivot.rows:
            i = row.row
            dot = total([product(w[i][columns[p]], c[columns[p]]) for p in row.shared])
            u_ij = out.set(f"u{i}_{j}", f"({dot}) * {inverse.expr}")
            out.raw(f"obs_u[{i}][{j}] = {u_ij.expr};")
            for col in columns:
                step = product(u_ij, w[j][col])
                if w[i][col] is None:
                    w[i][col] = out.set(f"w{i}_{col}", f"-({step})")
                else:
                    w[i][col] = out.set(f"w{i}_{col}", f"{w[i][col].expr} - {step}")
    return ("/* Transition.matrix and BiermanThornton.predict, unrolled (bench.firmware.udgen) */\n"
            "__attribute__((noinline)) static void obs_predict(void)\n{\n" + out.text() + "\n}\n")


def correction_c(n: int, gain: list[str], moves_y: bool, held: np.ndarray | None = None) -> str:
    """Float32Observer._update's correction with the gain's elements `gain` (C expressions) and the innovation nu:
    each node's step (gain_i nu) onto y (when a later measurement of the step may read it: `moves_y`) and onto the
    step's summed correction, each extra state + gain_i nu; a `held` state's step is a structural zero, not
    written, and then the function's value says whether any node moves (`update_return`)."""
    k = len(OUTPUTS)
    kept = [i for i in range(n) if held is None or not held[i]]
    lines = ["    float step;"] if any(i < k for i in kept) else ["    (void)correction;"]
    for i in (i for i in kept if i < k):
        lines.append(f"    step = ({gain[i]}) * nu;")
        if moves_y:
            lines.append(f"    y_est[{i}] = y_est[{i}] + step;")
        lines.append(f"    correction[{i}] = correction[{i}] + step;")
    lines += [f"    obs_extra[{i}] = obs_extra[{i}] + ({gain[i]}) * nu;" for i in kept if i >= k]
    return "\n".join(lines + [f"    return {int(moves_nodes(held))};"])


def moves_nodes(held: np.ndarray | None) -> bool:
    """Whether an update that holds `held` moves any node (Float32Observer._update's None when it does not)."""
    return held is None or not held[:len(OUTPUTS)].all()


def update_c(obs: Float32Observer, name: str, h: np.ndarray, moves_y: bool = True,
             held: np.ndarray | None = None) -> str:
    """`name`(r, nu, correction): Bierman's update of obs_u, obs_d with the constant row h and variance r
    (BiermanThornton.update), with `held` (consider states) Agee and Turner's rank-one update after it
    (`rank_one_c`), then the correction with its gain (the held rows -0) and the innovation nu (`correction_c`)."""
    cov, n = obs.cov, obs.n
    schedule = cov.bierman(h)
    v_nonzero = np.zeros(n, dtype=bool) if held is None else held & np.asarray(schedule.gain_nonzero)
    rank_one = cov.rank_one_steps(v_nonzero) if v_nonzero.any() else ()
    out = Lines()
    h_values = [literal(v) for v in h]
    reads = {(i, j) for j, terms in enumerate(schedule.terms) for i in terms if i < j}
    reads |= {(i, s.column) for s in (*schedule.steps, *rank_one) for i in (*s.updated, *s.filled)}
    u = {(i, j): out.set(f"u{i}_{j}", f"obs_u[{i}][{j}]") for (i, j) in sorted(reads, key=lambda p: (p[1], p[0]))}
    columns = sorted({s.column for s in (*schedule.steps, *rank_one)})
    d = {j: out.set(f"d{j}", f"obs_d[{j}]") for j in columns}
    a, b = _bierman_ab(out, schedule, h_values, u, d)
    updates = any(step.updated for step in schedule.steps)
    out.raw("float alpha = r, beta;" + (" float lambda, held;" if updates else ""))
    out.raw(f"float gamma = {ONE.expr} / alpha;")
    for step in schedule.steps:
        j = step.column
        out.raw("beta = alpha;")
        out.raw(f"alpha = alpha + {product(a[j], b[j])};")
        if step.updated:
            out.raw("lambda = -gamma;" if a[j].one else f"lambda = -{a[j].expr} * gamma;")
        out.raw(f"gamma = {ONE.expr} / alpha;")
        out.raw(f"{d[j].expr} = (beta * gamma) * {d[j].expr};")
        out.raw(f"obs_d[{j}] = {d[j].expr};")
        for i in step.updated:
            out.raw(f"held = {u[i, j].expr};")
            out.raw(f"{u[i, j].expr} = held + {b[i].expr} * lambda;")
            out.raw(f"obs_u[{i}][{j}] = {u[i, j].expr};")
            out.raw(f"{b[i].expr} = {b[i].expr} + {b[j].expr} * held;")
        for i in step.filled:
            b[i] = out.set(f"b{i}", f"{b[j].expr} * {u[i, j].expr}")
    if rank_one:
        rank_one_c(out, rank_one, np.flatnonzero(v_nonzero), b, u, d)
    gain = [f"{b[i].expr if i in b else C_NEG_ZERO} * gamma" for i in range(n)]
    out.lines.append(correction_c(n, gain, moves_y, held))
    return (f"/* BiermanThornton.update for h = [{', '.join(f'{float(v):.6g}' for v in h)}] and the correction, "
            "unrolled (bench.firmware.udgen); 1: it moved a node */\n"
            f"static int {name}(float r, float nu, float correction[4])\n{{\n" + out.text() + "\n}\n")


def _bierman_ab(out: Lines, schedule, h_values: list[Value], u: dict, d: dict) -> tuple[dict, dict]:
    """a = U^T h over h's nonzeros, b = d o a (the locals a<j>, b<j>), as BiermanThornton.update begins."""
    out.comment("a = U^T h over h's nonzeros, b = d o a")
    a: dict[int, Value] = {}
    b: dict[int, Value] = {}
    for j, terms in enumerate(schedule.terms):
        if not terms:
            continue
        parts = [h_values[j].expr if i == j else product(h_values[i], u[i, j]) for i in terms]
        a[j] = ONE if parts == [ONE.expr] else out.set(f"a{j}", total(parts))
        b[j] = out.set(f"b{j}", product(d[j], a[j]))
    return a, b


def variance_c(obs: Float32Observer, name: str, h: np.ndarray) -> str:
    """`name`(r) -> S = h P⁻ hᵀ + r as Bierman's update reaches it (BiermanThornton.innovation_variance: its final
    alpha, the gate's denominator), the covariance unchanged."""
    schedule = obs.cov.bierman(h)
    out = Lines()
    reads = {(i, j) for j, terms in enumerate(schedule.terms) for i in terms if i < j}
    u = {(i, j): out.load(f"u{i}_{j}", f"obs_u[{i}][{j}]") for (i, j) in sorted(reads, key=lambda p: (p[1], p[0]))}
    d = {j: out.load(f"d{j}", f"obs_d[{j}]") for j, terms in enumerate(schedule.terms) if terms}
    a, b = _bierman_ab(out, schedule, [literal(v) for v in h], u, d)
    out.raw("float alpha = r;")
    for step in schedule.steps:
        out.raw(f"alpha = alpha + {product(a[step.column], b[step.column])};")
    out.raw("return alpha;")
    return (f"/* BiermanThornton.innovation_variance for h = [{', '.join(f'{float(v):.6g}' for v in h)}] */\n"
            f"static float {name}(float r)\n{{\n" + out.text() + "\n}\n")


def rank_one_c(out: Lines, steps, rows, b: dict, u: dict, d: dict) -> None:
    """BiermanThornton.rank_one after Bierman's update: U D U^T + gamma v v^T, v = b on the held `rows` (the
    locals v<i>), over its schedule `steps`, into obs_u and obs_d."""
    out.comment("consider states: P += gamma v v^T, v = b on the held rows (Agee-Turner, BiermanThornton.rank_one)")
    v = {int(i): out.set(f"v{i}", b[int(i)].expr) for i in rows}
    out.raw("float ca = gamma, cv, dn;" + (" float beta_at;" if any(s.updated or s.filled for s in steps) else ""))
    for index, step in enumerate(steps):
        j = step.column
        if j not in v:            # filled by an earlier column
            raise AssertionError("the rank-one schedule's column has no v (a generator bug)")
        out.raw(f"cv = ca * {v[j].expr};")
        out.raw(f"dn = {d[j].expr} + cv * {v[j].expr};")
        if step.updated or step.filled:
            out.raw("beta_at = dn > 0.0f ? cv / dn : 0.0f;")
        if index < len(steps) - 1:      # the last column's c is not read again
            out.raw(f"ca = dn > 0.0f ? (ca * {d[j].expr}) / dn : ca;")
        out.raw(f"{d[j].expr} = dn;")
        out.raw(f"obs_d[{j}] = dn;")
        for i in step.updated:
            out.raw(f"{v[i].expr} = {v[i].expr} - {v[j].expr} * {u[i, j].expr};")
            out.raw(f"{u[i, j].expr} = {u[i, j].expr} + beta_at * {v[i].expr};")
            out.raw(f"obs_u[{i}][{j}] = {u[i, j].expr};")
        for i in step.filled:
            v[i] = out.set(f"v{i}", f"-({v[j].expr} * {u[i, j].expr})")
            out.raw(f"{u[i, j].expr} = {u[i, j].expr} + beta_at * {v[i].expr};")
            out.raw(f"obs_u[{i}][{j}] = {u[i, j].expr};")


def steady_c(n: int, updates: list[tuple[str, str, bool, np.ndarray | None]]) -> str:
    """The steady-state-gain form's kernels (SteadyState): no prediction; each (function, gain array, moves_y,
    held) of `updates` corrects with its measurement's row of K_ss, whatever r (`correction_c`)."""
    code = "/* SteadyState.predict: nothing (no covariance) */\nstatic void obs_predict(void)\n{\n}\n"
    for name, gain, moves_y, held in updates:
        body = correction_c(n, [f"{gain}[{i}]" for i in range(n)], moves_y, held)
        code += (f"\n/* SteadyState.update: the constant gain {gain} (K_ss's row), whatever r, and the correction; "
                 "1: it moved a node */\n"
                 f"static int {name}(float r, float nu, float correction[4])\n{{\n    (void)r;\n{body}\n}}\n")
    return code


def sigma_c(obs: Float32Observer) -> str:
    """fw_obs_sigma: each node's 1-σ into obs_sigma (Float32Observer.sigma with BiermanThornton.variance), over the
    structure: c the node's unit row (and the bias's one for the node an output bias adds to), v_j = Σ_i c_i u_ij
    over U's unit upper triangle (the ones not multiplied), σ² = (d_j v_j) v_j summed over v's structural nonzeros
    in order; the steady form's P_ss is the same every step (obs_sigma keeps its initial values)."""
    head = ("/* Float32Observer.sigma (BiermanThornton.variance over the structure: v = U^T c, sigma^2 = (d_j v_j) v_j "
            "summed), unrolled (bench.firmware.udgen) */\nvoid fw_obs_sigma(void)\n{\n")
    if obs.form == "steady":
        return head + "}\n"
    n, out = obs.n, Lines()
    u = {(i, j): out.load(f"u{i}_{j}", f"obs_u[{i}][{j}]") for j in range(n) for i in range(j)}
    d = [out.load(f"d{j}", f"obs_d[{j}]") for j in range(n)]
    bias, bias_output = obs.layout.bias_index, obs.layout.bias_output
    for node in range(len(OUTPUTS)):
        rows = [node, bias] if node == bias_output and bias >= 0 else [node]
        terms = []
        for j in range(n):
            parts = [ONE if i == j else u[i, j] for i in rows if i <= j]
            if not parts:
                continue
            v = parts[0] if len(parts) == 1 else out.set(f"v{node}_{j}", total([p.expr for p in parts]))
            terms.append(d[j].expr if v.one else f"({product(d[j], v)}) * {v.expr}")
        s = out.set(f"s{node}", total(terms))
        out.raw(f"obs_sigma[{node}] = {s.expr} > 0.0f ? __builtin_sqrtf({s.expr}) : 0.0f;")
    return head + out.text() + "\n}\n"


def output_c(obs: Float32Observer) -> str:
    """obs_output: y = C x (delta: (C x) + r), LinearBlockPart.output with C's elements as literals, every product
    kept (zeros too: `fmath.matvec`)."""
    part, k = obs.est.part, len(OUTPUTS)
    lines = []
    for i in range(k):
        terms = total([product(literal(part.c[i, j]), Value(f"x_state[{j}]")) for j in range(k)])
        lines.append(f"    y_est[{i}] = ({terms}) + {literal(part.reference).expr};" if part.delta
                     else f"    y_est[{i}] = {terms};")
    return ("/* y = C x (delta: (C x) + r): LinearBlockPart.output, unrolled (bench.firmware.udgen) */\n"
            "static void obs_output(void)\n{\n" + "\n".join(lines) + "\n}\n")


def move_state_c(obs: Float32Observer) -> str:
    """obs_move_state(correction): x <- x + C⁻¹ correction (Float32Observer._measurement_update: the step's node
    corrections moved into the model's states once), C⁻¹'s elements as literals, every product kept (zeros too:
    `fmath.matvec`)."""
    k = len(OUTPUTS)
    lines = []
    for i in range(k):
        terms = [product(literal(obs.c_inv[i, j]), Value(f"correction[{j}]")) for j in range(k)]
        lines.append(f"    x_state[{i}] = x_state[{i}] + ({total(terms)});")
    return ("/* x <- x + C^-1 correction: the step's node corrections in the model's states (bench.firmware.udgen) */\n"
            "static void obs_move_state(const float correction[4])\n{\n" + "\n".join(lines) + "\n}\n")
