"""`bench data`: generate the virtual motor's test-stand datasets (one per coolant inlet temperature), or with
--motor FILE the measurement files of a motor file's virtual plant (bench.drive.virtual)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from bench.commands.args import declare_files
from bench.commands.common import add_output_flags, check_writable, print_json
from bench.drive.seed import DEFAULT_SEED
from bench.errors import BenchError, UsageError
from bench.run.values import non_negative_int

COOLANT_LIMITS_C = (-30.0, 120.0)


def coolant_list(text: str) -> list[float]:
    """'20,40,60' -> [20.0, 40.0, 60.0]: distinct set points inside COOLANT_LIMITS_C."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UsageError(f"--coolant {text!r} is not a comma-separated list of temperatures, e.g. 20,40,60") from None
    low, high = COOLANT_LIMITS_C
    if not values or any(not math.isfinite(v) or not low <= v <= high for v in values):
        raise UsageError(f"--coolant {text!r} must list temperatures between {low:g} and {high:g} °C, e.g. 20,40,60")
    if len(set(values)) != len(values):
        raise UsageError(f"--coolant {text!r} lists a set point twice")
    return values


def name_list(text: str) -> list[str]:
    names = [v.strip() for v in text.split(",") if v.strip()]
    if not names or len(set(names)) != len(names):
        raise UsageError(f"--profiles {text!r} must list distinct profile names, comma-separated")
    return names


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("data", help="generate the FTP-75/WLTC3 datasets of the virtual 200 kW motor",
                              description=__doc__ + " Identification uses 20 and 60 °C, validation 40 °C.")
    p.add_argument("--out", type=Path, default=None,
                   help="output directory (default: out/data; with --motor out/<motor name>)")
    p.add_argument("--coolant", type=coolant_list, default=None,
                   help="coolant inlet set points in °C, comma-separated (default 20,40,60; not with --motor, "
                        "whose profiles set their own)")
    p.add_argument("--seed", type=non_negative_int, default=None,
                   help=f"noise seed (default {DEFAULT_SEED}; with --motor the file's virtual_plant.seed)")
    p.add_argument("--plot", action="store_true", help="also write a PNG per dataset (torque, speed, temperatures)")
    p.add_argument("--motor", type=Path, default=None,
                   help="a motor file with a virtual_plant table (e.g. examples/motor-ipm/motor.json): write its "
                        "profiles, in its own columns and units, plus profiles.json, instead of the built-in "
                        "motor's datasets")
    p.add_argument("--profiles", type=name_list, default=None,
                   help="with --motor: only these profiles, comma-separated names (default: all)")
    add_output_flags(p)
    declare_files(p, inputs=('--motor',), outputs=('--out',))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.drive.dataset import dataset_filename, default_dataset_dir, load_dataset
    from bench.drive.generate import COOLANT_SETPOINTS_C, GENERATOR_VERSION, ROLES, generate_and_write
    from bench.drive.sequence import TestSequence

    if args.motor is not None:
        return run_virtual(args)
    if args.profiles is not None:
        raise UsageError("--profiles selects a virtual motor's profiles; it needs --motor FILE")
    args.coolant = list(COOLANT_SETPOINTS_C) if args.coolant is None else args.coolant
    args.seed = DEFAULT_SEED if args.seed is None else args.seed
    out_dir = args.out if args.out is not None else default_dataset_dir()
    check_writable(out_dir, "--out", directory=True)  # before seconds of generation, not after
    started = time.perf_counter()
    records = []
    for setpoint in args.coolant:
        t0 = time.perf_counter()
        path = out_dir / dataset_filename(setpoint)
        try:
            _, sha = generate_and_write(path, setpoint, args.seed)
        except OSError as exc:
            raise BenchError(f"cannot write {path} ({exc.strerror or exc}); choose a writable --out") from None
        dataset = load_dataset(path)  # read back through the loader: what we report is what others will read
        record = _summary(dataset, path, sha, ROLES.get(setpoint, "extra"))
        if args.plot:
            from bench.drive.plots import plot_dataset

            record["plot"] = str(plot_dataset(dataset, path.with_suffix(".png")))
        record["seconds"] = round(time.perf_counter() - t0, 3)
        records.append(record)
        if not args.quiet:
            print(f"coolant {setpoint:g} °C: {path} ({record['rows']} rows, {record['seconds']:.1f} s)",
                  file=sys.stderr)
    sequence = TestSequence()
    report = {"out_dir": str(out_dir), "seed": args.seed, "generator_version": GENERATOR_VERSION,
              "sequence": {"duration_s": sequence.duration_s, **sequence.envelope_report()}, "datasets": records,
              "elapsed_s": round(time.perf_counter() - started, 3)}
    if args.json:
        print_json(report)
    else:
        _print_table(report)
    return 0


