"""Reading and checking a motor file's `virtual_plant` table into a VirtualPlant.

Schema of `virtual_plant` (version 1; every key required unless marked optional):

    schema_version = 1                      # optional
    seed = 20260                            # the default noise seed of 'bench data --motor'
    sample_period_s = 1.0                   # the files' sample period
    plant_step_s = 0.1                      # integration step; a whole fraction of the sample period
    [thermal]                               # the thermal truth: kind = "lptn4" (the default when kind is absent)
                                            #   or "distributed" (see below)
    [machine]                               # steady-state dq model of an interior-PM machine
    power_W, flux_linkage_Vs (ψ at copper_reference_C), L_d_H < L_q_H (saliency: i_d < 0 adds reluctance
    torque), voltage_limit_V (largest |u_dq|, amplitude-invariant), remanence_per_K (ψ(ϑ_m) = ψ·(1 + α(ϑ_m -
    ϑ_ref))); the machine must reach the whole envelope min(limits.torque_Nm, power_W/ω) within limits.current_A
    with the magnet at ϑ_ref and 100 K hotter
    [true_losses]                           # what the real machine does beyond the file's [losses] model
    resistance_factor, ac_factor, ac_magnet_W, copper_load_error, iron_factor, iron_per_K, magnet_factor,
    magnet_load_error, magnet_resistivity_per_K
    [vehicle]                               # bench.drive.vehicle.VehicleSpec's fields (cycles -> torque, speed)
    [stand]                                 # coolant conditioning and test-cell air (bench.drive.stand.StandSpec)
    [[columns]]                             # the output columns, in file order
    name, signal (torque, speed, i_d, i_q, u_d, u_q, coolant, ambient, winding, yoke, tooth, magnet, ntc,
    temperature, coolant_out),
    unit (any unit bench.drive.dataset's loader converts for that quantity), resolution, noise (1 σ, in the
    column's unit), gradient (optional, winding and ntc only: the sensor reads ϑ_w + gradient·(ϑ_w - ϑ_y)),
    lag_s (optional, temperatures: a first-order sensor lag), offset (optional, temperatures: added to the reading,
    in the column's unit); signal "ntc" is a stator NTC on the end winding (the winding node, through gradient,
    lag_s and offset), written to the dataset column ntc_C; at (optional, the plant's temperature signals only: a
    position of the thermal plant the sensor reads, e.g. "winding.end_a", "tooth.tip", "coolant.out"; default: the
    kind's position of the signal); signal "temperature" is an extra thermocouple (needs at) and "coolant_out" the
    coolant outlet (distributed plants): columns a mapping may leave unmapped (the loader ignores them)
    [[profiles]]                            # the measurement runs
    name, role ("train", "validate" or "test": a fixed split; test profiles are reported, never chosen on),
    coolant_C (set point at the start), start_C (optional: every node soaked at this at the start, a cold or hot
    start; default coolant_C), phases: a list of (bench.drive.virtual.phases reads them)
      {"kind": "cycle", "cycle": "ftp75"|"wltc3b"|"us06"|"hwfet", "from_s", "to_s" (optional: a segment that
       starts and ends at standstill), "speed_scale" (optional, default 1)}
      {"kind": "constant", "torque_Nm", "speed_rpm", "duration_s", "ramp_s" (optional, 20)}
      {"kind": "steps", "points": [[torque_Nm, speed_rpm, hold_s], ...], "ramp_s" (optional, 5),
       "repeat" (optional, 1)}: linear ramps between the points, from and back to standstill
      {"kind": "random_steps", "seed", "count", "torque_Nm": [low, high], "speed_rpm": [low, high],
       "hold_s": [low, high], "ramp_s" (optional, 10)}: count points drawn from seed (speed uniform, torque
       uniform clipped to the envelope, hold log-uniform in whole 10 s), then as steps
      {"kind": "rest", "duration_s"}: standstill
    and on any phase "coolant_C" (optional): the coolant set point from that phase on.

The `thermal` table by kind (bench.drive.virtual.plants; every number checked, defaults in the kind's module):

    kind = "lptn4": the 22 parameters C_y, C_w, C_t, C_m, R_yw, R_yt, R_wt, R_cy0, R_wm0, a_wm, b_wm, R_tm0,
    a_tm, b_tm, R_ma0, a_ma, b_ma, alpha_cy, k_0..k_3 of the parameter-varying network of paper Fig. 4 (speed
    ratio n / limits.speed_rpm), the same four-node model `bench identify` fits; positions yoke, winding, tooth,
    magnet.
    kind = "distributed": a network built from geometry (docs/plant.md; bench.drive.virtual.plants.distributed;
    required keys below have no default there):
      rotor = "inner" | "outer"; slices (axial slices of the active part, >= 4)
      [geometry] airgap_diameter_mm, stator_back_diameter_mm, stack_length_mm, slots, slot_depth_mm,
                 tooth_tip_mm, tooth_width_ratio, airgap_mm, magnet_thickness_mm, magnet_depth_mm,
                 magnet_width_ratio, rotor_back_iron_mm (outer rotor), shaft_diameter_mm, housing_thickness_mm,
                 end_turn_length_mm, end_winding_overhang_mm, end_space_mm, end_cap_thickness_mm, slot_fill,
                 slot_liner_mm, contact_gap_mm, bearing_outer_diameter_mm, bearing_width_mm, bearing_gap_mm
      [materials] optional overrides {material: {k_W_mK, rho_kg_m3, c_J_kgK}} of copper, lamination (plus
                 k_axial_W_mK), aluminium, magnet, shaft, impregnation, liner
      [cooling]  kind = "water_jacket": flow_l_min, turns, channel_width_mm, channel_height_mm, ambient_h_W_m2K
                 kind = "air": air_speed_m_s, fins, fin_height_mm, fin_thickness_mm, ambient_h_W_m2K
      [end_space] k1, k2, k3 (h = k1·(1 + k2·v^k3))          [losses] placement of the loss components
    positions: winding.slot_bottom/slot_top/slot_mid/mean/end_a/end_b, tooth.tip/body, yoke.inner/back,
    housing, coolant.out, magnet, magnet.mid/end_a/end_b, rotor, shaft, bearing.a/b, end_cap.a/b, end_space.a/b.

Every problem with the table is one VirtualPlantError sentence naming the file and the key.
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np

from bench.drive.dataset import BY_NAME, UNITS
from bench.drive.stand import STAND_KEYS, StandSpec
from bench.drive.vehicle import VehicleSpec
from bench.drive.virtual.errors import VirtualPlantError
from bench.drive.virtual.machine import Machine, TrueLosses
from bench.drive.virtual.phases import read_phase
from bench.drive.virtual.plants import ThermalPlant, thermal_plant
from bench.drive.virtual.profiles import ROLES, Profile
from bench.drive.virtual.simulation import (
    SENSED_NODE,
    SIGNALS,
    THERMAL_SIGNALS,
    OutputColumn,
    VirtualPlant,
    motor_where,
)
from bench.motor.check import Checker, is_number
from bench.motor.description import MotorDescription
from bench.motor.losses import ElectricalLosses

SCHEMA_VERSION = 1
TOP_KEYS = ("schema_version", "seed", "sample_period_s", "plant_step_s", "thermal", "machine", "true_losses",
            "vehicle", "stand", "columns", "profiles")
# what the bench needs to identify an electrical-loss motor from the files
REQUIRED_SIGNALS = ("torque", "speed", "i_d", "i_q", "coolant", "ambient", "winding", "magnet")


def virtual_plant(motor: MotorDescription) -> VirtualPlant:
    """The motor's virtual_plant, checked; VirtualPlantError (one sentence) on the first problem."""
    where = motor_where(motor)
    table = motor.virtual_plant
    if table is None:
        raise VirtualPlantError(f"{where} describes no virtual plant; bench data only generates data for virtual "
                                "motors (without --motor it writes the built-in motor's datasets)")
    if not isinstance(motor.loss_model, ElectricalLosses):
        raise VirtualPlantError(f"{where}: a virtual plant needs losses.kind = \"electrical\" (its data carry the "
                                "d/q currents the losses are computed from)")
    c = Checker(where, VirtualPlantError, prefix="virtual_plant.", hint="see examples/motor-ipm/motor.json",
                terse=True)
    c.only(table, "", TOP_KEYS)
    c.version(table, SCHEMA_VERSION)
    seed = c.whole(table, "seed", low=0)
    period = c.number(table, "sample_period_s", low=0.01, high=60.0)
    step = c.number(table, "plant_step_s", low=0.001, high=10.0)
    stride = period / step
    if abs(stride - round(stride)) > 1e-9 * stride:
        c.fail("sample_period_s", f"({period:g} s) must be a whole number of plant_step_s ({step:g} s)")
    thermal = thermal_plant(c, table, motor)
    machine = Machine(**_numbers(c, table, "machine", _names(Machine), signed=("remanence_per_K",)))
    if machine.L_q_H <= machine.L_d_H:
        c.fail("machine.L_q_H", "must exceed L_d_H (an interior-PM machine: i_d < 0 adds reluctance torque)")
    if not -0.01 <= machine.remanence_per_K <= 0.0:
        c.fail("machine.remanence_per_K", f"= {machine.remanence_per_K:g} must be from -0.01 to 0 (NdFeB: about "
               "-0.0012)")
    true_losses = TrueLosses(**_numbers(c, table, "true_losses", _names(TrueLosses),
                                        signed=("iron_per_K", "copper_load_error", "magnet_load_error"),
                                        positive=("resistance_factor", "iron_factor", "magnet_factor")))
    vehicle = _vehicle(c, table)
    stand = StandSpec(**_numbers(c, table, "stand", STAND_KEYS, signed=("ambient_C", "ambient_per_coolant_K"),
                                 positive=("coolant_lag_s", "coolant_heat_lag_s", "coolant_wander_s",
                                           "ambient_wander_s")))
    columns = _columns(c, table, thermal)
    plant = VirtualPlant(motor, seed, period, step, thermal, machine, true_losses, vehicle, stand, columns, ())
    profiles = _profiles(c, table, plant)
    plant = VirtualPlant(motor, seed, period, step, thermal, machine, true_losses, vehicle, stand, columns,
                         profiles)
    _check_envelope(plant)
    return plant



