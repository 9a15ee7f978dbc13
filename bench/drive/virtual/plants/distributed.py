"""distributed: a thermal network built from the machine's geometry, materials and cooling (docs/plant.md).

Nodes, per axial slice s of the active part (slices >= 4), counted from the A (drive) side:
  winding slot bottom w_bot[s] and slot top w_top[s] (the half near the slot opening), tooth tip tip[s] and tooth
  body body[s], yoke inner yoke_in[s] and yoke back yoke_back[s], housing housing[s] (the stator hub of an outer
  rotor), coolant cell coolant[s] (water in the jacket, or air between the fins), rotor iron rotor[s] and magnet
  segment magnet[s];
and once: end windings ew_a, ew_b, end-space air air_a, air_b, end caps cap_a, cap_b, bearings brg_a, brg_b, shaft.
A water-jacket inner-rotor machine with 4 slices has 10·4 + 9 = 49 nodes.

Paths (conductance k·A/L, radial ln(r2/r1)/(2πkL), series of the half-layers between node centres):
  radially coolant - housing - (contact gap) - yoke back - yoke inner - tooth body - tooth tip - air gap - rotor
  (inner rotor: rotor - magnet, rotor - shaft); outer rotor: coolant - hub - yoke back - yoke inner - teeth - air
  gap - magnets - rotor back iron - outside air;
  slot: w_bot - w_top, w_bot - yoke inner (slot bottom), both - tooth body (slot sides), w_top - tooth tip (slot
  opening), each through the equivalent slot conductivity (impregnated winding) plus the liner;
  axially between slices in every layer (laminations with their low axial conductivity; copper along the
  conductors; segments of the magnets glued), slot copper to the end windings;
  end spaces: end windings, end caps, housing ends and rotor ends to the end-space air (h = k1(1 + k2·v^k3));
  housing ends - end caps - bearings - shaft; rotor - shaft;
  boundary: coolant cells carried downstream by ṁc_p from the inlet (A to B), housing and end caps to ambient.
Losses: copper per node by its conductor length (dc ∝ 1 + αΔϑ, ac ∝ 1/(1 + αΔϑ) at the node's own temperature),
the ac share concentrated at the slot opening and weaker in the end windings; iron split between teeth (tips
carrying the harmonics) and yoke by flux density from the geometry; magnet loss over the segments, more at the
ends; bearing friction T_f·ω on the bearings; windage (Couette, ∝ ω³ r⁴ L) in the air gap.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from bench.drive.virtual.plants import (
    LossComponents,
    PlantKind,
    StepInputs,
    ThermalPlant,
    ThermalRun,
    mix,
    register,
)
from bench.drive.virtual.plants.correlations import (
    air,
    airgap_h,
    end_space_h,
    fin_efficiency,
    flat_plate_nu,
    gnielinski_nu,
    rotating_cylinder_h,
    slot_conductivity,
    water,
    windage_W,
)
from bench.drive.virtual.plants.geometry import Geometry, annulus, bar, disc, film, geometry, radial, series
from bench.drive.virtual.plants.materials import AXIAL, materials
from bench.drive.virtual.plants.network import AMBIENT, Conditions, Network, discretize
from bench.motor.check import Checker
from bench.motor.description import MotorDescription
from bench.thermal import portable

KEYS = ("kind", "rotor", "slices", "geometry", "materials", "cooling", "end_space", "losses")
ROTORS = ("inner", "outer")
COOLING_KINDS = ("water_jacket", "air")
COOLING_KEYS = {
    "water_jacket": {"flow_l_min": (None, 0.1, 500.0), "turns": (None, 1.0, 200.0),
                     "channel_width_mm": (None, 1.0, 500.0), "channel_height_mm": (None, 1.0, 100.0),
                     "ambient_h_W_m2K": (8.0, 0.0, 100.0)},
    "air": {"air_speed_m_s": (None, 0.1, 60.0), "fins": (None, 4.0, 400.0), "fin_height_mm": (None, 1.0, 200.0),
            "fin_thickness_mm": (None, 0.3, 20.0), "ambient_h_W_m2K": (8.0, 0.0, 100.0)},
}
END_SPACE = {"k1": (15.0, 1.0, 100.0), "k2": (0.4, 0.0, 5.0), "k3": (0.9, 0.1, 2.0)}    # Boglietti 2009, Staton
LOSS_KEYS = {
    "ac_top_share": (0.75, 0.0, 1.0),           # share of the slot's ac copper loss in the top (opening) half
    "end_ac_factor": (0.3, 0.0, 2.0),           # ac loss per conductor length in the end windings / in the slot
    "tip_loss_factor": (1.5, 0.5, 5.0),         # tooth-tip iron loss density / tooth body (slot harmonics)
    "magnet_end_factor": (1.3, 1.0, 3.0),       # eddy loss of an end segment / a middle one (3-D end effects)
    "bearing_friction_Nm": (0.05, 0.0, 10.0),   # friction torque per bearing
    "windage_factor": (1.0, 0.0, 10.0),         # × the smooth-cylinder Couette windage (slots, IPM bridges)
}
MIN_SLICES, MAX_SLICES = 4, 20
INTERNAL_AIR_C = 60.0        # air properties in the air gap and end spaces (they vary by a few % over 40-100 °C)
GLUE_MM, GLUE_K = 0.1, 0.3   # magnet pockets and segment joints: a resin layer
SHRINK_FIT_GAP_MM = 0.01     # rotor on the shaft, as an equivalent air gap
SPEED_GRID_RPM = 250.0       # the exact steps are tabulated on this speed grid (bilinear in speed and inlet)
COOLANT_GRID_K = 5.0         # and this inlet temperature grid (water properties)
LOSS_NAMES = ("yoke", "winding", "tooth", "magnet", "mechanical")
FLUID_REFERENCE_C = 40.0     # the coolant's ṁc_p and heat capacity (its h follows the inlet temperature)
# the canonical signals' positions: the end winding on the B side (farther from the inlet, where test benches put
# the hot-spot thermocouple), the yoke back, the tooth tip and the magnets at mid-stack; the electrical model's
# copper (resistance: the conductor-length mean) and flux (all magnet segments); the coolant outlet
SIGNAL_POSITIONS = {"winding": "winding.end_b", "yoke": "yoke.back", "tooth": "tooth.tip", "magnet": "magnet.mid",
                    "copper": "winding.mean", "flux": "magnet", "coolant_out": "coolant.out"}


def _numbers(check: Checker, table: Any, key: str, spec: Mapping[str, tuple]) -> dict[str, float]:
    if table is None:
        table = {}
    if not isinstance(table, dict):
        check.fail(f"thermal.{key}", f"must be a table of {', '.join(spec)}")
    check.only(table, f"thermal.{key}", spec)
    return {name: check.number(table, name, f"thermal.{key}.", low=low, high=high, default=default)
            for name, (default, low, high) in spec.items()}


@dataclass(frozen=True)
class Cooling:
    kind: str
    values: Mapping[str, float]


class DistributedPlant(ThermalPlant):
    kind = "distributed"
    loss_names = LOSS_NAMES

    def __init__(self, rotor: str, slices: int, geo: Geometry, mats: dict, cooling: Cooling,
                 end_space: Mapping[str, float], placement: Mapping[str, float], pole_pairs: int):
        self.rotor, self.slices, self.geo, self.mats, self.pole_pairs = rotor, slices, geo, mats, pole_pairs
        self.cooling, self.end_space, self.placement = cooling, end_space, placement
        self.net = Network()
        self._tables: dict[float, dict[tuple[int, int], np.ndarray]] = {}    # step -> grid corner -> exact step
        self._build()
        self.node_names = tuple(self.net.names)
        self._positions()
        self._losses()

    def _radii(self) -> dict[str, float]:
        return stator_radii(self.rotor, self.geo)

    def _rotor_radii(self) -> dict[str, float]:
        return rotor_radii(self.rotor, self.geo)

    # ------------------------------------------------------------------ the network
    def _build(self) -> None:
        d = self._dimensions()
        self._nodes(d)
        for s in range(self.slices):
            self._stator_links(d, s)
            self._rotor_links(s, d.length, d.rr, d.h_gap, d.r_mid_tip, d.r)
        self._axial_links(d)
        upstream = None                     # the coolant, carried from the inlet at A to the outlet at B
        for cell in self.ids["coolant"]:
            self.net.advect(upstream, cell, d.mcp)
            upstream = cell
        for side in (0, 1):
            self._end_links(d, side)
        if self.rotor == "outer":      # the out-runner's rotor hangs on the shaft by its B-side end disc
            self.net.link(self.ids["rotor"][-1], self.ids["shaft"][0],
                          disc(d.k_al, self.geo.end_cap_thickness, self.geo.shaft_diameter / 2.0, d.rr["magnet_out"]))
        self.windage = (d.rotor_surface, self.geo.stack_length, self.geo.airgap, d.inner_air)

    def _dimensions(self) -> SimpleNamespace:
        """What the parts of the network share: radii, lengths, sections, properties, varying coefficients."""
        g, m = self.geo, self.mats
        r, rr = self._radii(), self._rotor_radii()
        fill = g.slot_fill
        d = SimpleNamespace(r=r, rr=rr, length=g.stack_length / self.slices,
                            ext=g.end_winding_overhang + g.end_space, inner_air=air(INTERNAL_AIR_C),
                            k_fe=m["lamination"]["k_W_mK"], k_ax=m["lamination"][AXIAL],
                            k_cu=m["copper"]["k_W_mK"], k_al=m["aluminium"]["k_W_mK"], k_m=m["magnet"]["k_W_mK"],
                            rc={name: v["rho_kg_m3"] * v["c_J_kgK"] for name, v in m.items()},
                            k_eq=slot_conductivity(fill, m["copper"]["k_W_mK"], m["impregnation"]["k_W_mK"]))
        d.rc_slot = fill * d.rc["copper"] + (1.0 - fill) * d.rc["impregnation"]
        d.r_mid_tip = (r["gap"] + r["tip"]) / 2.0
        d.r_mid_body = (r["tip"] + r["slot"]) / 2.0
        d.r_yoke_q1 = (r["slot"] + r["yoke_mid"]) / 2.0
        d.r_yoke_q3 = (r["yoke_mid"] + r["back"]) / 2.0
        d.r_house_mid = (r["back"] + r["housing"]) / 2.0
        d.slot_area = (1.0 - g.tooth_width_ratio) * annulus(r["tip"], r["slot"]) / g.slots
        d.copper_depth = g.slot_depth - g.tooth_tip
        d.slot_width = d.slot_area / d.copper_depth
        d.cu_layer = fill * d.slot_area * g.slots / 2.0          # copper section of one slot half, all slots
        d.rotor_surface = rr["surface"]
        shaft_r = g.shaft_diameter / 2.0
        if self.rotor == "inner":
            d.magnet_section = g.magnet_width_ratio * annulus(rr["magnet_in"], rr["magnet_out"])
            d.rotor_section = annulus(shaft_r, rr["surface"]) - d.magnet_section
        else:
            d.magnet_section = g.magnet_width_ratio * annulus(rr["surface"], rr["magnet_out"])
            d.rotor_section = annulus(rr["magnet_out"], rr["back"])
        d.r_bearing = g.bearing_outer_diameter / 2.0
        d.r_cap_out = r["housing"] if self.rotor == "inner" else d.r_house_mid
        d.cap_area = annulus(d.r_bearing, d.r_cap_out)
        r_air_mean = (r["gap"] + d.rotor_surface) / 2.0
        es = self.end_space
        d.h_gap = self._memo(lambda c: airgap_h(c.omega, r_air_mean, g.airgap, d.inner_air))
        d.h_end = self._memo(lambda c: end_space_h(c.omega * d.rotor_surface, es["k1"], es["k2"], es["k3"]))
        d.film_per_m, d.mcp, d.cool_cap = self._coolant(r)
        d.h_amb = self.cooling.values["ambient_h_W_m2K"]
        return d

    def _nodes(self, d: SimpleNamespace) -> None:
        g, net, r, rc, length = self.geo, self.net, d.r, d.rc, d.length
        per_slice = {
            "w_bot": d.rc_slot * d.slot_area * g.slots / 2.0, "w_top": d.rc_slot * d.slot_area * g.slots / 2.0,
            "tip": rc["lamination"] * g.tip_width_ratio * annulus(r["gap"], r["tip"]),
            "body": rc["lamination"] * g.tooth_width_ratio * annulus(r["tip"], r["slot"]),
            "yoke_in": rc["lamination"] * annulus(r["slot"], r["yoke_mid"]),
            "yoke_back": rc["lamination"] * annulus(r["yoke_mid"], r["back"]),
            "housing": rc["aluminium"] * annulus(r["back"], r["housing"]), "coolant": d.cool_cap,
            "rotor": rc["lamination"] * d.rotor_section, "magnet": rc["magnet"] * d.magnet_section}
        ids: dict[str, list[int]] = {name: [] for name in per_slice}
        for s in range(self.slices):
            for name, cap_per_m in per_slice.items():
                ids[name].append(net.node(f"{name}[{s}]", cap_per_m * length))
        end_cu_cap = d.rc_slot * d.slot_area * g.slots * g.end_turn_length
        ids["ew"] = [net.node(side, end_cu_cap) for side in ("ew_a", "ew_b")]
        air_cap = d.inner_air.rho * d.inner_air.cp * annulus(r["back"], d.rotor_surface) * d.ext
        ids["air"] = [net.node(side, air_cap) for side in ("air_a", "air_b")]
        ids["cap"] = [net.node(side, rc["aluminium"] * d.cap_area * g.end_cap_thickness) for side in ("cap_a", "cap_b")]
        bearing_cap = rc["shaft"] * annulus(g.shaft_diameter / 2.0, d.r_bearing) * g.bearing_width * 0.5
        ids["bearing"] = [net.node(side, bearing_cap) for side in ("brg_a", "brg_b")]
        shaft_len = g.stack_length + 2.0 * (d.ext + g.end_cap_thickness)
        ids["shaft"] = [net.node("shaft", rc["shaft"] * math.pi * (g.shaft_diameter / 2.0) ** 2 * shaft_len)]
        self.ids = ids

    def _stator_links(self, d: SimpleNamespace, s: int) -> None:
        """Radially through slice s: coolant - housing - contact gap - yoke - teeth, and the slot."""
        g, net, ids, r, k_fe = self.geo, self.net, self.ids, d.r, d.k_fe
        ft, ftip = g.tooth_width_ratio, g.tip_width_ratio

        def half(k, a, b, share=1.0):
            return radial(k, d.length, a, b, share)

        def liner(area):
            return film(self.mats["liner"]["k_W_mK"] / g.slot_liner, area)

        tip, body, yin, yb = ids["tip"][s], ids["body"][s], ids["yoke_in"][s], ids["yoke_back"][s]
        wb, wt, hs, cl = ids["w_bot"][s], ids["w_top"][s], ids["housing"][s], ids["coolant"][s]
        net.link(tip, body, series(half(k_fe, d.r_mid_tip, r["tip"], ftip), half(k_fe, r["tip"], d.r_mid_body, ft)))
        net.link(body, yin, series(half(k_fe, d.r_mid_body, r["slot"], ft), half(k_fe, r["slot"], d.r_yoke_q1)))
        net.link(yin, yb, series(half(k_fe, d.r_yoke_q1, r["yoke_mid"]), half(k_fe, r["yoke_mid"], d.r_yoke_q3)))
        contact = (film(d.inner_air.k / g.contact_gap, 2.0 * math.pi * r["back"] * d.length)
                   if g.contact_gap > 0 else math.inf)
        net.link(yb, hs, series(half(k_fe, d.r_yoke_q3, r["back"]), contact, half(d.k_al, r["back"], d.r_house_mid)))
        net.link(hs, cl, self._scaled(d.film_per_m, d.length))
        if self.cooling.kind == "water_jacket" and self.rotor == "inner" and d.h_amb > 0:
            net.to_boundary(hs, AMBIENT, film(d.h_amb, 2.0 * math.pi * r["housing"] * d.length))
        # the slot: equivalent conductivity across the copper, then the liner
        opening = d.slot_width * d.length * g.slots
        sides = 2.0 * (d.copper_depth / 2.0) * d.length * g.slots
        net.link(wb, wt, bar(d.k_eq, opening, d.copper_depth / 2.0))
        net.link(wb, yin, series(bar(d.k_eq, opening, d.copper_depth / 4.0), liner(opening),
                                 half(k_fe, r["slot"], d.r_yoke_q1)))
        net.link(wt, tip, series(bar(d.k_eq, opening, d.copper_depth / 4.0), liner(opening),
                                 half(k_fe, d.r_mid_tip, r["tip"], ftip)))
        for w in (wb, wt):
            net.link(w, body, series(bar(d.k_eq, sides, d.slot_width / 4.0), liner(sides)))

    def _axial_links(self, d: SimpleNamespace) -> None:
        """Between the slices of every layer: laminations with their low axial conductivity, copper along the
        conductors, the housing around the channel, glued magnet segments."""
        g, r, k_ax = self.geo, d.r, d.k_ax
        sections = {"tip": k_ax * g.tip_width_ratio * annulus(r["gap"], r["tip"]),
                    "body": k_ax * g.tooth_width_ratio * annulus(r["tip"], r["slot"]),
                    "yoke_in": k_ax * annulus(r["slot"], r["yoke_mid"]),
                    "yoke_back": k_ax * annulus(r["yoke_mid"], r["back"]),
                    "housing": d.k_al * (annulus(r["back"], r["housing"]) - self._channel_section()),
                    "w_bot": d.k_cu * d.cu_layer, "w_top": d.k_cu * d.cu_layer, "rotor": k_ax * d.rotor_section}
        half_segment = bar(d.k_m, d.magnet_section, d.length / 2.0)
        joint = series(half_segment, _glue(d.magnet_section), half_segment)
        for s in range(self.slices - 1):
            for name, ka in sections.items():
                self.net.link(self.ids[name][s], self.ids[name][s + 1], ka / d.length)
            self.net.link(self.ids["magnet"][s], self.ids["magnet"][s + 1], joint)

    def _end_links(self, d: SimpleNamespace, side: int) -> None:
        """One end (0: A, 1: B): end winding, end-space air, end cap, bearing, shaft."""
        g, net, ids, r = self.geo, self.net, self.ids, d.r
        s = 0 if side == 0 else self.slices - 1
        ew, space, cap, bearing = ids["ew"][side], ids["air"][side], ids["cap"][side], ids["bearing"][side]
        for w in (ids["w_bot"][s], ids["w_top"][s]):   # to the end winding's MEAN temperature: heat arising
            # uniformly along a half end turn (ℓ/2) rises on average by a third of (ℓ/2)·Q/(kA) above its root
            net.link(w, ew, d.k_cu * d.cu_layer / (d.length / 2.0 + g.end_turn_length / 6.0))
        ew_area = 2.0 * (2.0 * math.pi * d.r_mid_body * g.end_winding_overhang)        # inner and outer faces
        rotor_face = d.rotor_section + d.magnet_section
        for node, area in ((ew, ew_area), (cap, d.cap_area), (ids["housing"][s], 2.0 * math.pi * r["back"] * d.ext),
                           (ids["rotor"][s], rotor_face)):
            net.link(node, space, self._scaled(d.h_end, area))
        r_cap_mid = math.sqrt(d.r_bearing * d.r_cap_out)
        net.link(ids["housing"][s], cap, series(bar(d.k_al, annulus(r["back"], r["housing"]), d.length / 2.0 + d.ext),
                                                disc(d.k_al, g.end_cap_thickness, r_cap_mid, d.r_cap_out)))
        if d.h_amb > 0:
            net.to_boundary(cap, AMBIENT, film(d.h_amb, math.pi * d.r_cap_out ** 2))
        bearing_g = film(d.inner_air.k / g.bearing_gap, 2.0 * math.pi * d.r_bearing * g.bearing_width)
        net.link(cap, bearing, series(disc(d.k_al, g.end_cap_thickness, d.r_bearing, r_cap_mid), 2.0 * bearing_g))
        shaft_bar = bar(self.mats["shaft"]["k_W_mK"], math.pi * (g.shaft_diameter / 2.0) ** 2,
                        g.stack_length / 2.0 + d.ext + g.end_cap_thickness / 2.0)
        net.link(bearing, ids["shaft"][0], series(2.0 * bearing_g, shaft_bar))

    def _rotor_links(self, s: int, length: float, rr: dict, h_gap_fn, r_mid_tip: float, r: dict) -> None:
        """Air gap, magnet and rotor iron of slice s, and the rotor's way out (shaft, or the outside air)."""
        g, m, net, ids = self.geo, self.mats, self.net, self.ids
        tip, rotor, magnet = ids["tip"][s], ids["rotor"][s], ids["magnet"][s]
        k_fe, k_m = m["lamination"]["k_W_mK"], m["magnet"]["k_W_mK"]
        fm = g.magnet_width_ratio
        gap_area = 2.0 * math.pi * rr["surface"] * length
        tip_half = radial(k_fe, length, r_mid_tip, r["tip"], g.tip_width_ratio)
        shaft_r = g.shaft_diameter / 2.0
        if self.rotor == "inner" and g.magnet_depth > 0:       # interior magnets: the air gap meets rotor iron
            net.link(tip, rotor, self._gap(h_gap_fn, gap_area, tip_half,
                                           radial(k_fe, length, rr["magnet_out"], rr["surface"])))
            faces = 2.0 * fm * 2.0 * math.pi * (rr["magnet_in"] + rr["magnet_out"]) / 2.0 * length
            net.link(magnet, rotor, series(bar(k_m, faces, g.magnet_thickness / 2.0), _glue(faces)))
        else:                                                  # surface magnets face the air gap
            net.link(tip, magnet, self._gap(h_gap_fn, fm * gap_area, tip_half,
                                            2.0 * radial(k_m, length, rr["surface"], rr["magnet_out"], fm)))
            net.link(tip, rotor, self._gap(h_gap_fn, (1.0 - fm) * gap_area, tip_half))
            face = fm * 2.0 * math.pi * rr["magnet_out"] * length
            net.link(magnet, rotor, series(bar(k_m, face, g.magnet_thickness / 2.0), _glue(face)))
        if self.rotor == "inner":
            inner = rr["magnet_in"] if g.magnet_depth > 0 else rr["magnet_out"]
            shrink = film(air(INTERNAL_AIR_C).k / (SHRINK_FIT_GAP_MM * 1e-3), 2.0 * math.pi * shaft_r * length)
            net.link(rotor, ids["shaft"][0], series(radial(k_fe, length, shaft_r, inner), shrink))
        else:                                                  # an out-runner's back iron in the outside air
            h_amb = self.cooling.values["ambient_h_W_m2K"]
            outside = 2.0 * math.pi * rr["back"] * length
            outer_air = air(INTERNAL_AIR_C)
            net.to_boundary(rotor, AMBIENT, self._memo(
                lambda c: film(h_amb + rotating_cylinder_h(c.omega, rr["back"], outer_air), outside)))

    # ------------------------------------------------------------------ cooling
    def _coolant(self, r: dict):
        """(housing-to-fluid conductance per metre of stack, W/(K m), a number or a function of the conditions;
        the fluid's ṁc_p, W/K; its heat capacity per metre, J/(K m))."""
        c, g = self.cooling.values, self.geo
        if self.cooling.kind == "water_jacket":
            # one helical channel wound from A to B: a (radial) × b (axial), `turns` turns over the stack, in the
            # middle of the housing; the walls toward the stator (inner wall and both sides) take the heat
            a, b, turns = c["channel_height_mm"] * 1e-3, c["channel_width_mm"] * 1e-3, c["turns"]
            d_h = 2.0 * a * b / (a + b)
            flow = c["flow_l_min"] / 60000.0
            v = flow / (a * b)
            path_per_m = turns * 2.0 * math.pi * (r["back"] + r["housing"]) / 2.0 / g.stack_length
            wet = (b + 2.0 * a) * path_per_m

            def per_m(cond: Conditions) -> float:
                w = water(cond.coolant_C)
                nu = gnielinski_nu(w.rho * v * d_h / w.mu, w.pr)
                return nu * w.k / d_h * wet

            ref = water(FLUID_REFERENCE_C)
            return self._memo(per_m), ref.rho * flow * ref.cp, ref.rho * ref.cp * a * b * path_per_m
        fins, height, thick = c["fins"], c["fin_height_mm"] * 1e-3, c["fin_thickness_mm"] * 1e-3
        r_out = r["housing"]
        pitch_gap = 2.0 * math.pi * r_out / fins - thick
        flow_area = fins * height * pitch_gap
        path = g.stack_length + 2.0 * (g.end_winding_overhang + g.end_space)
        k_al = self.mats["aluminium"]["k_W_mK"]

        def per_m_air(cond: Conditions) -> float:
            f = air(cond.coolant_C)
            h = flat_plate_nu(c["air_speed_m_s"] * path / f.nu, f.pr) * f.k / path
            eta = fin_efficiency(h, k_al, thick, height)
            return h * (fins * 2.0 * height * eta + 2.0 * math.pi * r_out - fins * thick)

        ref = air(FLUID_REFERENCE_C)
        return (self._memo(per_m_air), ref.rho * c["air_speed_m_s"] * flow_area * ref.cp,
                ref.rho * ref.cp * flow_area)

    def _channel_section(self) -> float:
        """The housing's axial section the channel interrupts: the channel's radial band, where the turns cover it."""
        c, r = self.cooling.values, self._radii()
        if self.cooling.kind != "water_jacket":
            return 0.0
        r_ch, a = (r["back"] + r["housing"]) / 2.0, c["channel_height_mm"] * 1e-3
        covered = min(1.0, c["turns"] * c["channel_width_mm"] * 1e-3 / self.geo.stack_length)
        return covered * annulus(r_ch - a / 2.0, r_ch + a / 2.0)

    # ------------------------------------------------------------------ positions and losses
    def _positions(self) -> None:
        ids, n = self.ids, self.slices
        mid = [n // 2 - 1, n // 2] if n % 2 == 0 else [n // 2]
        at = lambda name: [ids[name][s] for s in mid]        # noqa: E731
        copper = ids["w_bot"] + ids["w_top"] + ids["ew"]
        g = self.geo
        slot_len = g.stack_length / n / 2.0
        self.copper_nodes = copper
        self.copper_length = np.array([slot_len] * (2 * n) + [g.end_turn_length] * 2)
        self.positions = {
            "winding.slot_bottom": mix(at("w_bot")), "winding.slot_top": mix(at("w_top")),
            "winding.slot_mid": mix(at("w_bot") + at("w_top")),
            "winding.end_a": mix([ids["ew"][0]]), "winding.end_b": mix([ids["ew"][1]]),
            "winding.mean": mix(copper, self.copper_length),
            "tooth.tip": mix(at("tip")), "tooth.body": mix(at("body")),
            "yoke.inner": mix(at("yoke_in")), "yoke.back": mix(at("yoke_back")),
            "housing": mix(at("housing")), "coolant.out": mix([ids["coolant"][-1]]),
            "magnet": mix(ids["magnet"]), "magnet.mid": mix(at("magnet")),
            "magnet.end_a": mix([ids["magnet"][0]]), "magnet.end_b": mix([ids["magnet"][-1]]),
            "rotor": mix(at("rotor")), "shaft": mix(ids["shaft"]),
            "bearing.a": mix([ids["bearing"][0]]), "bearing.b": mix([ids["bearing"][1]]),
            "end_cap.a": mix([ids["cap"][0]]), "end_cap.b": mix([ids["cap"][1]]),
            "end_space.a": mix([ids["air"][0]]), "end_space.b": mix([ids["air"][1]]),
        }
        self.signal_positions = dict(SIGNAL_POSITIONS)

    def _losses(self) -> None:
        """Where each loss component goes: fixed shares over the nodes (they sum to 1 per component)."""
        g, p, ids, n = self.geo, self.placement, self.ids, self.slices
        size = self.net.size
        r = self._radii()
        # copper: dc by conductor length; ac by length, more at the slot opening, less in the end windings
        slot = g.stack_length / n
        top = p["ac_top_share"]
        self.dc_share = self.copper_length / self.copper_length.sum()
        ac = np.array([slot * (1.0 - top)] * n + [slot * top] * n + [g.end_turn_length * p["end_ac_factor"]] * 2)
        self.ac_share = ac / ac.sum()
        # iron: loss density ∝ B²; B_tooth = B_gap / (tooth share), B_yoke = B_gap·π r_g / (2 p h_yoke)
        v_tip = g.tip_width_ratio * annulus(r["gap"], r["tip"])
        v_body = g.tooth_width_ratio * annulus(r["tip"], r["slot"])
        v_yoke_in, v_yoke_back = annulus(r["slot"], r["yoke_mid"]), annulus(r["yoke_mid"], r["back"])
        b_yoke = math.pi * r["gap"] / (2.0 * self.pole_pairs * r["yoke"])
        weights = {"tip": v_tip * p["tip_loss_factor"] / g.tip_width_ratio ** 2,
                   "body": v_body / g.tooth_width_ratio ** 2,
                   "yoke_in": v_yoke_in * b_yoke ** 2, "yoke_back": v_yoke_back * b_yoke ** 2}
        total = sum(weights.values())
        self.iron = np.zeros(size)
        for name, w in weights.items():
            self.iron[ids[name]] = w / total / n
        self.yoke_share = (weights["yoke_in"] + weights["yoke_back"]) / total
        magnet = np.ones(n)
        magnet[[0, -1]] = p["magnet_end_factor"]
        self.magnet = np.zeros(size)
        self.magnet[ids["magnet"]] = magnet / magnet.sum()
        self.bearing = np.zeros(size)
        self.bearing[ids["bearing"]] = 1.0          # each bearing its own friction
        self.wind = np.zeros(size)                  # windage heats the air gap: half stator, half rotor
        self.wind[ids["tip"]] = 0.5 / n
        self.wind[ids["rotor"]] += 0.5 / n
        iron_nodes = ids["tip"] + ids["body"] + ids["yoke_in"] + ids["yoke_back"]
        caps = self.net.capacitances
        self.iron_position = mix(iron_nodes, caps[iron_nodes])      # the iron temperature of the iron loss

    def mechanical(self, speed_rpm) -> tuple[np.ndarray, np.ndarray]:
        """(friction of ONE bearing, windage) in W at the speeds."""
        omega = np.abs(np.asarray(speed_rpm, dtype=float)) * math.pi / 30.0
        radius, length, gap, fluid = self.windage
        wind = np.array([windage_W(w, radius, length, gap, fluid) for w in np.ravel(omega)]).reshape(omega.shape)
        return self.placement["bearing_friction_Nm"] * omega, self.placement["windage_factor"] * wind

    def placer(self, components: LossComponents):
        """place(x, inputs, bearing_W, windage_W) -> (node losses P, loss groups): the loss components at the
        nodes' temperatures x, where they arise."""
        evaluate = components.evaluate
        ref, alpha = components.copper_reference_C, components.copper_alpha_per_K
        cu_idx = np.array(self.copper_nodes)
        dc, ac = self.dc_share, self.ac_share
        iron, magnet, bearing, wind = self.iron, self.magnet, self.bearing, self.wind
        flux, fe = self.positions[SIGNAL_POSITIONS["flux"]], self.iron_position
        m_idx, m_w = list(flux.nodes), np.array(flux.weights)
        fe_idx, fe_w = list(fe.nodes), np.array(fe.weights)
        yoke_share = self.yoke_share

        def place(x, inputs, p_bearing: float, p_wind: float):
            th_m = portable.dot(x[m_idx], m_w)
            th_fe = portable.dot(x[fe_idx], fe_w)
            p_dc0, p_ac0, load, p_s, p_m, _ = evaluate(*inputs, th_m, th_fe)
            cu = 1.0 + alpha * (x[cu_idx] - ref)
            p_cu = (p_dc0 * dc * cu + p_ac0 * ac / cu) * load
            p = iron * p_s + magnet * p_m + bearing * p_bearing + wind * p_wind
            p[cu_idx] += p_cu
            groups = (yoke_share * p_s, math.fsum(p_cu), (1.0 - yoke_share) * p_s, p_m,
                      2.0 * p_bearing + p_wind)
            return p, groups

        return place

    # ------------------------------------------------------------------ integration
    def matrices(self, speed_rpm: float, coolant_C: float) -> tuple[np.ndarray, np.ndarray]:
        """G and E of the network at a speed and inlet temperature."""
        return self.net.matrices(Conditions(float(speed_rpm), float(coolant_C)))

    def cells(self, speeds, coolants, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The exact steps at the grid corners around each (speed, inlet) point, bilinear in both: (table (k, n,
        2n + 2) of the corners used, corner indices (N, 4), weights (N, 4)). The grid is fixed (multiples of
        SPEED_GRID_RPM and COOLANT_GRID_K) and its corners are computed once per plant and step, when first
        needed."""
        speeds, coolants = np.abs(np.asarray(speeds, dtype=float)), np.asarray(coolants, dtype=float)
        i_s = np.floor(speeds / SPEED_GRID_RPM).astype(int)
        w_s = speeds / SPEED_GRID_RPM - i_s
        i_c = np.floor(coolants / COOLANT_GRID_K).astype(int)
        w_c = coolants / COOLANT_GRID_K - i_c
        corners = np.stack([i_s, i_c, i_s, i_c + 1, i_s + 1, i_c, i_s + 1, i_c + 1], axis=-1).reshape(-1, 4, 2)
        weights = np.stack([(1 - w_s) * (1 - w_c), (1 - w_s) * w_c, w_s * (1 - w_c), w_s * w_c], axis=-1)
        keys, slots = np.unique(corners.reshape(-1, 2), axis=0, return_inverse=True)
        cache = self._tables.setdefault(h, {})
        caps = self.net.capacitances
        for i, j in keys.tolist():
            if (i, j) not in cache:
                cache[i, j] = discretize(*self.matrices(i * SPEED_GRID_RPM, j * COOLANT_GRID_K), caps, h)
        table = np.stack([cache[i, j] for i, j in keys.tolist()])
        return table, slots.reshape(-1, 4), weights

    def simulate(self, steps: StepInputs, components: LossComponents, start_C: float, stride: int) -> ThermalRun:
        n, count = self.net.size, steps.steps
        cool, amb = np.asarray(steps.coolant_C, dtype=float), np.asarray(steps.ambient_C, dtype=float)
        table, slots, weights = self.cells(steps.speed_rpm, cool, steps.step_s)
        bearing, wind = self.mechanical(steps.speed_rpm)
        inputs = list(zip(*(np.asarray(steps.op[k], dtype=float).tolist() for k in LossComponents.INPUTS),
                          strict=True))
        place = self.placer(components)
        x = np.full(n, float(start_C))
        z = np.empty(2 * n + 2)
        states, groups = [], []
        bearing, wind, cool_l, amb_l = bearing.tolist(), wind.tolist(), cool.tolist(), amb.tolist()
        for k in range(count):
            p, group = place(x, inputs[k], bearing[k], wind[k])
            if k % stride == 0:
                states.append(x)
                groups.append(group)
            z[:n] = x
            z[n:2 * n] = p
            z[2 * n] = cool_l[k]
            z[2 * n + 1] = amb_l[k]
            x = portable.blended_matvec(table, slots[k], weights[k], z)
        if count % stride == 0:
            states.append(x)
        return ThermalRun(np.array(states), np.array(groups))

    # ------------------------------------------------------------------ steady state and heat flows
    def steady(self, op: Mapping[str, float], speed_rpm: float, coolant_C: float, ambient_C: float,
               components: LossComponents, iterations: int = 200) -> tuple[np.ndarray, np.ndarray]:
        """Steady temperatures at a fixed operating point (the losses at their own temperatures, by fixed-point
        iteration of G x = -(E u + P(x))) and the node losses there."""
        g, e = self.matrices(speed_rpm, coolant_C)
        u = np.array([coolant_C, ambient_C])
        place = self.placer(components)
        bearing, wind = (float(v) for v in self.mechanical(speed_rpm))
        inputs = tuple(float(op[k]) for k in LossComponents.INPUTS)
        x = np.full(self.net.size, float(coolant_C))
        for _ in range(iterations):
            p, _ = place(x, inputs, bearing, wind)
            new = portable.solve(g, -(portable.matmul(e, u[:, None])[:, 0] + p))
            if np.max(np.abs(new - x)) < 1e-10:
                x = new
                break
            x = new
        p, _ = place(x, inputs, bearing, wind)
        return x, p

    def heat_flows(self, x, speed_rpm: float, coolant_C: float, ambient_C: float) -> dict[str, float]:
        """Heat leaving the network at state x (W): to the coolant (its enthalpy rise ṁc_p(T_out - T_in), plus any
        direct link to the inlet) and to the ambient (the boundary links)."""
        cond = Conditions(float(speed_rpm), float(coolant_C))
        out = self.net.boundary_heat(np.asarray(x), (coolant_C, ambient_C), cond)
        return {"coolant": self.net.enthalpy_rise(np.asarray(x), coolant_C) + out["coolant_film"],
                "ambient": out["ambient"]}

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, "rotor": self.rotor, "slices": self.slices, "nodes": self.net.size,
                "cooling": self.cooling.kind}

    # helpers for conductances that vary with the conditions -------------------------------------------
    @staticmethod
    def _memo(fn):
        cache: dict[tuple[float, float], float] = {}

        def value(c: Conditions) -> float:
            key = (c.speed_rpm, c.coolant_C)
            if key not in cache:
                cache[key] = fn(c)
            return cache[key]

        return value

    @staticmethod
    def _scaled(h, area: float):
        if callable(h):
            return lambda c: h(c) * area
        return h * area

    @staticmethod
    def _gap(h_fn, area: float, *solid: float):
        return lambda c: series(film(h_fn(c), area), *solid)


def _glue(area: float) -> float:
    """A resin layer (magnet pockets, segment joints)."""
    return film(GLUE_K / (GLUE_MM * 1e-3), area)


def stator_radii(rotor: str, g: Geometry) -> dict[str, float]:
    """Radii of every stator layer boundary; s = +1 when the stator lies outside the air gap (inner rotor)."""
    s = 1.0 if rotor == "inner" else -1.0
    r_g = g.airgap_diameter / 2.0
    r_back = g.stator_back_diameter / 2.0
    yoke = s * (r_back - r_g) - g.slot_depth
    return {"s": s, "gap": r_g, "tip": r_g + s * g.tooth_tip, "slot": r_g + s * g.slot_depth,
            "yoke_mid": r_g + s * (g.slot_depth + yoke / 2.0), "back": r_back,
            "housing": r_back + s * g.housing_thickness, "yoke": yoke}


def rotor_radii(rotor: str, g: Geometry) -> dict[str, float]:
    """The rotor's radii: its surface and the magnets' (inner rotor), or the magnets' and the back iron's (outer)."""
    r_g = g.airgap_diameter / 2.0
    if rotor == "inner":
        r_r = r_g - g.airgap
        m_out = r_r - g.magnet_depth
        return {"surface": r_r, "magnet_out": m_out, "magnet_in": m_out - g.magnet_thickness}
    r_r = r_g + g.airgap
    return {"surface": r_r, "magnet_out": r_r + g.magnet_thickness, "back": r_r + g.magnet_thickness
            + g.rotor_back_iron}


def check_geometry(check: Checker, rotor: str, g: Geometry) -> None:
    """The radial build must hold together: a yoke behind the slots, rotor iron around the shaft, bearings inside."""
    r = stator_radii(rotor, g)
    if r["yoke"] <= 2.0 * g.tooth_tip:
        side = "outside" if rotor == "inner" else "inside"
        check.fail("thermal.geometry", f"leaves a yoke of {r['yoke'] * 1e3:.1f} mm between the slots and the "
                   f"stator back; stator_back_diameter_mm must lie {side} the slots with room for a yoke")
    if g.slot_depth <= 2.0 * g.tooth_tip:
        check.fail("thermal.geometry.slot_depth_mm", "must exceed twice tooth_tip_mm (the tips and the copper)")
    if min(rotor_radii(rotor, g).values()) <= g.shaft_diameter / 2.0:
        check.fail("thermal.geometry", "leaves no rotor iron around the shaft; check airgap_diameter_mm, "
                   "magnet_thickness_mm, magnet_depth_mm and shaft_diameter_mm")
    if g.bearing_outer_diameter <= g.shaft_diameter or g.bearing_outer_diameter / 2.0 >= r["housing"]:
        check.fail("thermal.geometry.bearing_outer_diameter_mm", "must lie between the shaft and the housing"
                   + (" (the hub's bore)" if rotor == "outer" else ""))


class Distributed(PlantKind):
    name = "distributed"
    summary = "a network of dozens of nodes built from geometry, materials and cooling"

    def from_table(self, check: Checker, table: Mapping[str, Any], motor: MotorDescription) -> ThermalPlant:
        check.only(table, "thermal", KEYS)
        rotor = table.get("rotor", "inner")
        if rotor not in ROTORS:
            check.fail("thermal.rotor", f"{rotor!r} is not one of {', '.join(ROTORS)}")
        slices = check.whole(table, "slices", "thermal.", low=MIN_SLICES, high=MAX_SLICES, default=MIN_SLICES)
        geo = geometry(check, table)
        mats = materials(check, table)
        cooling_table = table.get("cooling")
        if not isinstance(cooling_table, dict):
            check.fail("thermal.cooling", f"is missing or not a table {{kind = {' | '.join(COOLING_KINDS)}, ...}}")
        kind = cooling_table.get("kind")
        if kind not in COOLING_KINDS:
            check.fail("thermal.cooling.kind", f"{kind!r} is not one of {', '.join(COOLING_KINDS)}")
        if rotor == "outer" and kind != "water_jacket":
            check.fail("thermal.cooling.kind", "must be water_jacket for an outer rotor (the stator is cooled from "
                       "its hub)")
        values = _numbers(check, {k: v for k, v in cooling_table.items() if k != "kind"}, "cooling",
                          COOLING_KEYS[kind])
        if kind == "air" and 2.0 * math.pi * (geo.stator_back_diameter / 2.0 + geo.housing_thickness) \
                / values["fins"] <= values["fin_thickness_mm"] * 1e-3 * 1.2:
            check.fail("thermal.cooling.fins", "leave no room between the fins; fewer or thinner fins")
        if kind == "water_jacket":
            if values["turns"] * values["channel_width_mm"] > geo.stack_length / 1e-3:
                check.fail("thermal.cooling.turns", "× channel_width_mm exceeds the stack length")
            if values["channel_height_mm"] * 1e-3 >= geo.housing_thickness * 0.8:
                check.fail("thermal.cooling.channel_height_mm", "must leave walls in the housing (below 80 % of "
                           "housing_thickness_mm)")
        end_space = _numbers(check, table.get("end_space"), "end_space", END_SPACE)
        placement = _numbers(check, table.get("losses"), "losses", LOSS_KEYS)
        check_geometry(check, rotor, geo)
        return DistributedPlant(rotor, slices, geo, mats, Cooling(kind, values), end_space, placement,
                                motor.pole_pairs)


register(Distributed())