def _summary(dataset, path: Path, sha: str, role: str) -> dict:
    ranges = {name: [round(float(dataset.column(name).min()), 3), round(float(dataset.column(name).max()), 3)]
              for name in ("coolant_C", "ambient_C", "winding_C", "rotor_surface_C", "pm_C")}
    return {"coolant_setpoint_C": dataset.coolant_setpoint_C, "role": role, "csv": str(path),
            "sidecar": str(path.with_suffix(".json")), "rows": dataset.rows, "sha256": sha,
            "duration_s": float(dataset.time_s[-1] - dataset.time_s[0]), "ranges_C": ranges,
            "max_rise_above_coolant_K": {
                "winding": round(float((dataset.winding_C - dataset.coolant_C).max()), 3),
                "pm": round(float((dataset.pm_C - dataset.coolant_C).max()), 3)}}


def _print_table(report: dict) -> None:
    seq = report["sequence"]
    print(f"sequence: {seq['duration_s']:g} s; peak torque {seq['peak_torque_Nm']:.0f} Nm, "
          f"peak speed {seq['peak_speed_rpm']:.0f} rpm, peak power {seq['peak_power_W'] / 1e3:.0f} kW")
    print(f"{'coolant':>8} {'role':15} {'rows':>6} {'winding °C':>13} {'PM °C':>13} {'rise w/PM K':>12}  sha256")
    for r in report["datasets"]:
        w, m = r["ranges_C"]["winding_C"], r["ranges_C"]["pm_C"]
        rise = r["max_rise_above_coolant_K"]
        print(f"{r['coolant_setpoint_C']:>8g} {r['role']:15} {r['rows']:>6} {w[0]:6.1f}..{w[1]:5.1f} "
              f"{m[0]:6.1f}..{m[1]:5.1f} {rise['winding']:5.1f}/{rise['pm']:4.1f}  {r['sha256'][:16]}…")
        if "plot" in r:
            print(f"{'':8} plot: {r['plot']}")
    print(f"written to {report['out_dir']} in {report['elapsed_s']:.1f} s (seed {report['seed']})")


def run_virtual(args: argparse.Namespace) -> int:
    """--motor FILE: the virtual plant's profiles, written as a user would bring them, and profiles.json."""
    from bench.drive.dataset import default_dataset_dir
    from bench.drive.virtual import generate_profiles, virtual_plant
    from bench.motor.description import load_motor

    if args.coolant is not None:
        raise UsageError("--coolant does not apply with --motor: each profile of the virtual plant sets its own "
                         "coolant temperatures")
    if args.plot:
        raise UsageError("--plot draws the built-in motor's datasets; with --motor, load the files with the motor's "
                         "mapping (bench evaluate --plots draws them)")
    plant = virtual_plant(load_motor(args.motor))
    names = args.profiles
    if names is not None:
        for name in names:
            plant.profile(name)   # an unknown name is one sentence, before any work
    out_dir = args.out if args.out is not None else default_dataset_dir().parent / plant.motor.name
    check_writable(out_dir, "--out", directory=True)
    seed = plant.seed if args.seed is None else args.seed
    started = time.perf_counter()

    def progress(profile, run, seconds):
        if not args.quiet:
            rise = run.rise_K()
            print(f"{profile.name}: {out_dir / profile.filename} ({len(run.time_s)} rows, winding "
                  f"+{rise['winding']:.0f} K, magnet +{rise['magnet']:.0f} K, {seconds:.1f} s)", file=sys.stderr)

    try:
        index = generate_profiles(plant, out_dir, seed, names, progress)
    except OSError as exc:
        raise BenchError(f"cannot write into {out_dir} ({exc.strerror or exc}); choose a writable --out") from None
    report = {"out_dir": str(out_dir), "index": str(out_dir / "profiles.json"),
              "elapsed_s": round(time.perf_counter() - started, 3), **index}
    if args.json:
        print_json(report)
    else:
        _print_virtual(report)
    return 0


def _print_virtual(report: dict) -> None:
    columns = ", ".join(f"{c['name']} [{c['unit']}]" for c in report["columns"])
    print(f"motor {report['motor']['name']}: every {report['sample_period_s']:g} s, no time column; columns {columns}")
    print(f"{'profile':12} {'role':9} {'rows':>5} {'coolant °C':>11} {'winding rise K':>15} {'magnet rise K':>14}"
          f" {'peak kW':>8}  sha256")
    for p in report["profiles"]:
        coolant = "→".join(f"{c:g}" for c in p["coolant_setpoints_C"])
        rise = p["true_max_rise_above_coolant_K"]
        print(f"{p['name']:12} {p['role']:9} {p['rows']:>5} {coolant:>11} {rise['winding']:>15.1f} "
              f"{rise['magnet']:>14.1f} {p['peak']['power_kW']:>8.1f}  {p['sha256'][:16]}…")
    print(f"written to {report['out_dir']} with {report['index']} in {report['elapsed_s']:.1f} s "
          f"(seed {report['seed']})")
