"""`bench motor`: motor description files: `template` prints an example to start from, `check FILE` validates
one and shows what the bench reads from it, `lump FILE` lumps a distributed virtual plant into the 22 parameters of
the four-node LPTN (a designer's prior for `thermal_prior.parameters`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.commands.args import declare_files
from bench.commands.common import add_output_flags, print_json


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("motor", help="motor description files: print a template, check a file",
                              description=__doc__)
    actions = p.add_subparsers(title="actions", dest="action", parser_class=type(p))
    template = actions.add_parser("template", help="print an example motor description")
    template.add_argument("--format", choices=("toml", "json"), default="toml", help="file format (default toml)")
    declare_files(template)
    template.set_defaults(func=run_template)
    check = actions.add_parser("check", help="validate a motor description and summarize it")
    check.add_argument("file", type=Path, help="the motor's .json or .toml file")
    add_output_flags(check)
    declare_files(check, inputs=('FILE',))
    check.set_defaults(func=run_check)
    lump = actions.add_parser("lump", help="a distributed virtual plant lumped into the four-node LPTN's 22 "
                              "parameters (a designer's prior)")
    lump.add_argument("file", type=Path, help="the motor's .json or .toml file (virtual_plant.thermal.kind = "
                      "\"distributed\")")
    add_output_flags(lump)
    declare_files(lump, inputs=('FILE',))
    lump.set_defaults(func=run_lump)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def run_template(args: argparse.Namespace) -> int:
    from bench.motor.template import template

    print(template(args.format), end="")
    return 0


def run_check(args: argparse.Namespace) -> int:
    from bench.motor.description import load_motor
    from bench.motor.losskinds import LAB_LOSS_KINDS

    motor = load_motor(args.file)
    summary = {**motor.provenance(), "description": motor.description,
               "copper_reference_C": motor.copper_reference_C, "copper_alpha_per_K": motor.copper_alpha_per_K,
               "needs_currents": motor.needs_currents,
               "thermal_prior": None if motor.prior is None else {"source": motor.prior.source,
                                                                  "bounds": list(motor.prior.bounds)},
               "virtual_plant": motor.virtual_plant is not None}
    summary.update(LAB_LOSS_KINDS[motor.loss_kind].describe(motor.loss_model))
    if args.json:
        print_json(summary)
    else:
        lim = summary["limits"]
        print(f"motor {motor.name}: {motor.pole_pairs} pole pairs, {lim['torque_Nm']:g} Nm, {lim['speed_rpm']:g} rpm, "
              f"{lim['current_A']:g} A; {motor.loss_kind} losses"
              + (" (needs i_d_A and i_q_A in the data)" if motor.needs_currents else "")
              + (f"; thermal prior {motor.prior.source} within {motor.prior.bounds[0]:g}..{motor.prior.bounds[1]:g}"
                 if motor.prior else "; thermal prior: Table 1 within 0.6..1.6")
              + ("; describes a virtual plant ('bench data --motor' can generate its data)"
                 if motor.virtual_plant else ""))
    return 0


def run_lump(args: argparse.Namespace) -> int:
    from bench.drive.virtual import VirtualPlantError, load_virtual_plant
    from bench.drive.virtual.plants.distributed import Distributed, DistributedPlant
    from bench.drive.virtual.plants.lump import designer_prior

    plant = load_virtual_plant(args.file)
    if not isinstance(plant.thermal, DistributedPlant):
        raise VirtualPlantError(f"motor file {args.file}: its virtual plant is {plant.thermal.kind!r}; bench motor "
                                f"lump lumps {Distributed.name!r} plants (virtual_plant.thermal.kind)")
    prior = designer_prior(plant.thermal, plant.motor.limits.speed_rpm).as_dict()
    if args.json:
        print_json(prior)
    else:
        params = prior["parameters"]
        print(f"motor {plant.motor.name}: {plant.thermal.net.size} nodes lumped into yoke, winding, tooth, magnet "
              "(steady-state fit of the group means; worst entry off by "
              + ", ".join(f"{v:g} % at {k}" for k, v in prior["fit_error_percent"].items()) + ")")
        print('"thermal_prior": {"parameters": {' + ", ".join(f'"{k}": {v:g}' for k, v in params.items()) + "}}")
    return 0
