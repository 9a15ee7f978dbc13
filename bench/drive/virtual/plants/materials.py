"""Materials of the distributed plant: conductivity k (W/mK), density ρ (kg/m³), specific heat c (J/kgK).

Defaults are handbook values; a motor file may override any of them (`thermal.materials`). Laminated steel has a
radial (in-plane) and a much lower axial conductivity: the stack's insulation coating and the gaps between sheets
(Staton et al. 2005 use about 1/30 of the in-plane value).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from bench.motor.check import Checker

PROPERTIES = ("k_W_mK", "rho_kg_m3", "c_J_kgK")
AXIAL = "k_axial_W_mK"
DEFAULTS: dict[str, dict[str, float]] = {
    "copper": {"k_W_mK": 390.0, "rho_kg_m3": 8930.0, "c_J_kgK": 385.0},
    "lamination": {"k_W_mK": 28.0, AXIAL: 1.0, "rho_kg_m3": 7650.0, "c_J_kgK": 460.0},
    "aluminium": {"k_W_mK": 160.0, "rho_kg_m3": 2700.0, "c_J_kgK": 900.0},
    "magnet": {"k_W_mK": 9.0, "rho_kg_m3": 7500.0, "c_J_kgK": 440.0},          # sintered NdFeB
    "shaft": {"k_W_mK": 45.0, "rho_kg_m3": 7800.0, "c_J_kgK": 460.0},          # carbon steel
    "impregnation": {"k_W_mK": 0.25, "rho_kg_m3": 1400.0, "c_J_kgK": 1300.0},  # epoxy / varnish
    "liner": {"k_W_mK": 0.2, "rho_kg_m3": 1400.0, "c_J_kgK": 1100.0},          # slot liner (Nomex-type)
}


def materials(check: Checker, table: Mapping[str, Any]) -> dict[str, dict[str, float]]:
    """The defaults with the file's overrides (thermal.materials), each checked positive."""
    out = {name: dict(values) for name, values in DEFAULTS.items()}
    given = table.get("materials", {})
    if not isinstance(given, dict):
        check.fail("thermal.materials", "must be a table {material: {k_W_mK, rho_kg_m3, c_J_kgK}}")
    check.only(given, "thermal.materials", DEFAULTS)
    for name, values in given.items():
        key = f"thermal.materials.{name}"
        if not isinstance(values, dict):
            check.fail(key, f"must be a table of {', '.join(DEFAULTS[name])}")
        check.only(values, key, DEFAULTS[name])
        for prop in values:
            out[name][prop] = check.number(values, prop, f"{key}.", positive=True, high=1e5)
    return out
