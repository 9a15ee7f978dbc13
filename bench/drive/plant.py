"""The virtual motor on its test stand: the thermal truth behind the generated measurements.

Thermal network: the parameter-varying LPTN of paper Fig. 4 (top), `bench.thermal.lptn.pv_matrices`, with the
`table1-refined` parameters unchanged: speed-dependent convection around the magnet (eq. 15) and the
coolant-dependent yoke-coolant resistance (eq. 16) are re-evaluated every step. Integration: exact
discretization of the network over each step h (0.1 s by default) with torque, speed, coolant and ambient
taken at the step's midpoint, and the state-dependent losses taken at the step's start; the tests show that
h = 0.1 s, h = 0.02 s and an adaptive ODE solver agree within 0.01 °C.

Losses: the parametric model behind the nominal maps (`bench.drive.motor`) with eqs. 3-8, plus effects the
nominal maps and an LTI network driven by them do not capture (`TrueEffects`):
- magnet remanence falls with magnet temperature (NdFeB, -0.12 %/K): more current for the same torque (60 % of
  it is magnet torque, `MotorSpec.magnet_torque_share`), so more copper loss when the magnet is hot, and less
  flux in the iron;
- iron losses fall with iron temperature (higher steel resistivity, lower hysteresis), -0.1 %/K;
- magnet eddy losses fall as the magnet's resistivity rises, +0.4 %/K;
- map error growing with load: the FE maps miss PWM-ripple, end-winding and local-saturation copper losses, so
  the real copper loss is the map's times (1 + 1.5·(I/I_max)²), i.e. up to 2.5 times the map at I_max; and they
  miss the 3-D eddy paths in the magnets, so the real magnet loss is the map's times (1 + 1.5·P_m,map/P_m,ref).
  An iron-loss load error (× (1 + e·|T|/T_peak)) is available but off by default: it is not a function of the
  iron loss alone, so no per-input nonlinearity could learn it and it would only blur the comparison.
The copper and magnet load errors are static functions of their losses, which a Hammerstein input nonlinearity can learn
(an identified LTI network can only split the difference between preheat and cycles); the temperature effects
are only partly learnable, which keeps the problem honest.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np

from bench.drive.motor import MotorSpec, current_components
from bench.thermal.lptn import pv_matrices, varying_resistances
from bench.thermal.parameters import TABLE1_REFINED, LptnParameters

PLANT_STEP_S = 0.1


@dataclass(frozen=True)
class TrueEffects:
    """What the real machine does that the nominal maps (at 20 °C, no load error) leave out."""

    remanence_per_K: float = -0.0012         # B_r(ϑ_m) = B_r20·(1 + α(ϑ_m - 20))
    iron_per_K: float = -0.001               # iron loss × (1 + α(ϑ_iron - 20)), ϑ_iron = mean(yoke, tooth)
    magnet_resistivity_per_K: float = 0.004  # magnet eddy loss ÷ (1 + α(ϑ_m - 20))
    copper_load_error: float = 1.5           # copper loss × (1 + e·((I/I_max)² - knee))
    copper_load_knee: float = 0.0            # below this (I/I_max)² the map overestimates the copper loss
    saturation_loss: float = 0.0             # extra copper loss share once the teeth saturate: × (1 + e·σ(…))
    saturation_current: float = 0.43         # I/I_max where tooth-tip saturation sets in
    magnet_load_error: float = 1.5           # magnet loss × (1 + e·P_m,map/P_m,ref), P_m,ref = MotorSpec.magnet_W
    iron_load_error: float = 0.0             # iron loss × (1 + e·|T|/T_peak); see the module docstring

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


NO_EFFECTS = TrueEffects(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
TRUE_EFFECTS = TrueEffects()


class DriveProfile(Protocol):
    """What the plant needs from a drive profile (TestSequence, ConstantDrive)."""

    motor: MotorSpec

    def drive(self, t) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True, eq=False)
class LossInputs:
    """State-independent parts of the loss model, per evaluation point (arrays or floats)."""

    i_q: np.ndarray    # torque-producing current at 20 °C magnet (A)
    i_d: np.ndarray    # field-weakening current (A)
    tau: np.ndarray    # |T| / T_peak
    w: np.ndarray      # |n| / n_max (the speed ratio of eqs. 8, 15)
    f: np.ndarray      # |n| / n_base (electrical frequency relative to base speed)


def loss_inputs(spec: MotorSpec, torque, speed_rpm) -> LossInputs:
    torque = np.asarray(torque, dtype=float)
    speed = np.abs(np.asarray(speed_rpm, dtype=float))
    i_q, i_d = current_components(spec, torque, speed)
    return LossInputs(i_q, i_d, np.abs(torque) / spec.peak_torque_Nm, speed / spec.max_speed_rpm,
                      speed / spec.base_speed_rpm)


def make_true_losses(spec: MotorSpec, effects: TrueEffects, p: LptnParameters):
    """losses(i_q, i_d, tau, w, f, th_y, th_w, th_t, th_m) -> (P_y, P_w, P_t, P_m).

    Written with arithmetic operators only, so the same code runs on Python floats (the plant's step loop,
    where numpy's per-call overhead would dominate) and on numpy arrays (tests, steady states, the ODE).
    It equals `motor.parametric_losses` + `thermal.losses.node_losses` when effects are NO_EFFECTS.
    """
    i_max, r15 = spec.i_max_A, 1.5 * spec.phase_resistance_ohm
    alpha_cu, ref = spec.alpha_cu_per_K, spec.reference_C
    k_ac, ac_pm = spec.ac_factor, spec.ac_pm_W
    p_h, p_e, c_d, c_q = spec.iron_hysteresis_W, spec.iron_eddy_W, spec.demagnetization, spec.armature_flux
    mag, c0, share = spec.magnet_W, spec.magnet_no_load_share, spec.magnet_torque_share
    rem, a_fe, a_pm = effects.remanence_per_K, effects.iron_per_K, effects.magnet_resistivity_per_K
    e_cu, e_fe, knee = effects.copper_load_error, effects.iron_load_error, effects.copper_load_knee
    e_pm = effects.magnet_load_error
    e_sat, r_sat = effects.saturation_loss, effects.saturation_current
    k0, k1, k2, k3 = p.k_0, p.k_1, p.k_2, p.k_3

    def losses(i_q, i_d, tau, w, f, th_y, th_w, th_t, th_m):
        flux = 1.0 + rem * (th_m - ref)
        iq = i_q / (1.0 + share * (flux - 1.0))
        i2 = iq * iq + i_d * i_d
        r = i2 ** 0.5 / i_max
        p_dc0 = r15 * i2
        p_ac0 = w * w * (k_ac * p_dc0 + ac_pm * flux * flux)
        cu = 1.0 + alpha_cu * (th_w - ref)
        saturation = e_sat / (1.0 + 2.718281828459045 ** (-(r - r_sat) / 0.03))
        p_w = (p_dc0 * cu + p_ac0 / cu) * (1.0 + e_cu * (r * r - knee) + saturation)      # eqs. 3-5, load error
        b = flux * (1.0 - c_d * i_d / i_max)
        p_s = (p_h * f + p_e * f * f) * (b * b + c_q * c_q * tau * tau)
        p_s = p_s * (1.0 + a_fe * (0.5 * (th_y + th_t) - ref)) * (1.0 + e_fe * tau)
        k_s = k0 + k1 * r + k2 * w + k3 * r * w                                      # eq. 8
        m = c0 * flux + (1.0 - c0) * r
        p_m_map = mag * w * w * m * m
        p_m = p_m_map * (1.0 + e_pm * p_m_map / mag) / (1.0 + a_pm * (th_m - ref))
        return k_s * p_s, p_w, (1.0 - k_s) * p_s, p_m                               # eqs. 6-7

    return losses


def pv_network(p: LptnParameters, speed_ratio, coolant_c):
    """Vectorized `pv_matrices`, split for the exact step: conductance matrix G (…, 4, 4) with A = C⁻¹G,
    and the yoke-coolant and magnet-ambient conductances g_cy, g_ma (…)."""
    r = varying_resistances(p, speed_ratio, coolant_c)
    g_wm = 1.0 / (r["R_wm1"] + p.a_wm)
    g_tm = 1.0 / (r["R_tm1"] + p.a_tm)
    g_ma = 1.0 / (r["R_ma1"] + p.a_ma)
    g_cy = 1.0 / (p.R_cy0 + r["R_cy01"])
    shape = np.broadcast(g_wm, g_cy).shape
    g = np.zeros(shape + (4, 4))
    for (i, j), gij in {(0, 1): 1 / p.R_yw, (0, 2): 1 / p.R_yt, (1, 2): 1 / p.R_wt,
                        (1, 3): g_wm, (2, 3): g_tm}.items():
        g[..., i, j] = g[..., j, i] = gij
    diag = g.sum(axis=-1)
    diag[..., 0] += g_cy
    diag[..., 3] += g_ma
    idx = np.arange(4)
    g[..., idx, idx] = -diag
    return g, np.broadcast_to(g_cy, shape), np.broadcast_to(g_ma, shape)


def exact_steps(p: LptnParameters, speed_ratio, coolant_c, h: float):
    """Exact discretization over h of the PV network at each (speed ratio, coolant) point.

    A = C⁻¹G with G symmetric, so S = C^-½ G C^-½ is symmetric: one batched eigh gives
    A_d = e^{Ah} and the input integral ∫₀ʰ e^{As} ds exactly. Returns A_d (N,4,4), the loss input
    matrix (N,4,4) and the coolant/ambient input matrix (N,4,2).
    """
    caps = np.array([p.C_y, p.C_w, p.C_t, p.C_m])
    g, g_cy, g_ma = pv_network(p, speed_ratio, coolant_c)
    s = 1.0 / np.sqrt(caps)
    lam, v = np.linalg.eigh(g * s[:, None] * s[None, :])
    e = np.exp(lam * h)
    phi = (e - 1.0) / lam                                    # λ < 0: the network leaks to coolant
    left = s[:, None] * v                                    # C^-½ V
    right = np.swapaxes(v, -1, -2) * (1.0 / s)[None, :]      # Vᵀ C^½
    a_d = (left * e[..., None, :]) @ right
    integral = (left * phi[..., None, :]) @ right
    b_loss = integral / caps[None, None, :]                  # ∫e^{As}ds · C⁻¹
    b_env = np.stack([b_loss[..., :, 0] * g_cy[..., None], b_loss[..., :, 3] * g_ma[..., None]], axis=-1)
    return a_d, b_loss, b_env


@dataclass(frozen=True, eq=False)
class PlantRun:
    """States [yoke, winding, tooth, magnet] (°C) at times k·h, and the node losses of each step (W)."""

    time_s: np.ndarray
    states: np.ndarray
    losses: np.ndarray


def simulate(sequence: DriveProfile, coolant, ambient, t_end: float, x0, h: float = PLANT_STEP_S,
             params: LptnParameters = TABLE1_REFINED, effects: TrueEffects = TRUE_EFFECTS,
             t_start: float = 0.0) -> PlantRun:
    """Integrate the plant from t_start to t_end (a whole number of steps h).

    coolant and ambient are functions of time (vectorized) giving °C; x0 is the state at t_start.
    """
    n = int(round((t_end - t_start) / h))
    if n <= 0 or abs(t_start + n * h - t_end) > 1e-9 * max(1.0, t_end):
        raise ValueError(f"t_end - t_start must be a positive whole number of steps of {h} s")
    spec = sequence.motor
    mid = t_start + (np.arange(n) + 0.5) * h
    torque, speed = sequence.drive(mid)
    li = loss_inputs(spec, torque, speed)
    cool, amb = coolant(mid), ambient(mid)
    a_d, b_loss, b_env = exact_steps(params, li.w, cool, h)
    drift = (b_env @ np.stack([cool, amb], axis=-1)[..., None])[..., 0]
    losses_fn = make_true_losses(spec, effects, params)
    return integrate_exact(a_d, b_loss, drift, (li.i_q, li.i_d, li.tau, li.w, li.f), losses_fn, x0, t_start, h)


def integrate_exact(a_d, b_loss, drift, step_inputs, losses_fn, x0, t_start: float = 0.0,
                    h: float = PLANT_STEP_S) -> PlantRun:
    """The exact-step loop shared by every virtual plant: x ← A_d x + B_loss·P(inputs, x) + drift, per step.

    a_d, b_loss (n, 4, 4) and drift (n, 4) come from `exact_steps` (drift = b_env @ [coolant, ambient]);
    step_inputs is a sequence of n-long arrays, the state-independent loss inputs of each step; losses_fn(*inputs,
    th_y, th_w, th_t, th_m) -> (P_y, P_w, P_t, P_m) at the step's start state (plain-float arithmetic).
    """
    n = len(a_d)
    steps = zip(a_d.reshape(n, 16).tolist(), b_loss.reshape(n, 16).tolist(), drift.tolist(),
                *(np.asarray(v, dtype=float).tolist() for v in step_inputs), strict=True)
    y, w_, t_, m = (float(v) for v in x0)
    states = [(y, w_, t_, m)]
    losses = []
    for a, b, d, *inputs in steps:   # plain floats: ~10 µs a step instead of ~100 with numpy
        py, pw, pt, pm = losses_fn(*inputs, y, w_, t_, m)
        y, w_, t_, m = (
            a[0] * y + a[1] * w_ + a[2] * t_ + a[3] * m + b[0] * py + b[1] * pw + b[2] * pt + b[3] * pm + d[0],
            a[4] * y + a[5] * w_ + a[6] * t_ + a[7] * m + b[4] * py + b[5] * pw + b[6] * pt + b[7] * pm + d[1],
            a[8] * y + a[9] * w_ + a[10] * t_ + a[11] * m + b[8] * py + b[9] * pw + b[10] * pt + b[11] * pm
            + d[2],
            a[12] * y + a[13] * w_ + a[14] * t_ + a[15] * m + b[12] * py + b[13] * pw + b[14] * pt
            + b[15] * pm + d[3],
        )
        states.append((y, w_, t_, m))
        losses.append((py, pw, pt, pm))
    return PlantRun(t_start + np.arange(n + 1) * h, np.array(states), np.array(losses))


def steady_state(params: LptnParameters, node_losses, speed_ratio: float, coolant_c: float,
                 ambient_c: float) -> np.ndarray:
    """Steady temperatures of the PV network for fixed node losses: solve G x + g_ext·ϑ_ext + P = 0."""
    g, g_cy, g_ma = pv_network(params, speed_ratio, coolant_c)
    rhs = -np.asarray(node_losses, dtype=float).copy()
    rhs[0] -= g_cy * coolant_c
    rhs[3] -= g_ma * ambient_c
    return np.linalg.solve(g, rhs)


def simulate_ode(sequence: DriveProfile, coolant, ambient, t_start: int, t_end: int, x0,
                 params: LptnParameters = TABLE1_REFINED, effects: TrueEffects = TRUE_EFFECTS,
                 rtol: float = 1e-10, atol: float = 1e-9) -> PlantRun:
    """Reference solution by an adaptive ODE solver (DOP853), for checking `simulate`.

    Independent of `exact_steps`: the network comes from `pv_matrices` at every evaluation. Torque jumps and
    the stand's signals bend at whole seconds, so the solver restarts there; states are returned at whole
    seconds from t_start to t_end (losses are those at the returned states).
    """
    from scipy.integrate import solve_ivp

    spec = sequence.motor
    losses_fn = make_true_losses(spec, effects, params)

    def rhs(t, x):
        torque, speed = sequence.drive(np.array([t]))
        li = loss_inputs(spec, torque[0], speed[0])
        a, b = pv_matrices(params, float(li.w), float(coolant(t)))
        p = losses_fn(li.i_q, li.i_d, li.tau, li.w, li.f, *x)
        return a @ x + b @ np.array([*p, coolant(t), ambient(t)], dtype=float)

    x = np.asarray(x0, dtype=float)
    states = [x]
    for k in range(int(t_start), int(t_end)):
        # evaluate the right-continuous torque of second k just inside the interval
        sol = solve_ivp(rhs, (k, k + 1), x, method="DOP853", rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(f"ODE solver failed in [{k}, {k + 1}] s: {sol.message}")
        x = sol.y[:, -1]
        states.append(x)
    time_s = np.arange(int(t_start), int(t_end) + 1, dtype=float)
    states = np.array(states)
    torque, speed = sequence.drive(time_s)
    li = loss_inputs(spec, torque, speed)
    losses = np.column_stack(losses_fn(li.i_q, li.i_d, li.tau, li.w, li.f, *states.T))
    return PlantRun(time_s, states, losses)
