"""Virtual motors described by a motor file: `bench data --motor FILE` simulates the file's `virtual_plant`.

The built-in 200 kW machine (bench.drive.generate) is hard-wired; this module turns any motor file with a
`virtual_plant` table and an electrical loss model into a set of measurement files of the kind a user brings:
the motor's own column names and units, no time column, a sample period of its own. The examples/motor-ipm
motor is one.

Schema of `virtual_plant` (version 1; every key required unless marked optional):

    schema_version = 1                      # optional
    seed = 20260                            # the default noise seed of 'bench data --motor'
    sample_period_s = 1.0                   # the files' sample period
    plant_step_s = 0.1                      # integration step; a whole fraction of the sample period
    [thermal]                               # the TRUE 22 LPTN parameters of the plant (the parameter-varying
                                            #   network of paper Fig. 4, speed ratio n / limits.speed_rpm)
    [machine]                               # steady-state dq model of an interior-PM machine
    power_W, flux_linkage_Vs (ψ at copper_reference_C), L_d_H < L_q_H (saliency: i_d < 0 adds reluctance
    torque), voltage_limit_V (largest |u_dq|, amplitude-invariant), remanence_per_K (ψ(ϑ_m) = ψ·(1 + α(ϑ_m -
    ϑ_ref))); the machine must reach the whole envelope min(limits.torque_Nm, power_W/ω) within limits.current_A
    with the magnet at ϑ_ref and 100 K hotter
    [true_losses]                           # what the real machine does beyond the file's [losses] model
    resistance_factor, ac_factor, ac_magnet_W, copper_load_error, iron_factor, iron_per_K, magnet_factor,
    magnet_load_error, magnet_resistivity_per_K
    [vehicle]                               # bench.drive.vehicle.VehicleSpec's fields (cycles -> torque, speed)
    [stand]                                 # coolant conditioning and test-cell air (StandSpec below)
    [[columns]]                             # the output columns, in file order
    name, signal (torque, speed, i_d, i_q, u_d, u_q, coolant, ambient, winding, yoke, tooth, magnet),
    unit (any unit bench.drive.dataset's loader converts for that quantity), resolution, noise (1 σ, in the
    column's unit), gradient (optional, winding only: the sensor reads ϑ_w + gradient·(ϑ_w - ϑ_y))
    [[profiles]]                            # the measurement runs
    name, role ("train" or "validate": a suggestion), coolant_C (set point at the start; the machine starts
    soaked at it), phases: a list of
      {"kind": "cycle", "cycle": "ftp75"|"wltc3b", "from_s", "to_s" (optional: a segment that starts and
       ends at standstill), "speed_scale" (optional, default 1)}
      {"kind": "constant", "torque_Nm", "speed_rpm", "duration_s", "ramp_s" (optional, 20)}
      {"kind": "steps", "points": [[torque_Nm, speed_rpm, hold_s], ...], "ramp_s" (optional, 5),
       "repeat" (optional, 1)}: linear ramps between the points, from and back to standstill
      {"kind": "rest", "duration_s"}: standstill
    and on any phase "coolant_C" (optional): the coolant set point from that phase on.

The physics (`VirtualPlant.simulate`):
- torque -> currents: maximum torque per ampere (i_d < 0, magnet plus reluctance torque), then field weakening
  along the constant-torque curve once |u_dq| would exceed voltage_limit_V; the torque is clamped to
  min(T_peak, P/ω). A hotter magnet has less flux, so the same torque takes more current (linear in ϑ_m
  between the currents at ϑ_ref and ϑ_ref + 100 K; the controller uses the winding resistance at ϑ_ref, so a hot
  winding may overshoot the voltage limit by about 1 %). u_d = R i_d - ω L_q i_q, u_q = R i_q + ω (ψ + L_d i_d)
  with the winding's resistance at its temperature.
- true losses: the file's electrical loss model on the true currents, with the differences a designer's model
  misses: winding resistance × resistance_factor; ac copper with ac_factor instead of the nominal one plus
  ac_magnet_W·(f/f_ac)² of strand eddy losses from the magnet field (current-independent); copper × (1 +
  copper_load_error·(I/I_max)²) (PWM ripple, end windings); iron loss × iron_factor scaled by the stator flux
  linkage squared, |ψ_s|²/ψ² (field weakening lowers it, load raises it: the nominal model's
  (1 + c_I (I/I_max)²) only approximates that) and × (1 + iron_per_K·(ϑ_iron - ϑ_ref)); magnet loss
  × magnet_factor with the no-load part following the magnet flux, × (1 + magnet_load_error·P_m/P_m,ref)
  ÷ (1 + magnet_resistivity_per_K·(ϑ_m - ϑ_ref)). Copper dc/ac temperature dependence as eqs. 3-5, the
  stator split k_s of eq. 8 with the TRUE k parameters.
- thermal: the parameter-varying LPTN integrated exactly (bench.drive.plant.exact_steps/integrate_exact) with
  torque, speed, coolant and ambient at each step's midpoint and the losses at its start.
- stand: the coolant inlet follows its set point through a first-order lag (coolant_lag_s), rises by
  coolant_gain_K_per_kW times the lagged nominal losses and wanders (AR(1)); the test-cell air likewise.
- initial state: every node at the profile's first coolant set point (the machine soaked).
- sensors: each column is the true signal at the sample time, converted to its unit, plus Gaussian noise
  (none on speed at standstill), rounded to its resolution. One numpy Generator per profile and purpose, from
  SeedSequence([seed, profile number]), so a seed reproduces every byte.

Every problem with the table is one VirtualPlantError sentence naming the file and the key.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from bench.drive.cycles import CHECKS as CYCLE_CHECKS
from bench.drive.cycles import KMH_PER_MPS, load_trace
from bench.drive.dataset import BY_NAME, UNITS
from bench.drive.motor import RPM_PER_RAD_S
from bench.drive.plant import exact_steps, integrate_exact
from bench.drive.stand import _lowpass, _wander
from bench.drive.vehicle import VehicleSpec, motor_speed_rpm, motor_torque_Nm
from bench.fileio import write_bytes_atomically
from bench.motor.description import MotorDescription, prior_parameters
from bench.motor.errors import MotorFileError
from bench.motor.losses import ElectricalLosses
from bench.thermal.parameters import LptnParameters

SCHEMA_VERSION = 1
# Bump when anything that changes the generated numbers changes.
GENERATOR_VERSION = "1.0.0"
INDEX_NAME = "profiles.json"
ROLES = ("train", "validate")
PHASE_KINDS = ("cycle", "constant", "steps", "rest")
TOP_KEYS = ("schema_version", "seed", "sample_period_s", "plant_step_s", "thermal", "machine", "true_losses",
            "vehicle", "stand", "columns", "profiles")
# output signal -> the schema column whose quantity (and so unit list) it has
SIGNALS = {"torque": "torque_Nm", "speed": "speed_rpm", "i_d": "i_d_A", "i_q": "i_q_A", "u_d": "u_d_V",
           "u_q": "u_q_V", "coolant": "coolant_C", "ambient": "ambient_C", "winding": "winding_C",
           "yoke": "yoke_C", "tooth": "tooth_C", "magnet": "pm_C"}
# what the bench needs to identify an electrical-loss motor from the files
REQUIRED_SIGNALS = ("torque", "speed", "i_d", "i_q", "coolant", "ambient", "winding", "magnet")
FLUX_PROBE_K = 100.0   # currents are computed at ϑ_ref and ϑ_ref + this, and interpolated linearly in ϑ_m


class VirtualPlantError(MotorFileError):
    """A motor file's virtual_plant table that bench data cannot simulate."""


