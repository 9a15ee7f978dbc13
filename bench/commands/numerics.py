"""`bench numerics`: the paper's Tables 2-4 analogue for every realization of the linear block."""

from __future__ import annotations

import argparse
import time

from bench.commands.common import add_output_flags, choice_list, float_list, print_json
from bench.errors import UsageError
from bench.thermal.excitation import SAMPLE_PERIOD_S, interval_means, synthetic_lti_inputs
from bench.thermal.parameters import PARAMETER_SETS, parameter_set
from bench.thermal.precision import PrecisionRow, numerics_report, precision_table
from bench.thermal.realizations import REALIZATIONS


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("numerics", help="condition numbers and float32 survival of each realization",
                              description=__doc__)
    p.add_argument("--params", default="table1-refined", help=f"parameter set: {', '.join(PARAMETER_SETS)}")
    p.add_argument("--disc", type=choice_list(("zoh", "tustin", "euler")), default=["zoh", "tustin"],
                   help="discretizations, comma-separated (default zoh,tustin)")
    p.add_argument("--dt", type=float_list, default=[0.5, 1.0, 2.0, 4.0], help="steps in s (default 0.5,1,2,4)")
    p.add_argument("--realizations", type=choice_list(REALIZATIONS), default=list(REALIZATIONS),
                   help="realizations, comma-separated (default all)")
    p.add_argument("--seed", type=int, default=7, help="seed of the synthetic 7274 s excitation")
    add_output_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        params = parameter_set(args.params)
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    started = time.perf_counter()
    samples = synthetic_lti_inputs(seed=args.seed)
    rows = precision_table(params, args.disc, args.dt, lambda dt: interval_means(samples, SAMPLE_PERIOD_S, dt),
                           args.realizations)
    report = numerics_report(params, args.params, rows)
    if args.json:
        print_json(report)
    else:
        print_tables(report, rows)
        if not args.quiet:
            print(f"\n{len(rows)} rows in {time.perf_counter() - started:.2f} s")
    return 0


def _fmt_list(values, digits=4) -> str:
    return " ".join(f"{v:.{digits}f}" for v in values)


def print_tables(report: dict, rows: list[PrecisionRow]) -> None:
    print(f"parameter set: {report['params']}")
    print(f"continuous eigenvalues (1/s): {_fmt_list(report['eigenvalues_continuous'], 7)}")
    print(f"time constants (s):           {_fmt_list(report['time_constants_s'], 2)}")
    header = (f"{'disc':7} {'dt':>4} {'realization':11} {'cond':>9}  {'eig float64':32}  "
              f"{'|eig| float32':32} {'f32':8} {'max err f32 (°C)':>16}")
    print()
    print(header)
    print("-" * len(header))
    for r in rows:
        stable = "stable" if r.stable_f32 else "UNSTABLE"
        err = f"{r.max_output_error_f32_C:.3e}" + (" (diverged)" if r.diverged_f32 else "")
        print(f"{r.discretization:7} {r.dt:4g} {r.realization:11} {r.cond:9.4f}  {_fmt_list(r.eig_f64):32}  "
              f"{_fmt_list(r.eig_f32_abs):32} {stable:8} {err:>16}")
