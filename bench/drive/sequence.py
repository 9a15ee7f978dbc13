"""The paper's test sequence: preheat 1800 s, FTP-75 1874 s, preheat 1800 s, WLTC3 1800 s = 7274 s.

Each drive cycle is preceded by a preheat: the machine runs at one constant operating point (motor torque
controlled, the dynamometer holding speed), 345 Nm at 3000 rpm (108 kW, roughly the continuous rating of a
200 kW-peak machine), which lifts the winding about 60 K above the coolant; 20 s linear ramps lead in and
out so the cycle starts from standstill. Torque and speed are functions of continuous time:
speed is the cycle trace interpolated linearly between its 1 Hz points, torque follows from the
vehicle model with the acceleration of the current second (so it is piecewise constant in the cycles).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from bench.drive.cycles import KMH_PER_MPS, load_trace
from bench.drive.motor import VIRTUAL_MOTOR, MotorSpec
from bench.drive.vehicle import VIRTUAL_VEHICLE, VehicleSpec, motor_speed_rpm, motor_torque_Nm

PREHEAT_S = 1800.0


@dataclass(frozen=True)
class OperatingPoint:
    """The preheat: constant torque and speed, reached and left by linear ramps of ramp_s."""

    torque_Nm: float = 345.0
    speed_rpm: float = 3000.0
    ramp_s: float = 20.0


PREHEAT = OperatingPoint()


@dataclass(frozen=True)
class Phase:
    name: str          # "preheat1", "ftp75", "preheat2", "wltc3"
    kind: str          # "preheat" or "cycle"
    start_s: float
    end_s: float
    cycle: str | None  # trace name for cycles

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@cache
def _phases() -> tuple[Phase, ...]:
    phases, t = [], 0.0
    for name, cycle in (("preheat1", None), ("ftp75", "ftp75"), ("preheat2", None), ("wltc3", "wltc3b")):
        duration = PREHEAT_S if cycle is None else load_trace(cycle).duration_s
        phases.append(Phase(name, "preheat" if cycle is None else "cycle", t, t + duration, cycle))
        t += duration
    return tuple(phases)


@dataclass(frozen=True)
class TestSequence:
    """The 7274 s drive profile of the virtual test stand."""

    __test__ = False  # not a pytest class

    motor: MotorSpec = VIRTUAL_MOTOR
    vehicle: VehicleSpec = VIRTUAL_VEHICLE
    preheat: OperatingPoint = PREHEAT

    @property
    def phases(self) -> tuple[Phase, ...]:
        return _phases()

    @property
    def duration_s(self) -> float:
        return self.phases[-1].end_s

    def phase_at(self, t) -> np.ndarray:
        """Index of the phase each time belongs to (phases are [start, end), the last one closed)."""
        starts = np.array([p.start_s for p in self.phases[1:]])
        return np.searchsorted(starts, np.asarray(t, dtype=float), side="right")

    def drive(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(motor torque in Nm, motor speed in rpm) at times t (s), vectorized."""
        t = np.asarray(t, dtype=float)
        torque, speed = np.zeros_like(t), np.zeros_like(t)
        which = self.phase_at(t)
        for k, phase in enumerate(self.phases):
            sel = which == k
            if not np.any(sel):
                continue
            local = t[sel] - phase.start_s
            if phase.cycle is None:
                torque[sel], speed[sel] = self._preheat(local, phase.duration_s)
            else:
                torque[sel], speed[sel] = self._cycle(phase.cycle, local)
        return torque, speed

    def _preheat(self, local, duration):
        p = self.preheat
        ramp = np.clip(np.minimum(local, duration - local) / p.ramp_s, 0.0, 1.0)
        return ramp * p.torque_Nm, ramp * p.speed_rpm

    def _cycle(self, name, local):
        trace = load_trace(name)
        v = trace.speed_kmh / KMH_PER_MPS
        v_t = np.interp(local, trace.time_s, v)
        second = np.clip(np.floor(local).astype(int), 0, len(v) - 2)
        accel = np.where(local < trace.duration_s, v[second + 1] - v[second], 0.0)  # right-continuous
        return motor_torque_Nm(self.vehicle, v_t, accel, self.motor), motor_speed_rpm(self.vehicle, v_t)

    def envelope_report(self, sample_period_s: float = 0.1) -> dict[str, float]:
        """Peak torque, speed and power over the sequence, and the smallest margin to the motor envelope."""
        t = np.arange(0.0, self.duration_s + 1e-9, sample_period_s)
        torque, speed = self.drive(t)
        power = torque * speed / 60.0 * 2 * np.pi
        margin = self.motor.torque_limit(speed) - np.abs(torque)
        return {"peak_torque_Nm": float(torque.max()), "min_torque_Nm": float(torque.min()),
                "peak_speed_rpm": float(speed.max()), "peak_power_W": float(power.max()),
                "min_power_W": float(power.min()), "min_envelope_margin_Nm": float(margin.min())}


@dataclass(frozen=True)
class ConstantDrive:
    """One operating point forever: for steady states and energy balances."""

    torque_Nm: float
    speed_rpm: float
    motor: MotorSpec = VIRTUAL_MOTOR

    def drive(self, t) -> tuple[np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        return np.full_like(t, self.torque_Nm), np.full_like(t, self.speed_rpm)