def _names(cls) -> tuple[str, ...]:
    return tuple(f.name for f in fields(cls))


def _numbers(c: Checker, table: dict, key: str, names: tuple[str, ...], signed=(), positive=None) -> dict[str, float]:
    """The numbers names of table[key]: >= 0 (> 0 if in positive, all if positive is None; any sign if signed)."""
    sub = c.table(table, key)
    c.only(sub, key, names)
    positive = names if positive is None else positive
    out = {}
    for name in names:
        if name in signed:
            out[name] = c.number(sub, name, f"{key}.")
        else:
            out[name] = c.number(sub, name, f"{key}.", positive=name in positive, low=0.0)
    return out


def _vehicle(c: Checker, table: dict) -> VehicleSpec:
    sub = c.table(table, "vehicle")
    names = _names(VehicleSpec)
    c.only(sub, "vehicle", names)
    values = {}
    for name in names:
        if name == "regen_fade_kmh":
            fade = sub.get(name)
            ok = isinstance(fade, list) and len(fade) == 2 and all(is_number(v) for v in fade)
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


def _columns(c: Checker, table: dict, thermal: ThermalPlant) -> tuple[OutputColumn, ...]:
    items = table.get("columns")
    if not isinstance(items, list) or not items:
        c.fail("columns", "must be a list of output columns ({name, signal, unit, resolution, noise})")
    out, names = [], set()
    keys = _names(OutputColumn)
    for i, item in enumerate(items):
        key = f"columns[{i}]"
        if not isinstance(item, dict):
            c.fail(key, "must be a table {name, signal, unit, resolution, noise}")
        c.only(item, key, keys)
        name = item.get("name")
        if not isinstance(name, str) or not name or any(ch in name for ch in ',"\r\n') or name != name.strip():
            c.fail(f"{key}.name", f"must be a column name without commas, quotes or surrounding blanks, not {name!r}")
        if name in names:
            c.fail(f"{key}.name", f"{name!r} appears twice")
        names.add(name)
        signal = item.get("signal")
        if not isinstance(signal, str) or signal not in SIGNALS:   # a list here: a sentence, not a TypeError
            c.fail(f"{key}.signal", f"{signal!r} is not one of {', '.join(SIGNALS)}")
        quantity = BY_NAME[SIGNALS[signal]].quantity
        unit = item.get("unit")
        if not isinstance(unit, str) or unit not in UNITS[quantity]:
            c.fail(f"{key}.unit", f"{unit!r} is not a {quantity} unit ({', '.join(UNITS[quantity])})")
        resolution = c.number(item, "resolution", f"{key}.", positive=True, high=100.0)
        noise = c.number(item, "noise", f"{key}.", low=0.0, high=1000.0)
        gradient = c.number(item, "gradient", f"{key}.", low=-1.0, high=1.0, default=0.0)
        if gradient and signal not in ("winding", "ntc"):
            c.fail(f"{key}.gradient", "applies to winding and NTC sensors only")
        lag = c.number(item, "lag_s", f"{key}.", low=0.0, high=3600.0, default=0.0)
        offset = c.number(item, "offset", f"{key}.", low=-50.0, high=50.0, default=0.0)
        if (lag or offset) and quantity != "temperature":
            c.fail(f"{key}.{'lag_s' if lag else 'offset'}", "applies to temperature sensors only")
        at = _position(c, key, item, signal, thermal)
        out.append(OutputColumn(name, signal, unit, resolution, noise, gradient, lag, offset, at))
    present = {col.signal for col in out}
    missing = [s for s in REQUIRED_SIGNALS if s not in present]
    if missing:
        c.fail("columns", f"lack a column with signal {missing[0]!r}; the bench needs {', '.join(REQUIRED_SIGNALS)}")
    return tuple(out)


