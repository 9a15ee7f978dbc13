"""Named LPTN parameter sets (paper Table 1) with units.

`table1` is the table as printed. `table1-refined` moves five rounded resistances inside their printed
rounding interval so the continuous eigenvalues equal the paper's eq. 27 (REFERENCE.md §2).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

# Unit of every parameter, in Table 1's order of appearance.
UNITS: dict[str, str] = {
    "C_y": "J/K", "C_w": "J/K", "C_t": "J/K", "C_m": "J/K",
    "R_yw": "K/W", "R_yt": "K/W", "R_wt": "K/W", "R_cy0": "K/W",
    "R_wm0": "K/W", "a_wm": "K/W", "b_wm": "-",
    "R_tm0": "K/W", "a_tm": "K/W", "b_tm": "-",
    "R_ma0": "K/W", "a_ma": "K/W", "b_ma": "-",
    "alpha_cy": "1/K",
    "k_0": "-", "k_1": "-", "k_2": "-", "k_3": "-",
}


@dataclass(frozen=True)
class LptnParameters:
    """The 22 parameters of the fourth-order LPTN (Table 1)."""

    C_y: float
    C_w: float
    C_t: float
    C_m: float
    R_yw: float
    R_yt: float
    R_wt: float
    R_cy0: float
    R_wm0: float
    a_wm: float
    b_wm: float
    R_tm0: float
    a_tm: float
    b_tm: float
    R_ma0: float
    a_ma: float
    b_ma: float
    alpha_cy: float
    k_0: float
    k_1: float
    k_2: float
    k_3: float

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def as_vector(self) -> list[float]:
        return [getattr(self, n) for n in self.names()]

    @classmethod
    def from_vector(cls, values) -> LptnParameters:
        return cls(**{n: float(v) for n, v in zip(cls.names(), values, strict=True)})

    def with_values(self, **changes: float) -> LptnParameters:
        return replace(self, **changes)


TABLE1 = LptnParameters(
    C_y=3340.0, C_w=5296.0, C_t=3043.0, C_m=6652.0,
    R_yw=0.009, R_yt=0.015, R_wt=0.436, R_cy0=0.004,
    R_wm0=0.665, a_wm=0.492, b_wm=0.968,
    R_tm0=0.484, a_tm=0.094, b_tm=0.200,
    R_ma0=0.314, a_ma=0.036, b_ma=-0.176,
    alpha_cy=-0.009,
    k_0=0.775, k_1=-0.080, k_2=-0.008, k_3=-0.115,
)

TABLE1_REFINED = TABLE1.with_values(
    R_yw=0.00884782, R_yt=0.01489667, R_cy0=0.00444406, a_tm=0.0945, a_ma=0.03562283,
)

PARAMETER_SETS: dict[str, LptnParameters] = {"table1": TABLE1, "table1-refined": TABLE1_REFINED}

# The reference coolant temperature of eq. 16 and the copper temperature coefficient of eqs. 3-4.
COOLANT_REFERENCE_C = 40.0
ALPHA_CU_PER_K = 0.0039


def parameter_set(name: str) -> LptnParameters:
    """Look a parameter set up by name; raises KeyError with the valid names."""
    try:
        return PARAMETER_SETS[name]
    except KeyError:
        raise KeyError(f"unknown parameter set {name!r}; choose one of {', '.join(PARAMETER_SETS)}") from None
