"""The drive-cycle speed traces shipped in `bench/data` (provenance in PROVENANCE.md there): FTP-75 and WLTC class 3b
(the paper's test sequence), US06 (aggressive, high-speed) and HWFET (highway), for virtual test-bench profiles.

Each trace is verified when it is loaded (points, duration, distance, top speed), so a damaged or replaced
file fails loudly instead of silently changing every dataset.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from functools import cache
from importlib import resources

import numpy as np

from bench.errors import BenchError

KMH_PER_MPS = 3.6


@dataclass(frozen=True)
class CycleCheck:
    """What a shipped trace must look like (PROVENANCE.md): points, duration, distance, top speed."""

    points: int
    duration_s: float
    distance_km: float
    max_speed_kmh: float


# Distances and top speeds as stated in PROVENANCE.md (and the issue: FTP-75 17.77 km, WLTC3b 23.27 km).
CHECKS: dict[str, CycleCheck] = {
    "ftp75": CycleCheck(points=1875, duration_s=1874.0, distance_km=17.769, max_speed_kmh=91.25),
    "wltc3b": CycleCheck(points=1801, duration_s=1800.0, distance_km=23.266, max_speed_kmh=131.3),
    # EPA: US06 8.01 mi in 600 s, top 80.3 mph; HWFET 10.26 mi in 765 s, top 59.9 mph
    "us06": CycleCheck(points=601, duration_s=600.0, distance_km=12.888, max_speed_kmh=129.23),
    "hwfet": CycleCheck(points=766, duration_s=765.0, distance_km=16.507, max_speed_kmh=96.40),
}


@dataclass(frozen=True, eq=False)
class SpeedTrace:
    """A 1 Hz vehicle speed trace: time in s from 0, speed in km/h."""

    name: str
    time_s: np.ndarray
    speed_kmh: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def distance_km(self) -> float:
        """Distance of the piecewise-linear trace (the trapezoid rule is exact for it)."""
        return float(np.trapezoid(self.speed_kmh / KMH_PER_MPS, self.time_s) / 1000.0)

    @property
    def max_speed_kmh(self) -> float:
        return float(self.speed_kmh.max())


class CycleError(BenchError):
    """A shipped speed trace is missing or does not match its provenance note."""


def _read(name: str) -> SpeedTrace:
    try:
        text = resources.files("bench").joinpath("data", f"{name}.csv").read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CycleError(f"the speed trace bench/data/{name}.csv is missing; reinstall the package") from None
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or rows[0] != ["time_s", "speed_kmh"]:
        raise CycleError(f"bench/data/{name}.csv must start with the header time_s,speed_kmh")
    data = np.array([[float(v) for v in row] for row in rows[1:] if row], dtype=float)
    return SpeedTrace(name, data[:, 0].copy(), data[:, 1].copy())


def verify(trace: SpeedTrace) -> None:
    """Raise CycleError unless the trace matches CHECKS (1 Hz, from 0, non-negative, right length/distance)."""
    check = CHECKS[trace.name]
    where = f"bench/data/{trace.name}.csv"
    problems = []
    if len(trace.time_s) != check.points:
        problems.append(f"has {len(trace.time_s)} points, expected {check.points}")
    elif not np.array_equal(trace.time_s, np.arange(check.points, dtype=float)):
        problems.append("is not sampled at exactly 1 Hz from 0 s")
    if abs(trace.duration_s - check.duration_s) > 1e-9:
        problems.append(f"lasts {trace.duration_s:g} s, expected {check.duration_s:g} s")
    if abs(trace.distance_km - check.distance_km) > 0.001:
        problems.append(f"covers {trace.distance_km:.3f} km, expected {check.distance_km:.3f} km")
    if abs(trace.max_speed_kmh - check.max_speed_kmh) > 0.01:
        problems.append(f"peaks at {trace.max_speed_kmh:.2f} km/h, expected {check.max_speed_kmh:.2f} km/h")
    if np.any(trace.speed_kmh < 0) or trace.speed_kmh[0] != 0 or trace.speed_kmh[-1] != 0:
        problems.append("must be non-negative and start and end at standstill")
    if problems:
        raise CycleError(f"{where} " + "; ".join(problems) + " (see bench/data/PROVENANCE.md)")


@cache
def load_trace(name: str) -> SpeedTrace:
    """The verified trace of a name in CHECKS (read once per process)."""
    if name not in CHECKS:
        raise KeyError(f"unknown cycle {name!r}; choose one of {', '.join(CHECKS)}")
    trace = _read(name)
    verify(trace)
    trace.time_s.setflags(write=False)
    trace.speed_kmh.setflags(write=False)
    return trace


def provenance() -> str:
    """The provenance note that travels with the traces."""
    return resources.files("bench").joinpath("data", "PROVENANCE.md").read_text(encoding="utf-8")
