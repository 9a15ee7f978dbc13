"""A thermal network of nodes, conductances (fixed or functions of the operating conditions), boundary links to the
coolant inlet and the ambient, and advection (a fluid carrying heat from one node to the next).

C dx/dt = G(c) x + E(c) u + P, u = [coolant inlet, ambient] (°C), c the conditions (rotor speed, inlet
temperature). Conduction and convection make G symmetric; advection does not (a coolant cell is fed by the one
upstream of it: C_j dT_j/dt = ṁc_p(T_(j-1) - T_j) + ...), so the exact step is the matrix exponential of the
augmented system rather than a symmetric eigendecomposition.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from bench.thermal import portable

INLET, AMBIENT = 0, 1          # columns of E: the boundary temperatures


@dataclass(frozen=True)
class Conditions:
    speed_rpm: float
    coolant_C: float           # inlet temperature (fluid properties)

    @property
    def omega(self) -> float:
        return abs(self.speed_rpm) * np.pi / 30.0


Conductance = float | Callable[[Conditions], float]


@dataclass
class Network:
    names: list[str] = field(default_factory=list)
    caps: list[float] = field(default_factory=list)
    links: list[tuple[int, int, Conductance]] = field(default_factory=list)
    boundary: list[tuple[int, int, Conductance]] = field(default_factory=list)    # (node, INLET|AMBIENT, g)
    # (upstream node or None for the inlet, node, ṁc_p)
    flows: list[tuple[int | None, int, float]] = field(default_factory=list)

    def node(self, name: str, capacitance: float) -> int:
        if name in self.names:
            raise ValueError(f"node {name!r} twice")
        if not capacitance > 0:
            raise ValueError(f"node {name!r} has capacitance {capacitance!r}")
        self.names.append(name)
        self.caps.append(float(capacitance))
        return len(self.names) - 1

    def link(self, i: int, j: int, g: Conductance) -> None:
        self.links.append((i, j, g))

    def to_boundary(self, i: int, which: int, g: Conductance) -> None:
        self.boundary.append((i, which, g))

    def advect(self, upstream: int | None, node: int, mcp: float) -> None:
        self.flows.append((upstream, node, mcp))

    @property
    def size(self) -> int:
        return len(self.names)

    @property
    def capacitances(self) -> np.ndarray:
        return np.array(self.caps)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def matrices(self, cond: Conditions) -> tuple[np.ndarray, np.ndarray]:
        """G (n, n) and E (n, 2) at the conditions."""
        n = self.size
        g = np.zeros((n, n))
        e = np.zeros((n, 2))
        for i, j, gij in self.links:
            v = _value(gij, cond)
            g[i, j] += v
            g[j, i] += v
            g[i, i] -= v
            g[j, j] -= v
        for i, which, gib in self.boundary:
            v = _value(gib, cond)
            g[i, i] -= v
            e[i, which] += v
        for up, node, mcp in self.flows:
            g[node, node] -= mcp
            if up is None:
                e[node, INLET] += mcp
            else:
                g[node, up] += mcp
        return g, e

    def boundary_heat(self, x: np.ndarray, u: Sequence[float], cond: Conditions) -> dict[str, float]:
        """Heat leaving through the boundary links (W) to the inlet's fluid and the ambient, by conduction or
        convection; the fluid's own enthalpy rise is `enthalpy_rise`."""
        out = {"coolant_film": 0.0, "ambient": 0.0}
        for i, which, gib in self.boundary:
            out["ambient" if which == AMBIENT else "coolant_film"] += _value(gib, cond) * (x[i] - u[which])
        return out

    def enthalpy_rise(self, x: np.ndarray, inlet_C: float) -> float:
        """ṁc_p(T_out - T_in) of the fluid (W): the cells no other cell is fed from are the outlets."""
        fed_from = {up for up, _, _ in self.flows if up is not None}
        return float(sum(mcp * (x[node] - inlet_C) for up, node, mcp in self.flows if node not in fed_from))


def _value(g: Conductance, cond: Conditions) -> float:
    return float(g(cond)) if callable(g) else float(g)


def discretize(g: np.ndarray, e: np.ndarray, caps: np.ndarray, h: float) -> np.ndarray:
    """The exact step over h with inputs held: x' = A_d x + B_loss P + B_env u, returned as one (n, 2n + 2) matrix
    [A_d | B_loss | B_env]. A = C⁻¹G, A_d = e^{Ah}; Γ = ∫₀ʰ e^{As} ds = A⁻¹(e^{Ah} - I) (A is invertible: every
    node reaches a boundary), B_loss = ΓC⁻¹, B_env = ΓC⁻¹E. In bench.thermal.portable's arithmetic, not BLAS's:
    a suite motor's profiles are then the same bytes on every machine (scipy's expm and numpy's solve and matmul
    sum in the order of the CPU's OpenBLAS kernel, and the identification amplifies a last bit into a K²)."""
    a = g / caps[:, None]
    a_d = portable.expm(a * h)
    gamma = portable.solve(a, a_d - np.eye(len(caps)))
    return np.hstack([a_d, gamma / caps[None, :], portable.matmul(gamma, e / caps[:, None])])
