"""Vehicle and driveline: a speed trace -> motor torque and speed on the test stand.

The motor drives a large electric van (or pickup) through a single reduction gear. The numbers are chosen to be
plausible for such a vehicle, not copied from a particular one: a 3.2 t test mass needs most of the
200 kW machine's torque range on WLTC's accelerations while staying inside its envelope, and the vehicle's
power-to-mass ratio (≈ 62 W/kg > 34 W/kg, top speed > 120 km/h) puts it in WLTC class 3b.

Road load is the usual coast-down polynomial F = f0 + f1·v + f2·v² (f0: rolling resistance 0.009·m·g;
f2: ½·ρ·c_d·A with ρ = 1.2 kg/m³, c_d·A = 1.25 m²). Rotating parts add 4 % to the inertial mass. The
gear passes power with 97 % efficiency in both directions. Braking is regenerative up to a torque and
power limit and fades out between 10 and 3 km/h; the friction brakes take the rest.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from bench.drive.motor import RPM_PER_RAD_S, VIRTUAL_MOTOR, MotorSpec

GRAVITY = 9.81


@dataclass(frozen=True)
class VehicleSpec:
    mass_kg: float = 3200.0
    rotating_mass_factor: float = 1.04
    f0_N: float = 0.009 * 3200.0 * GRAVITY          # rolling resistance, acts only while moving
    f1_N_per_mps: float = 2.0                      # drivetrain and tyre speed losses
    f2_N_per_mps2: float = 0.5 * 1.2 * 1.25        # aerodynamic drag
    wheel_radius_m: float = 0.36
    gear_ratio: float = 7.0
    gear_efficiency: float = 0.97
    regen_torque_Nm: float = 400.0                 # motor-side regenerative torque limit
    regen_power_W: float = 120e3
    regen_fade_kmh: tuple[float, float] = (3.0, 10.0)

    def as_dict(self) -> dict:
        return asdict(self)


VIRTUAL_VEHICLE = VehicleSpec()


def motor_speed_rpm(vehicle: VehicleSpec, speed_mps):
    """Motor speed from vehicle speed (no slip)."""
    return np.asarray(speed_mps, dtype=float) / vehicle.wheel_radius_m * vehicle.gear_ratio * RPM_PER_RAD_S


def road_load_N(vehicle: VehicleSpec, speed_mps):
    v = np.asarray(speed_mps, dtype=float)
    return np.where(v > 0, vehicle.f0_N + vehicle.f1_N_per_mps * v + vehicle.f2_N_per_mps2 * v * v, 0.0)


def motor_torque_Nm(vehicle: VehicleSpec, speed_mps, accel_mps2, spec: MotorSpec = VIRTUAL_MOTOR):
    """Motor torque for a vehicle speed and acceleration: traction, or regenerative braking within limits."""
    v = np.asarray(speed_mps, dtype=float)
    force = vehicle.mass_kg * vehicle.rotating_mass_factor * np.asarray(accel_mps2, dtype=float)
    force = force + road_load_N(vehicle, v)
    wheel_torque = force * vehicle.wheel_radius_m
    traction = wheel_torque / (vehicle.gear_ratio * vehicle.gear_efficiency)
    braking = wheel_torque * vehicle.gear_efficiency / vehicle.gear_ratio
    omega = np.maximum(motor_speed_rpm(vehicle, v), 1e-9) / RPM_PER_RAD_S
    low, high = vehicle.regen_fade_kmh
    fade = np.clip((v * 3.6 - low) / (high - low), 0.0, 1.0)
    regen_limit = np.minimum(vehicle.regen_torque_Nm, vehicle.regen_power_W / omega) * fade
    return np.where(wheel_torque >= 0, traction, np.maximum(braking, -regen_limit))
