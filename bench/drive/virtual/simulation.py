"""A motor file's virtual plant, checked (bench.drive.virtual.schema builds it), and one profile's simulation.

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
  ÷ (1 + magnet_resistivity_per_K·(ϑ_m - ϑ_ref)). Copper dc/ac temperature dependence as eqs. 3-5 at the copper's
  own temperature; the kind places the components (lptn4: the stator split k_s of eq. 8 with the TRUE k
  parameters; distributed: where they arise, plus bearing friction and windage).
- thermal: the plant kind of virtual_plant.thermal (bench.drive.virtual.plants: lptn4, the parameter-varying LPTN
  integrated exactly, or distributed, a network built from geometry), with torque, speed, coolant and ambient at
  each step's midpoint and the losses at its start; the kind places the loss components on its nodes.
- stand: the coolant inlet follows its set point through a first-order lag (coolant_lag_s), rises by
  coolant_gain_K_per_kW times the lagged nominal losses and wanders (AR(1)); the test-cell air likewise.
- initial state: every node at the profile's start_C, else its first coolant set point (the machine soaked).
- sensors: each column is the true signal at the sample time (a stator NTC: the winding node moved toward the yoke
  by its gradient, through a first-order lag of lag_s, plus its offset), converted to its unit, plus Gaussian noise
  (none on speed at standstill), rounded to its resolution. A column's `at` names the plant position it reads
  (default: the kind's position of its signal). One numpy Generator per profile and purpose, from
  SeedSequence([seed, profile number]), so a seed reproduces every byte.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np

from bench.drive.cycles import KMH_PER_MPS, load_trace
from bench.drive.dataset import BY_NAME, UNITS
from bench.drive.stand import Environment, StandSpec, environment
from bench.drive.vehicle import VehicleSpec, motor_speed_rpm, motor_torque_Nm
from bench.drive.virtual.errors import VirtualPlantError
from bench.drive.virtual.machine import DqModel, Machine, TrueLosses
from bench.drive.virtual.plants import LossComponents, StepInputs, ThermalPlant
from bench.drive.virtual.profiles import Phase, Profile
from bench.motor.description import MotorDescription
from bench.motor.losses import ElectricalLosses
from dbc.contract import TEMPERATURE_NODES

# output signal -> the schema column whose quantity (and so unit list) it has
SIGNALS = {"torque": "torque_Nm", "speed": "speed_rpm", "i_d": "i_d_A", "i_q": "i_q_A", "u_d": "u_d_V",
           "u_q": "u_q_V", "coolant": "coolant_C", "ambient": "ambient_C", "winding": "winding_C",
           "yoke": "yoke_C", "tooth": "tooth_C", "magnet": "pm_C", "ntc": "ntc_C",
           "temperature": "coolant_C", "coolant_out": "coolant_C"}
# the signal whose true value a sensor signal sees by default (the stator NTC sits on the end winding: the winding,
# with a gradient); "temperature" (an extra thermocouple) has no default and needs `at`
SENSED_NODE = {"ntc": "winding"}
# a plant position's true value in VirtualRun.truth is under AT + its name (apart from the signals' own)
AT = "at:"
# signals a column reads from a plant position (the others are drive, stand and electrical signals)
THERMAL_SIGNALS = ("winding", "yoke", "tooth", "magnet", "ntc", "temperature", "coolant_out")
FLUX_PROBE_K = 100.0   # currents are computed at ϑ_ref and ϑ_ref + this, and interpolated linearly in ϑ_m


def motor_where(motor: MotorDescription) -> str:
    """How a sentence about the motor's virtual plant names it."""
    return f"motor file {motor.path}" if motor.path else f"motor {motor.name!r}"


@dataclass(frozen=True)
class OutputColumn:
    name: str
    signal: str
    unit: str
    resolution: float
    noise: float
    gradient: float = 0.0
    lag_s: float = 0.0      # first-order sensor lag (temperature sensors)
    offset: float = 0.0     # added to the reading, in the column's unit (temperature sensors)
    at: str | None = None   # the plant position read (temperature sensors; default: the signal's position)

    @property
    def decimals(self) -> int:
        return max(0, -math.floor(math.log10(self.resolution) + 1e-9))

    def from_internal(self, values: np.ndarray) -> np.ndarray:
        """Internal unit (°C, rpm, Nm, A, V) -> this column's unit (the loader's conversion, inverted)."""
        scale, offset = UNITS[BY_NAME[SIGNALS[self.signal]].quantity][self.unit]
        return (np.asarray(values, dtype=float) - offset) / scale


