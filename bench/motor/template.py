"""The example motor description `bench motor template` prints: every key, with what it means."""

from __future__ import annotations

import json
import tomllib

TEMPLATE_TOML = '''\
# Motor description for pmsm-thermal-bench (schema version 1). Check it with: bench motor check motor.toml
schema = "pmsm-thermal-bench.motor"
schema_version = 1
name = "my-ipm-60kw"                 # letters, digits, '.', '-', '_'
description = "60 kW interior-PM traction motor, water jacket"
pole_pairs = 4

[limits]
torque_Nm = 180.0                    # peak torque
speed_rpm = 14000.0                  # maximum speed: the speed ratio n/n_max of the convection terms
current_A = 400.0                    # phase current amplitude at peak torque (I_max)

[losses]
# "electrical": losses from the measured d/q currents and the speed (the data need i_d_A and i_q_A columns):
#   f = pole_pairs·|n|/60, I² = i_d² + i_q²
#   copper  p_dc = 1.5·R·I²,  p_ac = p_dc·ac_factor·(f/ac_reference_Hz)²   (at copper_reference_C)
#   iron    (iron_hysteresis_W·(f/f_fe) + iron_eddy_W·(f/f_fe)²)·(1 + iron_current_factor·(I/I_max)²)
#   magnet  magnet_W·(f/magnet_reference_Hz)²·(share + (1 - share)·I/I_max)²
# "maps": file = "losses.csv" instead, a CSV beside this file on an evenly spaced torque × speed grid with the
#   columns torque_Nm, speed_rpm, copper_dc_W, copper_ac_W, iron_W, magnet_W, current_A.
kind = "electrical"
copper_reference_C = 20.0
copper_alpha_per_K = 0.00393
stator_resistance_ohm = 0.018        # per phase at copper_reference_C
ac_factor = 0.35
ac_reference_Hz = 933.0
iron_hysteresis_W = 600.0
iron_eddy_W = 500.0
iron_reference_Hz = 933.0
iron_current_factor = 0.3
magnet_W = 250.0
magnet_reference_Hz = 933.0
magnet_no_load_share = 0.4

[thermal_prior]                      # optional: where the particle swarm starts and how far it may go
parameters = "auto"                  # auto: read from the training data (each measured node's gain and time
                                     # constant); or a parameter set (table1, table1-refined) or a table of the
                                     # 22 values, your network if you have one
bounds = [0.1, 10.0]                 # capacitances and resistances within 0.1..10 × the prior (0.6..1.6 suits
                                     # a fitted network of this motor)
'''


def template(fmt: str = "toml") -> str:
    """The template as TOML (with comments) or JSON (the same content)."""
    if fmt == "toml":
        return TEMPLATE_TOML
    return json.dumps(tomllib.loads(TEMPLATE_TOML), indent=2) + "\n"
