"""`bench data`: generate the virtual motor's test-stand datasets (one per coolant inlet temperature)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from bench.commands.common import add_output_flags, check_writable, print_json
from bench.errors import BenchError, UsageError

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


def seed_value(text: str) -> int:
    try:
        seed = int(text)
    except ValueError:
        seed = -1
    if seed < 0:
        raise UsageError(f"--seed {text!r} must be a non-negative integer")
    return seed


def add_subparser(subparsers) -> None:
    from bench.drive.generate import COOLANT_SETPOINTS_C, DEFAULT_SEED

    p = subparsers.add_parser("data", help="generate the FTP-75/WLTC3 datasets of the virtual 200 kW motor",
                              description=__doc__ + " Identification uses 20 and 60 °C, validation 40 °C.")
    p.add_argument("--out", type=Path, default=None, help="output directory (default: out/data)")
    p.add_argument("--coolant", type=coolant_list, default=list(COOLANT_SETPOINTS_C),
                   help="coolant inlet set points in °C, comma-separated (default 20,40,60)")
    p.add_argument("--seed", type=seed_value, default=DEFAULT_SEED, help=f"noise seed (default {DEFAULT_SEED})")
    p.add_argument("--plot", action="store_true", help="also write a PNG per dataset (torque, speed, temperatures)")
    add_output_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.drive.dataset import dataset_filename, default_dataset_dir, load_dataset
    from bench.drive.generate import GENERATOR_VERSION, ROLES, generate_and_write
    from bench.drive.sequence import TestSequence

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
