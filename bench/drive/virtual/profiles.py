"""The measurement runs of a virtual plant: profiles of phases (drive cycle segments, constant points, steps,
rests) and the torque and speed of the phases that are not drive cycles."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# train: identification; validate: choosing among settings; test: reported only, never looked at while choosing
ROLES = ("train", "validate", "test")


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

    def ramps(self, local) -> tuple[np.ndarray, np.ndarray]:
        """constant/steps/rest: (torque, speed) at local times, linear ramps of ramp_s from standstill through the
        points and back."""
        knots_t, knots_T, knots_n = [0.0], [0.0], [0.0]
        t = 0.0
        for torque, speed, hold in self.points:
            t += self.ramp_s
            knots_t += [t, t + hold]
            knots_T += [torque, torque]
            knots_n += [speed, speed]
            t += hold
        knots_t.append(t + self.ramp_s)
        knots_T.append(0.0)
        knots_n.append(0.0)
        return np.interp(local, knots_t, knots_T), np.interp(local, knots_t, knots_n)


@dataclass(frozen=True)
class Profile:
    number: int                        # 1-based position in the file: part of the noise seed
    name: str
    role: str
    coolant_C: float
    phases: tuple[Phase, ...]
    start_C: float | None = None       # every node soaked at this at t = 0 (None: at coolant_C); a cold/hot start

    @property
    def initial_C(self) -> float:
        return self.coolant_C if self.start_C is None else self.start_C

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