def _position(c: Checker, key: str, item: dict, signal: str, thermal: ThermalPlant) -> str | None:
    """The column's `at`: a position of the plant, for temperature signals; None reads the signal's default."""
    at = item.get("at")
    sensed = SENSED_NODE.get(signal, signal)
    if at is None:
        if signal in THERMAL_SIGNALS and sensed not in thermal.signal_positions:
            c.fail(f"{key}.at", f"is needed for signal {signal!r} (a {thermal.kind} plant has no default position "
                   f"for it); positions: {', '.join(thermal.positions)}")
        return None
    if signal not in THERMAL_SIGNALS:
        c.fail(f"{key}.at", f"applies to the plant's temperature signals only ({', '.join(THERMAL_SIGNALS)})")
    if not isinstance(at, str) or at not in thermal.positions:
        c.fail(f"{key}.at", f"{at!r} is not a position of the {thermal.kind} plant; positions: "
               f"{', '.join(thermal.positions)}")
    return at


def _profiles(c: Checker, table: dict, plant: VirtualPlant) -> tuple[Profile, ...]:
    items = table.get("profiles")
    if not isinstance(items, list) or not items:
        c.fail("profiles", "must be a list of profiles ({name, role, coolant_C, phases})")
    out, names = [], set()
    for i, item in enumerate(items):
        key = f"profiles[{i}]"
        if not isinstance(item, dict):
            c.fail(key, "must be a table {name, role, coolant_C, phases}")
        c.only(item, key, ("name", "role", "coolant_C", "start_C", "phases"))
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
        start = c.number(item, "start_C", f"{key}.", low=-30.0, high=200.0) if "start_C" in item else None
        phases = item.get("phases")
        if not isinstance(phases, list) or not phases:
            c.fail(f"{key}.phases", "must be a non-empty list of phases")
        parsed = tuple(read_phase(c, f"{key}.phases[{j}]", ph, plant) for j, ph in enumerate(phases))
        profile = Profile(i + 1, name, role, coolant, parsed, start)
        rows = profile.duration_s / plant.sample_period_s
        if abs(rows - round(rows)) > 1e-9 * max(rows, 1.0):
            c.fail(key, f"lasts {profile.duration_s:g} s, not a whole number of sample periods "
                        f"({plant.sample_period_s:g} s)")
        out.append(profile)
    return tuple(out)


def _check_envelope(plant: VirtualPlant) -> None:
    """The machine must reach the whole torque envelope, with the magnet at ϑ_ref and 100 K hotter."""
    speed = np.linspace(0.0, plant.motor.limits.speed_rpm, 281)
    torque = plant.dq.torque_limit(speed)
    plant.operating_point(torque, speed)


def load_virtual_plant(path: str | Path) -> VirtualPlant:
    """Load a motor file and its virtual plant."""
    from bench.motor.description import load_motor

    return virtual_plant(load_motor(path))