@dataclass(frozen=True)
class Machine:
    power_W: float
    flux_linkage_Vs: float
    L_d_H: float
    L_q_H: float
    voltage_limit_V: float
    remanence_per_K: float


@dataclass(frozen=True)
class TrueLosses:
    resistance_factor: float
    ac_factor: float
    ac_magnet_W: float
    copper_load_error: float
    iron_factor: float
    iron_per_K: float
    magnet_factor: float
    magnet_load_error: float
    magnet_resistivity_per_K: float


@dataclass(frozen=True)
class StandSpec:
    coolant_lag_s: float              # conditioning unit: first-order lag to a new set point
    coolant_gain_K_per_kW: float      # the inlet rises with the heat the motor rejects ...
    coolant_heat_lag_s: float         # ... after this lag
    coolant_wander_K: float
    coolant_wander_s: float
    ambient_C: float
    ambient_per_coolant_K: float      # warm pipes: per K of coolant set point above 20 °C
    ambient_wander_K: float
    ambient_wander_s: float


@dataclass(frozen=True)
class OutputColumn:
    name: str
    signal: str
    unit: str
    resolution: float
    noise: float
    gradient: float = 0.0

    @property
    def decimals(self) -> int:
        return max(0, -math.floor(math.log10(self.resolution) + 1e-9))

    def from_internal(self, values: np.ndarray) -> np.ndarray:
        """Internal unit (°C, rpm, Nm, A, V) -> this column's unit (the loader's conversion, inverted)."""
        scale, offset = UNITS[BY_NAME[SIGNALS[self.signal]].quantity][self.unit]
        return (np.asarray(values, dtype=float) - offset) / scale


@dataclass(frozen=True)
class Phase:
    kind: str
    duration_s: float
    coolant_C: float | None
    spec: dict                         # the phase as given (for the index), defaults filled in
    cycle: str | None = None
    from_s: float = 0.0
    speed_scale: float = 1.0
    ramp_s: float = 0.0
    points: tuple[tuple[float, float, float], ...] = ()   # (torque, speed, hold) for constant/steps/rest


@dataclass(frozen=True)
class Profile:
    number: int                        # 1-based position in the file: part of the noise seed
    name: str
    role: str
    coolant_C: float
    phases: tuple[Phase, ...]

    @property
    def duration_s(self) -> float:
        return float(sum(p.duration_s for p in self.phases))

    @property
    def starts_s(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum([p.duration_s for p in self.phases])])

    @property
    def setpoints_C(self) -> list[float]:
        out = [self.coolant_C]
        for p in self.phases:
            if p.coolant_C is not None and p.coolant_C != out[-1]:
                out.append(p.coolant_C)
        return out

    @property
    def filename(self) -> str:
        return f"{self.name}.csv"


# ---------------------------------------------------------------- the dq machine