@dataclass(frozen=True, eq=False)
class VirtualPlant:
    """A motor file's virtual_plant, read and checked (`virtual_plant(motor)`)."""

    motor: MotorDescription
    seed: int
    sample_period_s: float
    plant_step_s: float
    thermal: ThermalPlant
    machine: Machine
    true_losses: TrueLosses
    vehicle: VehicleSpec
    stand: StandSpec
    columns: tuple[OutputColumn, ...]
    profiles: tuple[Profile, ...]

    @property
    def params(self):
        """The true LPTN parameters of an lptn4 plant."""
        return self.thermal.params

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
                torque[sel], speed[sel] = phase.ramps(local)
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

    def environment(self, profile: Profile, rng: np.random.Generator) -> Environment:
        """Coolant inlet and test-cell air on a 1 s grid (bench.drive.stand), from the soaked start."""
        def nominal(t):
            torque, speed = self.drive(profile, t)
            i_d, i_q, _ = self.dq.currents(torque, speed)
            return self.nominal.evaluate_columns({"speed_rpm": speed, "i_d_A": i_d, "i_q_A": i_q})

        return environment(profile.duration_s, lambda t: self.setpoint(profile, t), nominal, rng, self.stand,
                           start_C=profile.coolant_C)

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
                f"{motor_where(self.motor)}: the machine cannot produce {float(np.ravel(torque)[bad]):.1f} Nm at "
                f"{float(np.ravel(speed_rpm)[bad]):.0f} rpm within limits.current_A and "
                "virtual_plant.machine.voltage_limit_V; raise them or lower the envelope")
        f = self.motor.pole_pairs * np.abs(np.asarray(speed_rpm, dtype=float)) / 60.0
        nom = self.nominal
        return {"i_d0": i_d0, "i_q0": i_q0, "di_d": (i_d1 - i_d0) / FLUX_PROBE_K,
                "di_q": (i_q1 - i_q0) / FLUX_PROBE_K, "x_ac": f / nom.ac_reference_Hz,
                "x_fe": f / nom.iron_reference_Hz, "x_m": f / nom.magnet_reference_Hz,
                "w": np.abs(np.asarray(speed_rpm, dtype=float)) / self.motor.limits.speed_rpm}

    def loss_components(self) -> LossComponents:
        """The true losses as components (bench.drive.virtual.plants.LossComponents); the kind places them."""
        nom, tl, mach = self.nominal, self.true_losses, self.machine
        ref = self.motor.copper_reference_C
        i_max = self.motor.limits.current_A
        r15 = 1.5 * nom.stator_resistance_ohm * tl.resistance_factor
        k_ac, ac_pm = tl.ac_factor, tl.ac_magnet_W
        e_cu, rem = tl.copper_load_error, mach.remanence_per_K
        p_h, p_e = nom.iron_hysteresis_W * tl.iron_factor, nom.iron_eddy_W * tl.iron_factor
        a_fe, psi0, l_d, l_q = tl.iron_per_K, mach.flux_linkage_Vs, mach.L_d_H, mach.L_q_H
        mag, c0 = nom.magnet_W * tl.magnet_factor, nom.magnet_no_load_share
        e_pm, a_pm = tl.magnet_load_error, tl.magnet_resistivity_per_K

        def components(i_d0, i_q0, di_d, di_q, x_ac, x_fe, x_m, th_m, th_iron):
            dm = th_m - ref
            flux = 1.0 + rem * dm
            i_d = i_d0 + di_d * dm
            i_q = i_q0 + di_q * dm
            i2 = i_d * i_d + i_q * i_q
            r = i2 ** 0.5 / i_max
            p_dc0 = r15 * i2
            p_ac0 = x_ac * x_ac * (k_ac * p_dc0 + ac_pm * flux * flux)
            load = 1.0 + e_cu * r * r
            psi_d = (psi0 * flux + l_d * i_d) / psi0
            psi_q = l_q * i_q / psi0
            p_s = (p_h * x_fe + p_e * x_fe * x_fe) * (psi_d * psi_d + psi_q * psi_q)
            p_s = p_s * (1.0 + a_fe * (th_iron - ref))
            m = c0 * flux + (1.0 - c0) * r
            p_m_map = mag * x_m * x_m * m * m
            p_m = p_m_map * (1.0 + e_pm * p_m_map / mag) / (1.0 + a_pm * dm)
            return p_dc0, p_ac0, load, p_s, p_m, r

        return LossComponents(components, ref, self.motor.copper_alpha_per_K)

    # ------------------------------------------------ one profile
    def simulate(self, profile: Profile, seed: int | None = None) -> VirtualRun:
        """The profile's true signals at the sample times and the measured columns (in the columns' units)."""
        seed = self.seed if seed is None else seed
        env_ss, sensor_ss = np.random.SeedSequence([int(seed), profile.number]).spawn(2)
        env = self.environment(profile, np.random.default_rng(env_ss))
        coolant, ambient = env.coolant, env.ambient
        h, period = self.plant_step_s, self.sample_period_s
        n = int(round(profile.duration_s / h))
        mid = (np.arange(n) + 0.5) * h
        torque, speed = self.drive(profile, mid)
        steps = StepInputs(self.operating_point(torque, speed), speed, coolant(mid), ambient(mid), h)
        stride = int(round(period / h))
        rows = int(round(profile.duration_s / period)) + 1
        run = self.thermal.simulate(steps, self.loss_components(), profile.initial_C, stride)
        t = np.arange(rows) * period
        states = run.states[:rows]
        truth = self.truth_at(profile, t, states, coolant(t), ambient(t))
        measured = self.measure(truth, np.random.default_rng(sensor_ss))
        return VirtualRun(profile, int(seed), t, truth, measured, run.losses)

    def truth_at(self, profile: Profile, t, states, coolant, ambient) -> dict[str, np.ndarray]:
        torque, speed = self.drive(profile, t)
        op = self.operating_point(torque, speed)
        ref = self.motor.copper_reference_C
        at = self.thermal.signal_positions
        dm = self.thermal.read(states, at["flux"]) - ref
        i_d, i_q = op["i_d0"] + op["di_d"] * dm, op["i_q0"] + op["di_q"] * dm
        flux = 1.0 + self.machine.remanence_per_K * dm
        resistance = (self.nominal.stator_resistance_ohm * self.true_losses.resistance_factor
                      * (1.0 + self.motor.copper_alpha_per_K * (self.thermal.read(states, at["copper"]) - ref)))
        u_d, u_q = self.dq.voltages(i_d, i_q, speed, flux, resistance)
        truth = {"torque": torque, "speed": speed, "i_d": i_d, "i_q": i_q, "u_d": u_d, "u_q": u_q,
                 "coolant": coolant, "ambient": ambient}
        for signal in TEMPERATURE_NODES:
            truth[signal] = self.thermal.read(states, at[signal])
        if "coolant_out" in at:
            truth["coolant_out"] = self.thermal.read(states, at["coolant_out"])
        for position in {col.at for col in self.columns if col.at is not None}:
            truth[AT + position] = self.thermal.read(states, position)
        return truth

    def measure(self, truth: dict[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
        """One noise block per column, in file order; noise and rounding in the column's unit."""
        out = {}
        for col in self.columns:
            x = np.asarray(truth[AT + col.at] if col.at else truth[SENSED_NODE.get(col.signal, col.signal)],
                           dtype=float)
            if col.gradient:
                x = x + col.gradient * (x - truth["yoke"])
            if col.lag_s:
                x = first_order_lag(x, self.sample_period_s, col.lag_s)
            x = col.from_internal(x) + col.offset
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


def first_order_lag(x: np.ndarray, period_s: float, tau_s: float) -> np.ndarray:
    """A sensor with time constant tau_s sampled every period_s, starting settled at x[0]: y_k = y_(k-1) +
    (1 - exp(-T/τ))·(x_k - y_(k-1)) (exact for an input held over each sample period)."""
    from scipy.signal import lfilter

    a = math.exp(-period_s / tau_s)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])
    return y


@dataclass(frozen=True, eq=False)
class VirtualRun:
    profile: Profile
    seed: int
    time_s: np.ndarray
    truth: dict[str, np.ndarray]       # internal units (°C, rpm, Nm, A, V)
    measured: dict[str, np.ndarray]    # by output column name, in the columns' units
    losses: np.ndarray                 # (rows - 1, k) the plant's loss groups (thermal.loss_names) of the step
                                       # starting at each sample (W); lptn4: the four node losses

    def rise_K(self) -> dict[str, float]:
        cool = self.truth["coolant"]
        return {node: round(float((self.truth[node] - cool).max()), 2) for node in ("winding", "magnet")}
