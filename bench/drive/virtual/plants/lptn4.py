"""lptn4: the bench's own four-node parameter-varying LPTN (paper Fig. 4) with its 22 TRUE parameters.

The table is the 22 parameters (`bench.thermal.parameters.LptnParameters`), optionally with kind = "lptn4". Nodes:
yoke, winding, tooth, magnet; the yoke leaks to the coolant (R_cy, eq. 16), the magnet to the ambient (R_ma,
eq. 15). Integrated exactly per plant step (bench.drive.plant.exact_steps/integrate_exact) with the speed ratio and
coolant at the step's midpoint and the losses at its start. The stator iron loss is split by eq. 8 with the TRUE k
parameters; the copper loss sits on the winding node at its temperature. The arithmetic is the one every motor file
written before the registry was generated with, so their files stay byte for byte the same.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from bench.drive.plant import exact_steps, integrate_exact, pv_network, steady_state
from bench.drive.virtual.errors import VirtualPlantError
from bench.drive.virtual.plants import LossComponents, PlantKind, StepInputs, ThermalPlant, ThermalRun, mix, register
from bench.motor.check import Checker
from bench.motor.description import MotorDescription, prior_parameters
from bench.motor.errors import MotorFileError
from bench.thermal.parameters import LptnParameters
from dbc.contract import TEMPERATURE_NODES

NODES = TEMPERATURE_NODES


class Lptn4Plant(ThermalPlant):
    kind = "lptn4"
    node_names = NODES
    loss_names = NODES

    def __init__(self, params: LptnParameters, speed_max_rpm: float):
        self.params = params
        self.speed_max_rpm = speed_max_rpm
        self.positions = {name: mix([i]) for i, name in enumerate(NODES)}
        self.signal_positions = {**{name: name for name in NODES}, "copper": "winding", "flux": "magnet"}

    def node_losses(self, components: LossComponents):
        """losses(i_d0, i_q0, di_d, di_q, x_ac, x_fe, x_m, w, ϑ_y, ϑ_w, ϑ_t, ϑ_m) -> (P_y, P_w, P_t, P_m)."""
        evaluate = components.evaluate
        ref, alpha = components.copper_reference_C, components.copper_alpha_per_K
        p = self.params
        k0, k1, k2, k3 = p.k_0, p.k_1, p.k_2, p.k_3

        def losses(i_d0, i_q0, di_d, di_q, x_ac, x_fe, x_m, w, th_y, th_w, th_t, th_m):
            p_dc0, p_ac0, load, p_s, p_m, r = evaluate(i_d0, i_q0, di_d, di_q, x_ac, x_fe, x_m, th_m,
                                                       0.5 * (th_y + th_t))
            cu = 1.0 + alpha * (th_w - ref)
            p_w = (p_dc0 * cu + p_ac0 / cu) * load
            k_s = k0 + k1 * r + k2 * w + k3 * r * w                                 # eq. 8
            return k_s * p_s, p_w, (1.0 - k_s) * p_s, p_m

        return losses

    def simulate(self, steps: StepInputs, components: LossComponents, start_C: float, stride: int) -> ThermalRun:
        op, cool, amb, h = steps.op, steps.coolant_C, steps.ambient_C, steps.step_s
        a_d, b_loss, b_env = exact_steps(self.params, op["w"], cool, h)
        drift = (b_env @ np.stack([cool, amb], axis=-1)[..., None])[..., 0]
        inputs = tuple(op[k] for k in (*LossComponents.INPUTS, "w"))
        run = integrate_exact(a_d, b_loss, drift, inputs, self.node_losses(components), [start_C] * 4, 0.0, h)
        return ThermalRun(run.states[::stride], run.losses[::stride])

    def steady(self, node_losses, speed_rpm: float, coolant_C: float, ambient_C: float) -> np.ndarray:
        """Steady temperatures for fixed node losses (W)."""
        return steady_state(self.params, node_losses, abs(speed_rpm) / self.speed_max_rpm, coolant_C, ambient_C)

    def heat_flows(self, states, speed_rpm: float, coolant_C: float, ambient_C: float) -> dict[str, float]:
        """Heat leaving the network at the states: to the coolant through R_cy, to the ambient through R_ma."""
        _, g_cy, g_ma = pv_network(self.params, abs(speed_rpm) / self.speed_max_rpm, coolant_C)
        return {"coolant": float(g_cy * (states[0] - coolant_C)), "ambient": float(g_ma * (states[3] - ambient_C))}

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, "nodes": 4, "parameters": self.params.as_dict()}


class Lptn4(PlantKind):
    name = "lptn4"
    summary = "the bench's four-node parameter-varying LPTN with its 22 true parameters"

    def from_table(self, check: Checker, table: Mapping[str, Any], motor: MotorDescription) -> ThermalPlant:
        values = {k: v for k, v in table.items() if k != "kind"}
        try:
            params, _ = prior_parameters(values, f"{check.where}: virtual_plant.thermal")
        except VirtualPlantError:
            raise
        except MotorFileError as exc:
            raise VirtualPlantError(str(exc)) from None
        return Lptn4Plant(params, motor.limits.speed_rpm)


register(Lptn4())