@dataclass(frozen=True)
class DqModel:
    """Torque -> (i_d, i_q) and voltages of an interior-PM machine (amplitude-invariant dq quantities)."""

    pole_pairs: int
    torque_max_Nm: float
    speed_max_rpm: float
    current_max_A: float
    machine: Machine

    def torque_limit(self, speed_rpm) -> np.ndarray:
        omega = np.maximum(np.abs(np.asarray(speed_rpm, dtype=float)), 1e-9) / RPM_PER_RAD_S
        return np.minimum(self.torque_max_Nm, self.machine.power_W / omega)

    def _mtpa(self, torque, psi):
        """MTPA currents for |torque| by bisection on the current amplitude; torque per MTPA amplitude grows."""
        m = self.machine
        dl, k = m.L_q_H - m.L_d_H, 1.5 * self.pole_pairs
        lo, hi = np.zeros_like(torque), np.full_like(torque, 2.0 * self.current_max_A)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            i_d = (psi - np.sqrt(psi * psi + 8.0 * dl * dl * mid * mid)) / (4.0 * dl)
            i_q = np.sqrt(np.maximum(mid * mid - i_d * i_d, 0.0))
            low = k * i_q * (psi - dl * i_d) < torque
            lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
        amp = 0.5 * (lo + hi)
        i_d = (psi - np.sqrt(psi * psi + 8.0 * dl * dl * amp * amp)) / (4.0 * dl)
        return i_d, np.sqrt(np.maximum(amp * amp - i_d * i_d, 0.0))

    def _voltage(self, i_d, i_q, omega_e, psi, resistance):
        m = self.machine
        u_d = resistance * i_d - omega_e * m.L_q_H * i_q
        u_q = resistance * i_q + omega_e * (psi + m.L_d_H * i_d)
        return u_d, u_q

    def currents(self, torque, speed_rpm, flux_ratio=1.0, resistance: float = 0.0):
        """(i_d, i_q, feasible): MTPA, field weakening above the voltage limit; vectorized.

        flux_ratio: the magnet's flux relative to flux_linkage_Vs. feasible is False where the torque needs more
        than limits.current_A or cannot be reached within the voltage limit.
        """
        m = self.machine
        torque, speed = np.broadcast_arrays(np.asarray(torque, dtype=float), np.asarray(speed_rpm, dtype=float))
        psi = m.flux_linkage_Vs * np.broadcast_to(np.asarray(flux_ratio, dtype=float), torque.shape)
        t_abs = np.abs(torque)
        omega_e = self.pole_pairs * np.abs(speed) / RPM_PER_RAD_S
        i_d, i_q = self._mtpa(t_abs, psi)
        u_d, u_q = self._voltage(i_d, i_q, omega_e, psi, resistance)
        weaken = np.hypot(u_d, u_q) > m.voltage_limit_V
        feasible = np.ones(torque.shape, dtype=bool)
        if weaken.any():
            dl, k = m.L_q_H - m.L_d_H, 1.5 * self.pole_pairs
            p, t, w = psi[weaken], t_abs[weaken], omega_e[weaken]
            hi = i_d[weaken]                      # |u| too high here
            lo = -p / m.L_d_H                     # ψ_d = 0: the deepest useful field weakening

            def volts(d):
                q = t / (k * (p - dl * d))
                ud, uq = self._voltage(d, q, w, p, resistance)
                return np.hypot(ud, uq), q

            feasible[weaken] = volts(lo)[0] <= m.voltage_limit_V
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                too_high = volts(mid)[0] > m.voltage_limit_V
                hi, lo = np.where(too_high, mid, hi), np.where(too_high, lo, mid)
            d = np.where(feasible[weaken], lo, hi)
            i_d = i_d.copy()
            i_q = i_q.copy()
            i_d[weaken], i_q[weaken] = d, volts(d)[1]
        feasible &= np.hypot(i_d, i_q) <= self.current_max_A * (1.0 + 1e-6)
        return i_d, np.sign(torque) * i_q, feasible

    def voltages(self, i_d, i_q, speed_rpm, flux_ratio, resistance):
        omega_e = self.pole_pairs * np.asarray(speed_rpm, dtype=float) / RPM_PER_RAD_S
        return self._voltage(np.asarray(i_d, float), np.asarray(i_q, float), omega_e,
                             self.machine.flux_linkage_Vs * np.asarray(flux_ratio, dtype=float),
                             np.asarray(resistance, dtype=float))


# ---------------------------------------------------------------- the plant


