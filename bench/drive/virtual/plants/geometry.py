"""Geometry of the distributed plant: the motor file's keys (millimetres), their defaults and ranges, and the
conduction formulas the network is built from.

Conduction (steady, one-dimensional): a cylindrical layer r1..r2 of length L conducts G = 2πkL/ln(r2/r1) radially
(times the share of the circumference that is solid, e.g. the teeth); a bar of section A and length L conducts
G = kA/L; an annular disc of thickness t conducts 2πkt/ln(r2/r1) radially. Series paths add resistances.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from bench.motor.check import Checker

MM = 1e-3
# key: (default or None if required, low, high); lengths in mm
KEYS: dict[str, tuple[float | None, float, float]] = {
    "airgap_diameter_mm": (None, 20.0, 2000.0),       # stator bore (inner rotor) / stator outside (outer rotor)
    "stator_back_diameter_mm": (None, 10.0, 2500.0),  # yoke back: stator outside (inner) / hub bore (outer rotor)
    "stack_length_mm": (None, 10.0, 2000.0),
    "slots": (None, 6.0, 400.0),
    "slot_depth_mm": (None, 2.0, 300.0),              # from the air gap to the slot bottom, tooth tip included
    "tooth_tip_mm": (2.0, 0.3, 50.0),                 # radial height of the tooth tips (the slot opening's layer)
    "tooth_width_ratio": (0.5, 0.1, 0.9),             # tooth width / slot pitch (the teeth's share of the circle)
    "tip_width_ratio": (0.75, 0.1, 0.98),             # the same at the tips (1 - slot opening / slot pitch)
    "airgap_mm": (None, 0.1, 20.0),
    "magnet_thickness_mm": (None, 0.5, 50.0),
    "magnet_depth_mm": (0.0, 0.0, 50.0),              # rotor surface to magnet (interior PM); 0: surface magnets
    "magnet_width_ratio": (0.8, 0.2, 1.0),            # magnets' share of the circumference
    "rotor_back_iron_mm": (15.0, 2.0, 200.0),         # outer rotor: back iron outside the magnets
    "shaft_diameter_mm": (None, 5.0, 500.0),
    "housing_thickness_mm": (None, 2.0, 200.0),       # housing (inner rotor) / stator hub (outer rotor)
    "end_turn_length_mm": (None, 5.0, 2000.0),        # conductor length of one end turn per side
    "end_winding_overhang_mm": (None, 5.0, 500.0),    # axial extent of each end winding
    "end_space_mm": (15.0, 1.0, 500.0),               # axial air space between end winding and end cap
    "end_cap_thickness_mm": (12.0, 2.0, 200.0),
    "slot_fill": (0.45, 0.1, 0.8),                    # copper share of the slot area
    "slot_liner_mm": (0.3, 0.05, 3.0),
    "contact_gap_mm": (0.03, 0.0, 0.5),               # stator-housing interface as an equivalent air gap
    "bearing_outer_diameter_mm": (None, 10.0, 1000.0),
    "bearing_width_mm": (15.0, 3.0, 200.0),
    "bearing_gap_mm": (0.3, 0.01, 3.0),               # the bearing as an equivalent interface gap (Staton)
}
WHOLE = ("slots",)


@dataclass(frozen=True)
class Geometry:
    """The file's geometry in metres (suffix _mm dropped), ratios and counts as given."""

    values: Mapping[str, float]

    def __getattr__(self, name: str) -> float:
        try:
            return self.values[name]
        except KeyError:
            raise AttributeError(name) from None


def geometry(check: Checker, table: Mapping[str, Any]) -> Geometry:
    """thermal.geometry, checked: every key known, each within its range, the radial build consistent."""
    sub = table.get("geometry")
    if not isinstance(sub, dict):
        check.fail("thermal.geometry", "is missing or not a table; see examples/suite/ipm-60kw-distributed")
    check.only(sub, "thermal.geometry", KEYS)
    values = {}
    for key, (default, low, high) in KEYS.items():
        if key in WHOLE:
            value = float(check.whole(sub, key, "thermal.geometry.", low=int(low), high=int(high)))
        else:
            value = check.number(sub, key, "thermal.geometry.", low=low, high=high, default=default)
        values[key.removesuffix("_mm")] = value * MM if key.endswith("_mm") else value
    return Geometry(values)


def radial(k: float, length: float, r1: float, r2: float, share: float = 1.0) -> float:
    """Conductance (W/K) of a cylindrical layer between radii r1 and r2 (either order)."""
    if r1 == r2:
        return math.inf
    return share * 2.0 * math.pi * k * length / abs(math.log(r2 / r1))


def disc(k: float, thickness: float, r1: float, r2: float) -> float:
    """Radial conductance of an annular disc."""
    return radial(k, thickness, r1, r2)


def bar(k: float, area: float, length: float) -> float:
    """Conductance of a bar (axial conduction)."""
    return k * area / length


def film(h: float, area: float) -> float:
    """Convection conductance h·A."""
    return h * area


def series(*conductances: float) -> float:
    """Conductances in series."""
    return 1.0 / sum(1.0 / g for g in conductances)


def annulus(r1: float, r2: float) -> float:
    """Area of the ring between r1 and r2 (either order)."""
    return math.pi * abs(r2 * r2 - r1 * r1)
