"""Reading a profile's phases from a motor file's `virtual_plant.profiles[…].phases`: one reader per phase kind.

Kinds (`PHASE_READERS`, in the order messages list them):
- cycle: a drive-cycle segment (bench.drive.cycles: ftp75, wltc3b, us06, hwfet) through the vehicle model;
- constant: one operating point with ramps from and back to standstill;
- steps: a list of [torque_Nm, speed_rpm, hold_s] points, repeated;
- random_steps: operating points drawn from the phase's own seed, as test benches run them (holds of minutes,
  torque uniform within the envelope at a uniform speed, hold log-uniform), so the profile is fixed by the motor
  file whatever the noise seed;
- rest: standstill (a cool-down).

Each reader checks its keys (one VirtualPlantError sentence through the Checker) and returns a `Phase`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bench.drive.cycles import CHECKS as CYCLE_CHECKS
from bench.drive.cycles import KMH_PER_MPS, load_trace
from bench.drive.vehicle import motor_speed_rpm
from bench.drive.virtual.profiles import Phase
from bench.motor.check import Checker, is_number

COMMON = ("kind", "coolant_C")
# random_steps: holds are drawn in whole multiples of this (the profile stays a whole number of samples)
HOLD_GRID_S = 10.0


def read_phase(c: Checker, key: str, item, plant) -> Phase:
    """The phase of one table of a profile's `phases` list."""
    if not isinstance(item, dict):
        c.fail(key, f"must be a table with a kind ({', '.join(PHASE_READERS)})")
    kind = item.get("kind")
    if not isinstance(kind, str) or kind not in PHASE_READERS:
        c.fail(f"{key}.kind", f"must be one of {', '.join(PHASE_READERS)}, not {kind!r}")
    coolant = None
    if "coolant_C" in item:
        coolant = c.number(item, "coolant_C", f"{key}.", low=-30.0, high=120.0)
    spec = {"kind": kind, **({"coolant_C": coolant} if coolant is not None else {})}
    return PHASE_READERS[kind](c, key, item, plant, spec, coolant)


def _cycle(c: Checker, key: str, item: dict, plant, spec: dict, coolant) -> Phase:
    c.only(item, key, (*COMMON, "cycle", "from_s", "to_s", "speed_scale"))
    cycle = item.get("cycle")
    if not isinstance(cycle, str) or cycle not in CYCLE_CHECKS:
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
    if top > plant.motor.limits.speed_rpm:
        c.fail(key, f"reaches {top:.0f} rpm, above limits.speed_rpm ({plant.motor.limits.speed_rpm:g}); lower "
                    "speed_scale or the gear ratio")
    spec.update(cycle=cycle, from_s=start, to_s=end, speed_scale=scale)
    return Phase("cycle", end - start, coolant, spec, cycle=cycle, from_s=start, speed_scale=scale)


def _rest(c: Checker, key: str, item: dict, plant, spec: dict, coolant) -> Phase:
    c.only(item, key, (*COMMON, "duration_s"))
    duration = c.number(item, "duration_s", f"{key}.", positive=True, high=1e6)
    spec.update(duration_s=duration)
    return Phase("rest", duration, coolant, spec, points=((0.0, 0.0, duration),))


def _constant(c: Checker, key: str, item: dict, plant, spec: dict, coolant) -> Phase:
    c.only(item, key, (*COMMON, "torque_Nm", "speed_rpm", "duration_s", "ramp_s"))
    duration = c.number(item, "duration_s", f"{key}.", positive=True, high=1e6)
    ramp = c.number(item, "ramp_s", f"{key}.", low=0.0, high=600.0, default=20.0)
    if 2 * ramp >= duration:
        c.fail(f"{key}.duration_s", f"({duration:g} s) must be longer than its two ramps ({ramp:g} s each)")
    torque, speed = _point(c, key, item.get("torque_Nm"), item.get("speed_rpm"), plant)
    spec.update(torque_Nm=torque, speed_rpm=speed, duration_s=duration, ramp_s=ramp)
    return Phase("constant", duration, coolant, spec, ramp_s=ramp, points=((torque, speed, duration - 2 * ramp),))


