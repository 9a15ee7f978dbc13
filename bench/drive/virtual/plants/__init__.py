"""Kinds of thermal plant behind a virtual motor: `virtual_plant.thermal.kind` names one (absent: "lptn4").

- lptn4: the bench's own four-node parameter-varying LPTN with its 22 true parameters (the model class contains the
  truth; every motor file written before the registry is one).
- distributed: a network of dozens of nodes built from the machine's geometry, materials and cooling
  (`bench.drive.virtual.plants.distributed`), which no four-node model can be.

Every module of this package that is not private (`_name`) or a helper listed in HELPERS is a kind and registers
itself on import; `PLANT_KINDS` loads them on first use.

A kind (`PlantKind`) parses and checks its table (`from_table`, one VirtualPlantError sentence per problem) into a
`ThermalPlant`, which
- integrates the profile (`simulate`) given the state-independent inputs of each plant step (`StepInputs`) and the
  true loss model as COMPONENTS (`LossComponents`): copper dc and ac at the reference temperature, the stator iron
  loss, the magnet loss; the kind places them on its nodes (and adds its own losses, e.g. bearings and windage);
- names positions (a node or a weighted mix of nodes) that sensor columns read (`positions`), with a default
  position per canonical signal (`signal_positions`: winding, yoke, tooth, magnet, and for the electrical model
  the copper and magnet temperatures it needs).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from bench.motor.check import Checker
from bench.motor.description import MotorDescription
from dbc.contract import TEMPERATURE_NODES
from target_sim.registry import Registry

DEFAULT_KIND = "lptn4"
# helper modules of this package that are not kinds
HELPERS = ("correlations", "geometry", "materials", "network", "lump")
# the positions the plant's electrical model reads: the copper temperature of the winding resistance and the
# magnet temperature of the flux linkage (keys of signal_positions)
ELECTRICAL_POSITIONS = ("copper", "flux")
# the canonical temperature signals of the bench's dataset every kind maps to a position
CANONICAL_SIGNALS = TEMPERATURE_NODES


@dataclass(frozen=True, eq=False)
class LossComponents:
    """The true loss model as components (bench.drive.virtual.simulation.VirtualPlant.loss_components).

    evaluate(i_d0, i_q0, di_d, di_q, x_ac, x_fe, x_m, th_m, th_iron) -> (p_dc0, p_ac0, load, p_s, p_m, r):
    copper dc and ac at copper_reference_C (three phases), the copper load factor both are multiplied by, the
    stator iron loss at iron temperature th_iron, the magnet loss at magnet temperature th_m, and I/I_max.
    A copper node at ϑ carries (share_dc·p_dc0·(1 + α(ϑ - ϑ_ref)) + share_ac·p_ac0/(1 + α(ϑ - ϑ_ref)))·load.
    Arithmetic operators only: it runs on floats and arrays alike.
    """

    evaluate: Callable
    copper_reference_C: float
    copper_alpha_per_K: float
    # the names of the per-step inputs evaluate takes first, in order (keys of StepInputs.op)
    INPUTS: ClassVar[tuple[str, ...]] = ("i_d0", "i_q0", "di_d", "di_q", "x_ac", "x_fe", "x_m")


@dataclass(frozen=True, eq=False)
class StepInputs:
    """The state-independent inputs of each plant step (arrays of n steps, taken at the steps' midpoints)."""

    op: Mapping[str, np.ndarray]      # the operating point (VirtualPlant.operating_point): currents, ratios
    speed_rpm: np.ndarray
    coolant_C: np.ndarray             # coolant inlet (the stand's conditioning)
    ambient_C: np.ndarray             # test-cell air
    step_s: float

    @property
    def steps(self) -> int:
        return len(self.speed_rpm)


@dataclass(frozen=True, eq=False)
class ThermalRun:
    """States (°C) at the sample times (every stride-th step from the start) and the loss groups of the step
    starting at each of them but the last (W, columns named by the plant's loss_names)."""

    states: np.ndarray
    losses: np.ndarray


@dataclass(frozen=True)
class Position:
    """A place of the plant a sensor reads: node indices and weights summing to 1."""

    nodes: tuple[int, ...]
    weights: tuple[float, ...]

    def read(self, states: np.ndarray) -> np.ndarray:
        states = np.asarray(states, dtype=float)
        if len(self.nodes) == 1:
            return states[..., self.nodes[0]].copy()
        out = states[..., self.nodes[0]] * self.weights[0]   # summed in order, element by element: no BLAS
        for node, weight in zip(self.nodes[1:], self.weights[1:], strict=True):
            out = out + states[..., node] * weight
        return out


def mix(nodes, weights=None) -> Position:
    """A position over nodes, weighted (default: equal weights), the weights normalized to sum 1."""
    nodes = tuple(int(i) for i in nodes)
    w = np.ones(len(nodes)) if weights is None else np.asarray(weights, dtype=float)
    return Position(nodes, tuple(float(v) for v in w / w.sum()))


class ThermalPlant:
    """A kind's plant, parsed from its table. Subclasses set the attributes and implement simulate."""

    kind: ClassVar[str]
    node_names: tuple[str, ...]
    positions: Mapping[str, Position]
    signal_positions: Mapping[str, str]    # canonical signal (and ELECTRICAL_POSITIONS, coolant_out) -> position
    loss_names: tuple[str, ...]

    def simulate(self, steps: StepInputs, components: LossComponents, start_C: float, stride: int) -> ThermalRun:
        raise NotImplementedError

    def read(self, states: np.ndarray, position: str) -> np.ndarray:
        return self.positions[position].read(states)

    def describe(self) -> dict[str, Any]:
        """What a report shows of the plant."""
        return {"kind": self.kind, "nodes": len(self.node_names)}


class PlantKind:
    """One kind of thermal plant: its name and how its `virtual_plant.thermal` table is read."""

    name: ClassVar[str]
    summary: ClassVar[str]

    def from_table(self, check: Checker, table: Mapping[str, Any], motor: MotorDescription) -> ThermalPlant:
        """The plant of the table (check's prefix is "virtual_plant."; keys under "thermal.")."""
        raise NotImplementedError


class _PlantRegistry(Registry[PlantKind]):
    def _load(self) -> None:   # the helper modules are no kinds: import only the kinds' modules
        if self._loaded:
            return
        self._loaded = True
        import importlib
        import pkgutil

        package = importlib.import_module(self._package)
        for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
            if not info.name.startswith("_") and info.name not in HELPERS:
                importlib.import_module(f"{self._package}.{info.name}")


PLANT_KINDS: Registry[PlantKind] = _PlantRegistry("virtual plant kind", __name__, first=(DEFAULT_KIND,))


def register(kind: PlantKind) -> PlantKind:
    return PLANT_KINDS.register(kind.name, kind)


def thermal_plant(check: Checker, table: Mapping[str, Any], motor: MotorDescription) -> ThermalPlant:
    """The plant of virtual_plant.thermal: its kind (default lptn4) reads the rest; an unknown kind is one sentence."""
    thermal = check.table(table, "thermal")
    kind = thermal.get("kind", DEFAULT_KIND)
    if not isinstance(kind, str) or kind not in PLANT_KINDS:
        check.fail("thermal.kind", f"{kind!r} is not one of {', '.join(PLANT_KINDS.names())}")
    return PLANT_KINDS[kind].from_table(check, thermal, motor)