@dataclass(frozen=True, eq=False)
class VirtualPlant:
    """A motor file's virtual_plant, read and checked (`virtual_plant(motor)`)."""

    motor: MotorDescription
    seed: int
    sample_period_s: float
    plant_step_s: float
    params: LptnParameters
    machine: Machine
    true_losses: TrueLosses
    vehicle: VehicleSpec
    stand: StandSpec
    columns: tuple[OutputColumn, ...]
    profiles: tuple[Profile, ...]

    @property
    def nominal(self) -> ElectricalLosses:
        return self.motor.loss_model

    @property
    def dq(self) -> DqModel:
        lim = self.motor.limits
        return DqModel(self.motor.pole_pairs, lim.torque_Nm, lim.speed_rpm, lim.current_A, self.machine)

    def profile(self, name: str) -> Profile:
        for p in self.profiles:
            if p.name == name:
                return p
        raise VirtualPlantError(f"motor {self.motor.name!r} has no profile {name!r}; its profiles are "
                                f"{', '.join(p.name for p in self.profiles)}")

    # ------------------------------------------------ drive
    def drive(self, profile: Profile, t) -> tuple[np.ndarray, np.ndarray]:
        """(torque Nm, speed rpm) at times t (s), vectorized; torque clamped to the envelope."""
        t = np.asarray(t, dtype=float)
        torque, speed = np.zeros_like(t), np.zeros_like(t)
        starts = profile.starts_s
        which = np.clip(np.searchsorted(starts[1:-1], t, side="right"), 0, len(profile.phases) - 1)
        for k, phase in enumerate(profile.phases):
            sel = which == k
            if not np.any(sel):
                continue
            local = t[sel] - starts[k]
            if phase.kind == "cycle":
                torque[sel], speed[sel] = self._cycle(phase, local)
            else:
                torque[sel], speed[sel] = _piecewise(phase, local)
        limit = self.dq.torque_limit(speed)
        return np.clip(torque, -limit, limit), speed

    def _cycle(self, phase: Phase, local):
        trace = load_trace(phase.cycle)
        v = trace.speed_kmh / KMH_PER_MPS * phase.speed_scale
        at = phase.from_s + local
        v_t = np.interp(at, trace.time_s, v)
        second = np.clip(np.floor(at).astype(int), 0, len(v) - 2)
        accel = np.where(local < phase.duration_s, v[second + 1] - v[second], 0.0)   # right-continuous
        return motor_torque_Nm(self.vehicle, v_t, accel), motor_speed_rpm(self.vehicle, v_t)

    # ------------------------------------------------ stand
    def setpoint(self, profile: Profile, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        out = np.full_like(t, profile.coolant_C)
        for start, phase in zip(profile.starts_s, profile.phases, strict=False):
            if phase.coolant_C is not None:
                out = np.where(t >= start, phase.coolant_C, out)
        return out

    def environment(self, profile: Profile, rng: np.random.Generator):
        """Coolant inlet and test-cell air on a 1 s grid -> (coolant(t), ambient(t)) interpolating functions."""
        s = self.stand
        t = np.arange(0.0, np.ceil(profile.duration_s) + 2.0)
        torque, speed = self.drive(profile, t + 0.5)
        i_d, i_q, _ = self.dq.currents(torque, speed)
        nominal = self.nominal.evaluate_columns({"speed_rpm": speed, "i_d_A": i_d, "i_q_A": i_q})
        total_kW = (nominal["p_dc0"] + nominal["p_ac0"] + nominal["p_stator"] + nominal["p_magnet"]) / 1000.0
        setpoint = self.setpoint(profile, t)
        coolant = (_lowpass(setpoint, s.coolant_lag_s, profile.coolant_C)
                   + s.coolant_gain_K_per_kW * _lowpass(total_kW, s.coolant_heat_lag_s, 0.0)
                   + _wander(rng, len(t), s.coolant_wander_K, s.coolant_wander_s))
        ambient = (s.ambient_C + s.ambient_per_coolant_K * (setpoint - 20.0)
                   + _wander(rng, len(t), s.ambient_wander_K, s.ambient_wander_s))
        return (lambda x: np.interp(x, t, coolant)), (lambda x: np.interp(x, t, ambient))

    # ------------------------------------------------ losses
    def operating_point(self, torque, speed_rpm) -> dict[str, np.ndarray]:
        """Currents at ϑ_ref and their change per K of magnet temperature, plus the frequency ratios."""
        dq, rem = self.dq, self.machine.remanence_per_K
        r_s = self.nominal.stator_resistance_ohm * self.true_losses.resistance_factor   # at ϑ_ref
        i_d0, i_q0, ok0 = dq.currents(torque, speed_rpm, 1.0, r_s)
        i_d1, i_q1, ok1 = dq.currents(torque, speed_rpm, 1.0 + rem * FLUX_PROBE_K, r_s)
        if not (ok0.all() and ok1.all()):
            bad = int(np.argmax(~(ok0 & ok1)))
            raise VirtualPlantError(
                f"{self._where}: the machine cannot produce {float(np.ravel(torque)[bad]):.1f} Nm at "
                f"{float(np.ravel(speed_rpm)[bad]):.0f} rpm within limits.current_A and "
                "virtual_plant.machine.voltage_limit_V; raise them or lower the envelope")
        f = self.motor.pole_pairs * np.abs(np.asarray(speed_rpm, dtype=float)) / 60.0
        nom = self.nominal
        return {"i_d0": i_d0, "i_q0": i_q0, "di_d": (i_d1 - i_d0) / FLUX_PROBE_K,
                "di_q": (i_q1 - i_q0) / FLUX_PROBE_K, "x_ac": f / nom.ac_reference_Hz,
                "x_fe": f / nom.iron_reference_Hz, "x_m": f / nom.magnet_reference_Hz,
                "w": np.abs(np.asarray(speed_rpm, dtype=float)) / self.motor.limits.speed_rpm}

    def loss_function(self) -> Callable:
        """losses(i_d0, i_q0, di_d, di_q, x_ac, x_fe, x_m, w, ϑ_y, ϑ_w, ϑ_t, ϑ_m) -> (P_y, P_w, P_t, P_m).

        Arithmetic operators only, so it runs on floats (the plant loop) and on arrays alike.
        """
        nom, tl, mach, p = self.nominal, self.true_losses, self.machine, self.params
        ref, alpha = self.motor.copper_reference_C, self.motor.copper_alpha_per_K
        i_max = self.motor.limits.current_A
        r15 = 1.5 * nom.stator_resistance_ohm * tl.resistance_factor
        k_ac, ac_pm = tl.ac_factor, tl.ac_magnet_W
        e_cu, rem = tl.copper_load_error, mach.remanence_per_K
        p_h, p_e = nom.iron_hysteresis_W * tl.iron_factor, nom.iron_eddy_W * tl.iron_factor
        a_fe, psi0, l_d, l_q = tl.iron_per_K, mach.flux_linkage_Vs, mach.L_d_H, mach.L_q_H
        mag, c0 = nom.magnet_W * tl.magnet_factor, nom.magnet_no_load_share
        e_pm, a_pm = tl.magnet_load_error, tl.magnet_resistivity_per_K
        k0, k1, k2, k3 = p.k_0, p.k_1, p.k_2, p.k_3

        def losses(i_d0, i_q0, di_d, di_q, x_ac, x_fe, x_m, w, th_y, th_w, th_t, th_m):
            dm = th_m - ref
            flux = 1.0 + rem * dm
            i_d = i_d0 + di_d * dm
            i_q = i_q0 + di_q * dm
            i2 = i_d * i_d + i_q * i_q
            r = i2 ** 0.5 / i_max
            cu = 1.0 + alpha * (th_w - ref)
            p_dc0 = r15 * i2
            p_ac0 = x_ac * x_ac * (k_ac * p_dc0 + ac_pm * flux * flux)
            p_w = (p_dc0 * cu + p_ac0 / cu) * (1.0 + e_cu * r * r)
            psi_d = (psi0 * flux + l_d * i_d) / psi0
            psi_q = l_q * i_q / psi0
            p_s = (p_h * x_fe + p_e * x_fe * x_fe) * (psi_d * psi_d + psi_q * psi_q)
            p_s = p_s * (1.0 + a_fe * (0.5 * (th_y + th_t) - ref))
            k_s = k0 + k1 * r + k2 * w + k3 * r * w
            m = c0 * flux + (1.0 - c0) * r
            p_m_map = mag * x_m * x_m * m * m
            p_m = p_m_map * (1.0 + e_pm * p_m_map / mag) / (1.0 + a_pm * dm)
            return k_s * p_s, p_w, (1.0 - k_s) * p_s, p_m

        return losses

    # ------------------------------------------------ one profile
    def simulate(self, profile: Profile, seed: int | None = None) -> VirtualRun:
        """The profile's true signals at the sample times and the measured columns (in the columns' units)."""
        seed = self.seed if seed is None else seed
        env_ss, sensor_ss = np.random.SeedSequence([int(seed), profile.number]).spawn(2)
        coolant, ambient = self.environment(profile, np.random.default_rng(env_ss))
        h, period = self.plant_step_s, self.sample_period_s
        n = int(round(profile.duration_s / h))
        mid = (np.arange(n) + 0.5) * h
        torque, speed = self.drive(profile, mid)
        op = self.operating_point(torque, speed)
        cool, amb = coolant(mid), ambient(mid)
        a_d, b_loss, b_env = exact_steps(self.params, op["w"], cool, h)
        drift = (b_env @ np.stack([cool, amb], axis=-1)[..., None])[..., 0]
        inputs = tuple(op[k] for k in ("i_d0", "i_q0", "di_d", "di_q", "x_ac", "x_fe", "x_m", "w"))
        run = integrate_exact(a_d, b_loss, drift, inputs, self.loss_function(), [profile.coolant_C] * 4, 0.0, h)
        stride = int(round(period / h))
        rows = int(round(profile.duration_s / period)) + 1
        t = np.arange(rows) * period
        states = run.states[::stride][:rows]
        truth = self.truth_at(profile, t, states, coolant(t), ambient(t))
        measured = self.measure(truth, np.random.default_rng(sensor_ss))
        return VirtualRun(profile, int(seed), t, truth, measured, run.losses[::stride])

    def truth_at(self, profile: Profile, t, states, coolant, ambient) -> dict[str, np.ndarray]:
        torque, speed = self.drive(profile, t)
        op = self.operating_point(torque, speed)
        ref = self.motor.copper_reference_C
        dm = states[:, 3] - ref
        i_d, i_q = op["i_d0"] + op["di_d"] * dm, op["i_q0"] + op["di_q"] * dm
        flux = 1.0 + self.machine.remanence_per_K * dm
        resistance = (self.nominal.stator_resistance_ohm * self.true_losses.resistance_factor
                      * (1.0 + self.motor.copper_alpha_per_K * (states[:, 1] - ref)))
        u_d, u_q = self.dq.voltages(i_d, i_q, speed, flux, resistance)
        return {"torque": torque, "speed": speed, "i_d": i_d, "i_q": i_q, "u_d": u_d, "u_q": u_q,
                "coolant": coolant, "ambient": ambient, "yoke": states[:, 0], "winding": states[:, 1],
                "tooth": states[:, 2], "magnet": states[:, 3]}

    def measure(self, truth: dict[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
        """One noise block per column, in file order; noise and rounding in the column's unit."""
        out = {}
        for col in self.columns:
            x = np.asarray(truth[col.signal], dtype=float)
            if col.gradient:
                x = x + col.gradient * (x - truth["yoke"])
            x = col.from_internal(x)
            noise = rng.standard_normal(x.shape) * col.noise
            if col.signal == "speed":
                noise = np.where(truth["speed"] != 0, noise, 0.0)
            out[col.name] = np.round((x + noise) / col.resolution) * col.resolution + 0.0
        return out

    def csv_bytes(self, measured: dict[str, np.ndarray]) -> bytes:
        names = [c.name for c in self.columns]
        fmt = ",".join(f"%.{c.decimals}f" for c in self.columns)
        out = io.StringIO()
        out.write(",".join(names) + "\n")
        np.savetxt(out, np.column_stack([measured[n] for n in names]), fmt=fmt, delimiter=",", newline="\n")
        return out.getvalue().encode("ascii")

    @property
    def _where(self) -> str:
        return f"motor file {self.motor.path}" if self.motor.path else f"motor {self.motor.name!r}"


@dataclass(frozen=True, eq=False)
class VirtualRun:
    profile: Profile
    seed: int
    time_s: np.ndarray
    truth: dict[str, np.ndarray]       # internal units (°C, rpm, Nm, A, V)
    measured: dict[str, np.ndarray]    # by output column name, in the columns' units
    losses: np.ndarray                 # (rows - 1, 4) node losses of the step starting at each sample (W)

    def rise_K(self) -> dict[str, float]:
        cool = self.truth["coolant"]
        return {node: round(float((self.truth[node] - cool).max()), 2) for node in ("winding", "magnet")}


def _piecewise(phase: Phase, local):
    """constant/steps/rest: linear ramps of phase.ramp_s from standstill through the points and back."""
    knots_t, knots_T, knots_n = [0.0], [0.0], [0.0]
    t = 0.0
    for torque, speed, hold in phase.points:
        t += phase.ramp_s
        knots_t += [t, t + hold]
        knots_T += [torque, torque]
        knots_n += [speed, speed]
        t += hold
    knots_t.append(t + phase.ramp_s)
    knots_T.append(0.0)
    knots_n.append(0.0)
    return np.interp(local, knots_t, knots_T), np.interp(local, knots_t, knots_n)


# ---------------------------------------------------------------- generating files


def generate_profiles(plant: VirtualPlant, out_dir: Path, seed: int | None = None, names=None,
                      progress: Callable[[Profile, VirtualRun, float], None] | None = None) -> dict:
    """Simulate the profiles (all, or those named), write each CSV atomically and then DIR/profiles.json.

    Returns the index (what profiles.json holds). It lists the profiles written now and, when only some were
    asked for, those an earlier run of the same motor file, generator and seed left in DIR unchanged.
    """
    import time

    out_dir = Path(out_dir)
    seed = plant.seed if seed is None else int(seed)
    if seed < 0:
        raise ValueError("the seed must be a non-negative integer")
    profiles = plant.profiles if names is None else tuple(plant.profile(n) for n in names)
    entries = []
    for profile in profiles:
        started = time.perf_counter()
        run = plant.simulate(profile, seed)
        payload = plant.csv_bytes(run.measured)
        write_bytes_atomically(out_dir / profile.filename, payload)
        entries.append(_index_entry(plant, profile, run, hashlib.sha256(payload).hexdigest()))
        if progress is not None:
            progress(profile, run, time.perf_counter() - started)
    if names is not None:
        entries = _kept_entries(plant, out_dir, seed, entries)
    index = {
        "generator": "bench.drive.virtual", "generator_version": GENERATOR_VERSION, "seed": seed,
        "motor": {"name": plant.motor.name, "file": plant.motor.path.name if plant.motor.path else None,
                  "sha256": plant.motor.sha256},
        "sample_period_s": plant.sample_period_s, "time_column": None,
        "initial_state": "all nodes at the profile's first coolant set point",
        "columns": [{"name": c.name, "signal": c.signal, "unit": c.unit, "resolution": c.resolution,
                     "noise": c.noise} for c in plant.columns],
        "profiles": entries,
        "roles": {role: [e["file"] for e in entries if e["role"] == role] for role in ROLES},
    }
    text = json.dumps(index, indent=2, ensure_ascii=False) + "\n"
    write_bytes_atomically(out_dir / INDEX_NAME, text.encode("utf-8"))
    return index


def _kept_entries(plant: VirtualPlant, out_dir: Path, seed: int, written: list[dict]) -> list[dict]:
    """written plus the entries of an existing index of the same motor, generator and seed whose files are still
    as written, in the motor file's profile order."""
    try:
        old = json.loads((out_dir / INDEX_NAME).read_text(encoding="utf-8"))
        same = (old.get("generator_version") == GENERATOR_VERSION and old.get("seed") == seed
                and old.get("motor", {}).get("sha256") == plant.motor.sha256)
        previous = {e["name"]: e for e in old.get("profiles", [])} if same else {}
    except (OSError, ValueError, AttributeError, KeyError, TypeError):
        previous = {}
    by_name = {e["name"]: e for e in written}
    out = []
    for profile in plant.profiles:
        entry = by_name.get(profile.name) or previous.get(profile.name)
        if entry is None:
            continue
        if profile.name not in by_name:
            try:
                if hashlib.sha256((out_dir / profile.filename).read_bytes()).hexdigest() != entry.get("sha256"):
                    continue
            except OSError:
                continue
        out.append(entry)
    return out


def _index_entry(plant: VirtualPlant, profile: Profile, run: VirtualRun, sha: str) -> dict:
    phases, starts = [], profile.starts_s
    for k, phase in enumerate(profile.phases):
        phases.append({**phase.spec, "start_s": float(starts[k]), "end_s": float(starts[k + 1])})
    torque, speed = run.truth["torque"], run.truth["speed"]
    power = torque * speed / RPM_PER_RAD_S
    return {"name": profile.name, "file": profile.filename, "sha256": sha, "role": profile.role,
            "rows": len(run.time_s), "duration_s": profile.duration_s,
            "coolant_setpoint_C": profile.coolant_C, "coolant_setpoints_C": profile.setpoints_C,
            "phases": phases,
            "true_max_rise_above_coolant_K": run.rise_K(),
            "true_range_C": {n: [round(float(run.truth[n].min()), 2), round(float(run.truth[n].max()), 2)]
                             for n in ("coolant", "winding", "magnet")},
            "peak": {"torque_Nm": round(float(np.abs(torque).max()), 1),
                     "speed_rpm": round(float(speed.max()), 0), "power_kW": round(float(power.max()) / 1e3, 1),
                     "current_A": round(float(np.hypot(run.truth["i_d"], run.truth["i_q"]).max()), 1)}}


# ---------------------------------------------------------------- reading and checking the table


def virtual_plant(motor: MotorDescription) -> VirtualPlant:
    """The motor's virtual_plant, checked; VirtualPlantError (one sentence) on the first problem."""
    where = f"motor file {motor.path}" if motor.path else f"motor {motor.name!r}"
    table = motor.virtual_plant
    if table is None:
        raise VirtualPlantError(f"{where} describes no virtual plant; bench data only generates data for virtual "
                                "motors (without --motor it writes the built-in motor's datasets)")
    if not isinstance(motor.loss_model, ElectricalLosses):
        raise VirtualPlantError(f"{where}: a virtual plant needs losses.kind = \"electrical\" (its data carry the "
                                "d/q currents the losses are computed from)")
    c = _Check(where)
    c.only(table, "virtual_plant", TOP_KEYS)
    version = table.get("schema_version", SCHEMA_VERSION)
    if type(version) is not int or version != SCHEMA_VERSION:
        raise VirtualPlantError(f"{where}: virtual_plant.schema_version {version!r} is not supported (this bench "
                                f"reads {SCHEMA_VERSION})")
    seed = table.get("seed")
    if type(seed) is not int or seed < 0:
        raise VirtualPlantError(f"{where}: virtual_plant.seed must be a non-negative whole number, not {seed!r}")
    period = c.number(table, "sample_period_s", low=0.01, high=60.0)
    step = c.number(table, "plant_step_s", low=0.001, high=10.0)
    stride = period / step
    if abs(stride - round(stride)) > 1e-9 * stride:
        raise VirtualPlantError(f"{where}: virtual_plant.sample_period_s ({period:g} s) must be a whole number of "
                                f"plant_step_s ({step:g} s)")
    try:
        params, _ = prior_parameters(c.table(table, "thermal"), f"{where}: virtual_plant.thermal")
    except VirtualPlantError:
        raise
    except MotorFileError as exc:
        raise VirtualPlantError(str(exc)) from None
    machine = Machine(**_numbers(c, table, "machine", Machine, signed=("remanence_per_K",)))
    if machine.L_q_H <= machine.L_d_H:
        raise VirtualPlantError(f"{where}: virtual_plant.machine.L_q_H must exceed L_d_H (an interior-PM machine: "
                                "i_d < 0 adds reluctance torque)")
    if not -0.01 <= machine.remanence_per_K <= 0.0:
        raise VirtualPlantError(f"{where}: virtual_plant.machine.remanence_per_K = {machine.remanence_per_K:g} "
                                "must be from -0.01 to 0 (NdFeB: about -0.0012)")
    true_losses = TrueLosses(**_numbers(c, table, "true_losses", TrueLosses,
                                        signed=("iron_per_K", "copper_load_error", "magnet_load_error"),
                                        positive=("resistance_factor", "iron_factor", "magnet_factor")))
    vehicle = _vehicle(c, table)
    stand = StandSpec(**_numbers(c, table, "stand", StandSpec, signed=("ambient_C", "ambient_per_coolant_K"),
                                 positive=("coolant_lag_s", "coolant_heat_lag_s", "coolant_wander_s",
                                           "ambient_wander_s")))
    columns = _columns(c, table)
    plant = VirtualPlant(motor, seed, period, step, params, machine, true_losses, vehicle, stand, columns, ())
    profiles = _profiles(c, table, plant)
    plant = VirtualPlant(motor, seed, period, step, params, machine, true_losses, vehicle, stand, columns,
                         profiles)
    _check_envelope(plant)
    return plant


class _Check:
    def __init__(self, where: str):
        self.where = where

    def fail(self, key: str, what: str):
        raise VirtualPlantError(f"{self.where}: virtual_plant.{key} {what}")

    def table(self, content: dict, key: str, prefix: str = "") -> dict:
        value = content.get(key)
        if not isinstance(value, dict):
            self.fail(prefix + key, "is missing or not a table; see examples/motor-ipm/motor.json")
        return value

    def only(self, table: dict, name: str, keys) -> None:
        unknown = [k for k in table if k not in keys]
        if unknown:
            raise VirtualPlantError(f"{self.where}: {name}.{unknown[0]} is not a known key (known: "
                                    f"{', '.join(keys)})")

    def number(self, content: dict, key: str, prefix: str = "", *, low=None, high=None, positive=False,
               default=None) -> float:
        value = content.get(key, default)
        if value is None:
            self.fail(prefix + key, "is missing")
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            self.fail(prefix + key, f"must be a finite number, not {value!r}")
        value = float(value)
        if positive and value <= 0:
            self.fail(prefix + key, f"must be positive, not {value:g}")
        if (low is not None and value < low) or (high is not None and value > high):
            span = (f"from {low:g} to {high:g}" if high is not None and low is not None
                    else f"at least {low:g}" if low is not None else f"at most {high:g}")
            self.fail(prefix + key, f"= {value:g} must be {span}")
        return value


def _numbers(c: _Check, table: dict, key: str, cls, signed=(), positive=None) -> dict[str, float]:
    """All fields of dataclass cls from table[key]: numbers >= 0 (> 0 if in positive; any sign if signed)."""
    sub = c.table(table, key)
    names = [f.name for f in fields(cls)]
    c.only(sub, f"virtual_plant.{key}", names)
    positive = names if positive is None else positive
    out = {}
    for name in names:
        if name in signed:
            out[name] = c.number(sub, name, f"{key}.")
        else:
            out[name] = c.number(sub, name, f"{key}.", positive=name in positive, low=0.0)
    return out


def _vehicle(c: _Check, table: dict) -> VehicleSpec:
    sub = c.table(table, "vehicle")
    names = [f.name for f in fields(VehicleSpec)]
    c.only(sub, "virtual_plant.vehicle", names)
    values = {}
    for name in names:
        if name == "regen_fade_kmh":
            fade = sub.get(name)
            ok = (isinstance(fade, list) and len(fade) == 2 and all(
                not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v) for v in fade))
            if not ok or not 0 <= fade[0] < fade[1]:
                c.fail("vehicle.regen_fade_kmh", f"must be two speeds [low, high] in km/h with 0 <= low < high, "
                       f"not {fade!r}")
            values[name] = (float(fade[0]), float(fade[1]))
        else:
            values[name] = c.number(sub, name, "vehicle.", positive=name not in ("f0_N", "f1_N_per_mps",
                                                                                 "f2_N_per_mps2"), low=0.0)
    if values["gear_efficiency"] > 1 or values["rotating_mass_factor"] < 1:
        c.fail("vehicle", "needs gear_efficiency <= 1 and rotating_mass_factor >= 1")
    return VehicleSpec(**values)


def _columns(c: _Check, table: dict) -> tuple[OutputColumn, ...]:
    items = table.get("columns")
    if not isinstance(items, list) or not items:
        c.fail("columns", "must be a list of output columns ({name, signal, unit, resolution, noise})")
    out, names = [], set()
    keys = [f.name for f in fields(OutputColumn)]
    for i, item in enumerate(items):
        key = f"columns[{i}]"
        if not isinstance(item, dict):
            c.fail(key, "must be a table {name, signal, unit, resolution, noise}")
        c.only(item, f"virtual_plant.{key}", keys)
        name = item.get("name")
        if not isinstance(name, str) or not name or any(ch in name for ch in ',"\r\n') or name != name.strip():
            c.fail(f"{key}.name", f"must be a column name without commas, quotes or surrounding blanks, not {name!r}")
        if name in names:
            c.fail(f"{key}.name", f"{name!r} appears twice")
        names.add(name)
        signal = item.get("signal")
        if signal not in SIGNALS:
            c.fail(f"{key}.signal", f"{signal!r} is not one of {', '.join(SIGNALS)}")
        quantity = BY_NAME[SIGNALS[signal]].quantity
        unit = item.get("unit")
        if unit not in UNITS[quantity]:
            c.fail(f"{key}.unit", f"{unit!r} is not a {quantity} unit ({', '.join(UNITS[quantity])})")
        resolution = c.number(item, "resolution", f"{key}.", positive=True, high=100.0)
        noise = c.number(item, "noise", f"{key}.", low=0.0, high=1000.0)
        gradient = c.number(item, "gradient", f"{key}.", low=-1.0, high=1.0, default=0.0)
        if gradient and signal != "winding":
            c.fail(f"{key}.gradient", "applies to winding sensors only")
        out.append(OutputColumn(name, signal, unit, resolution, noise, gradient))
    present = {col.signal for col in out}
    missing = [s for s in REQUIRED_SIGNALS if s not in present]
    if missing:
        c.fail("columns", f"lack a column with signal {missing[0]!r}; the bench needs {', '.join(REQUIRED_SIGNALS)}")
    return tuple(out)


def _profiles(c: _Check, table: dict, plant: VirtualPlant) -> tuple[Profile, ...]:
    items = table.get("profiles")
    if not isinstance(items, list) or not items:
        c.fail("profiles", "must be a list of profiles ({name, role, coolant_C, phases})")
    out, names = [], set()
    for i, item in enumerate(items):
        key = f"profiles[{i}]"
        if not isinstance(item, dict):
            c.fail(key, "must be a table {name, role, coolant_C, phases}")
        c.only(item, f"virtual_plant.{key}", ("name", "role", "coolant_C", "phases"))
        name = item.get("name")
        if not isinstance(name, str) or not name or not all(ch.isalnum() or ch in "._-" for ch in name):
            c.fail(f"{key}.name", f"must be letters, digits, '.', '-' or '_' (it names the file), not {name!r}")
        if name in names:
            c.fail(f"{key}.name", f"{name!r} appears twice")
        names.add(name)
        role = item.get("role")
        if role not in ROLES:
            c.fail(f"{key}.role", f"must be one of {', '.join(ROLES)}, not {role!r}")
        coolant = c.number(item, "coolant_C", f"{key}.", low=-30.0, high=120.0)
        phases = item.get("phases")
        if not isinstance(phases, list) or not phases:
            c.fail(f"{key}.phases", "must be a non-empty list of phases")
        parsed = tuple(_phase(c, f"{key}.phases[{j}]", ph, plant) for j, ph in enumerate(phases))
        profile = Profile(i + 1, name, role, coolant, parsed)
        rows = profile.duration_s / plant.sample_period_s
        if abs(rows - round(rows)) > 1e-9 * max(rows, 1.0):
            c.fail(key, f"lasts {profile.duration_s:g} s, not a whole number of sample periods "
                        f"({plant.sample_period_s:g} s)")
        out.append(profile)
    return tuple(out)


def _phase(c: _Check, key: str, item, plant: VirtualPlant) -> Phase:
    if not isinstance(item, dict):
        c.fail(key, "must be a table with a kind (cycle, constant, steps, rest)")
    kind = item.get("kind")
    if kind not in PHASE_KINDS:
        c.fail(f"{key}.kind", f"must be one of {', '.join(PHASE_KINDS)}, not {kind!r}")
    limits = plant.motor.limits
    coolant = None
    if "coolant_C" in item:
        coolant = c.number(item, "coolant_C", f"{key}.", low=-30.0, high=120.0)
    spec = {"kind": kind, **({"coolant_C": coolant} if coolant is not None else {})}
    if kind == "cycle":
        c.only(item, f"virtual_plant.{key}", ("kind", "cycle", "from_s", "to_s", "speed_scale", "coolant_C"))
        cycle = item.get("cycle")
        if cycle not in CYCLE_CHECKS:
            c.fail(f"{key}.cycle", f"must be one of {', '.join(CYCLE_CHECKS)}, not {cycle!r}")
        trace = load_trace(cycle)
        start = c.number(item, "from_s", f"{key}.", low=0.0, high=trace.duration_s, default=0.0)
        end = c.number(item, "to_s", f"{key}.", low=0.0, high=trace.duration_s, default=trace.duration_s)
        scale = c.number(item, "speed_scale", f"{key}.", low=0.5, high=2.0, default=1.0)
        if start != int(start) or end != int(end) or end <= start:
            c.fail(key, f"needs whole seconds from_s < to_s, not {start:g}..{end:g}")
        for at in (start, end):
            if trace.speed_kmh[int(at)] != 0:
                c.fail(key, f"must start and end at standstill; {cycle} runs at {trace.speed_kmh[int(at)]:g} km/h "
                            f"at {at:g} s")
        top = float(motor_speed_rpm(plant.vehicle, trace.speed_kmh.max() / KMH_PER_MPS * scale))
        if top > limits.speed_rpm:
            c.fail(key, f"reaches {top:.0f} rpm, above limits.speed_rpm ({limits.speed_rpm:g}); lower "
                        "speed_scale or the gear ratio")
        spec.update(cycle=cycle, from_s=start, to_s=end, speed_scale=scale)
        return Phase("cycle", end - start, coolant, spec, cycle=cycle, from_s=start, speed_scale=scale)
    if kind == "rest":
        c.only(item, f"virtual_plant.{key}", ("kind", "duration_s", "coolant_C"))
        duration = c.number(item, "duration_s", f"{key}.", positive=True, high=1e6)
        spec.update(duration_s=duration)
        return Phase("rest", duration, coolant, spec, points=((0.0, 0.0, duration),))
    if kind == "constant":
        c.only(item, f"virtual_plant.{key}", ("kind", "torque_Nm", "speed_rpm", "duration_s", "ramp_s", "coolant_C"))
        duration = c.number(item, "duration_s", f"{key}.", positive=True, high=1e6)
        ramp = c.number(item, "ramp_s", f"{key}.", low=0.0, high=600.0, default=20.0)
        if 2 * ramp >= duration:
            c.fail(f"{key}.duration_s", f"({duration:g} s) must be longer than its two ramps ({ramp:g} s each)")
        point = _point(c, key, item.get("torque_Nm"), item.get("speed_rpm"), plant)
        spec.update(torque_Nm=point[0], speed_rpm=point[1], duration_s=duration, ramp_s=ramp)
        return Phase("constant", duration, coolant, spec, ramp_s=ramp,
                     points=((point[0], point[1], duration - 2 * ramp),))
    c.only(item, f"virtual_plant.{key}", ("kind", "points", "ramp_s", "repeat", "coolant_C"))
    ramp = c.number(item, "ramp_s", f"{key}.", low=0.0, high=600.0, default=5.0)
    repeat = item.get("repeat", 1)
    if type(repeat) is not int or not 1 <= repeat <= 1000:
        c.fail(f"{key}.repeat", f"must be a whole number from 1 to 1000, not {repeat!r}")
    raw = item.get("points")
    if not isinstance(raw, list) or not raw:
        c.fail(f"{key}.points", "must be a list of [torque_Nm, speed_rpm, hold_s] points")
    points = []
    for j, pt in enumerate(raw):
        if not isinstance(pt, list) or len(pt) != 3:
            c.fail(f"{key}.points[{j}]", f"must be [torque_Nm, speed_rpm, hold_s], not {pt!r}")
        torque, speed = _point(c, f"{key}.points[{j}]", pt[0], pt[1], plant)
        hold = c.number({"hold_s": pt[2]}, "hold_s", f"{key}.points[{j}].", low=0.0, high=1e5)
        points.append((torque, speed, hold))
    points = tuple(points) * repeat
    duration = sum(p[2] for p in points) + ramp * (len(points) + 1)
    spec.update(points=[list(p) for p in points[: len(raw)]], ramp_s=ramp, repeat=repeat)
    return Phase("steps", duration, coolant, spec, ramp_s=ramp, points=points)


def _point(c: _Check, key: str, torque, speed, plant: VirtualPlant) -> tuple[float, float]:
    torque = c.number({"torque_Nm": torque}, "torque_Nm", f"{key}.")
    speed = c.number({"speed_rpm": speed}, "speed_rpm", f"{key}.", low=0.0, high=plant.motor.limits.speed_rpm)
    limit = float(plant.dq.torque_limit(speed))
    if abs(torque) > limit + 1e-9:
        c.fail(key, f"asks {torque:g} Nm at {speed:g} rpm, outside the motor's envelope (at most {limit:.1f} Nm "
                    "there: min(limits.torque_Nm, machine.power_W / ω))")
    return torque, speed


def _check_envelope(plant: VirtualPlant) -> None:
    """The machine must reach the whole torque envelope, with the magnet at ϑ_ref and 100 K hotter."""
    speed = np.linspace(0.0, plant.motor.limits.speed_rpm, 281)
    torque = plant.dq.torque_limit(speed)
    plant.operating_point(torque, speed)


def load_virtual_plant(path: str | Path) -> VirtualPlant:
    """Load a motor file and its virtual plant."""
    from bench.motor.description import load_motor

    return virtual_plant(load_motor(path))