def _steps(c: Checker, key: str, item: dict, plant, spec: dict, coolant) -> Phase:
    c.only(item, key, (*COMMON, "points", "ramp_s", "repeat"))
    ramp = c.number(item, "ramp_s", f"{key}.", low=0.0, high=600.0, default=5.0)
    repeat = c.whole(item, "repeat", f"{key}.", low=1, high=1000, default=1)
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
    spec.update(points=[list(p) for p in points[: len(raw)]], ramp_s=ramp, repeat=repeat)
    return _steps_phase(spec, coolant, ramp, points)


def _random_steps(c: Checker, key: str, item: dict, plant, spec: dict, coolant) -> Phase:
    """{kind = "random_steps", seed, count, torque_Nm = [low, high], speed_rpm = [low, high], hold_s = [low, high],
    ramp_s (optional, 10)}: count points, each a speed uniform in speed_rpm, a torque uniform in torque_Nm clipped
    to the envelope at that speed, held a log-uniform time in hold_s (whole multiples of HOLD_GRID_S)."""
    c.only(item, key, (*COMMON, "seed", "count", "torque_Nm", "speed_rpm", "hold_s", "ramp_s"))
    seed = c.whole(item, "seed", f"{key}.", low=0)
    count = c.whole(item, "count", f"{key}.", low=1, high=1000)
    ramp = c.number(item, "ramp_s", f"{key}.", low=0.0, high=600.0, default=10.0)
    limits = plant.motor.limits
    torque = _range(c, f"{key}.torque_Nm", item.get("torque_Nm"), -limits.torque_Nm, limits.torque_Nm)
    speed = _range(c, f"{key}.speed_rpm", item.get("speed_rpm"), 0.0, limits.speed_rpm)
    hold = _range(c, f"{key}.hold_s", item.get("hold_s"), HOLD_GRID_S, 1e5)
    rng = np.random.default_rng(seed)
    points = []
    for _ in range(count):   # one draw order per point: speed, torque, hold
        n = float(rng.uniform(*speed))
        limit = float(plant.dq.torque_limit(n))
        t = float(np.clip(rng.uniform(*torque), -limit, limit))
        h = HOLD_GRID_S * max(1.0, round(float(np.exp(rng.uniform(*np.log(hold)))) / HOLD_GRID_S))
        points.append((round(t, 1), round(n, 0), h))
    spec.update(seed=seed, count=count, torque_Nm=list(torque), speed_rpm=list(speed), hold_s=list(hold),
                ramp_s=ramp)
    return _steps_phase(spec, coolant, ramp, tuple(points))


def _steps_phase(spec: dict, coolant, ramp: float, points: tuple) -> Phase:
    duration = sum(p[2] for p in points) + ramp * (len(points) + 1)
    return Phase("steps", duration, coolant, spec, ramp_s=ramp, points=points)


def _range(c: Checker, key: str, value, low: float, high: float) -> tuple[float, float]:
    ok = isinstance(value, list) and len(value) == 2 and all(is_number(v) for v in value)
    if not ok or not low <= value[0] <= value[1] <= high:
        c.fail(key, f"must be [low, high] with {low:g} <= low <= high <= {high:g}, not {value!r}")
    return float(value[0]), float(value[1])


def _point(c: Checker, key: str, torque, speed, plant) -> tuple[float, float]:
    torque = c.number({"torque_Nm": torque}, "torque_Nm", f"{key}.")
    speed = c.number({"speed_rpm": speed}, "speed_rpm", f"{key}.", low=0.0, high=plant.motor.limits.speed_rpm)
    limit = float(plant.dq.torque_limit(speed))
    if abs(torque) > limit + 1e-9:
        c.fail(key, f"asks {torque:g} Nm at {speed:g} rpm, outside the motor's envelope (at most {limit:.1f} Nm "
                    "there: min(limits.torque_Nm, machine.power_W / ω))")
    return torque, speed


PHASE_READERS: dict[str, Callable[..., Phase]] = {
    "cycle": _cycle, "constant": _constant, "steps": _steps, "random_steps": _random_steps, "rest": _rest}
PHASE_KINDS = tuple(PHASE_READERS)
