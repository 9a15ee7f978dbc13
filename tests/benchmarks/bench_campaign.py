"""Campaign against a serial loop (prints figures; not a test): the runs of a campaign spec through `bench campaign
run` on N local Dask workers, and the same runs as plain `bench run` subprocesses one after the other, in the same
sitting, with both wall times.

    python tests/benchmarks/bench_campaign.py [--spec examples/campaigns/soak.toml] [--workers N] [--rows N]
                                              [--set KEY=VALUE ...] [--serial-first] [--keep DIR]

--rows N overrides the spec's rows (e.g. --rows 2000 to try the soak small); --set overrides any option as in
`bench campaign run --set`. Both sides run the same `bench run` arguments (the campaign's own, from the spec), each
run in a directory of its own; the serial side pays one `bench run` start-up per run as the campaign does, and the
campaign's figure includes starting and stopping its local cluster. Writes its record (`tests/benchmarks/record.py`)
as `campaign-<spec>[-rows<N>].json`, one per spec and size.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from record import Record, add_record_arguments  # noqa: E402

from bench.campaign.execute import prepare_datasets  # noqa: E402
from bench.campaign.spec import load_spec  # noqa: E402


def env() -> dict[str, str]:
    out = {k: v for k, v in os.environ.items() if not k.startswith("CAN_")}
    out.update(MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    return out


def campaign_side(spec: Path, out: Path, workers: int, sets: list[str]) -> tuple[float, dict]:
    started = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "bench", "campaign", "run", str(spec), "--out", str(out),
                           "--workers", str(workers), "--json", "--quiet", *(f"--set={s}" for s in sets)],
                          capture_output=True, text=True, env=env(), cwd=ROOT)
    wall = time.perf_counter() - started
    if proc.returncode not in (0, 1) or not proc.stdout.strip():
        sys.exit(f"bench campaign run failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return wall, json.loads(proc.stdout)


def serial_side(spec: Path, out: Path, sets: list[str]) -> tuple[float, list[tuple[str, int, float]]]:
    campaign = load_spec(spec, sets)
    data = prepare_datasets(campaign.runs, out, quiet=True)   # made before the clock, as the campaign's are
    results = []
    started = time.perf_counter()
    for run in campaign.runs:
        run_dir = out / "runs" / run.run_id
        run_dir.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "bench", "run", *run.argv(run_dir, data[run.run_id])],
                              capture_output=True, text=True, env=env(), cwd=run_dir, timeout=campaign.timeout_s)
        results.append((run.run_id, proc.returncode, time.perf_counter() - t0))
    return time.perf_counter() - started, results


def _shown(path: Path) -> str:
    """A path as the record shows it: relative to the repository when inside it."""
    resolved = path.resolve()
    return str(resolved.relative_to(ROOT)) if resolved.is_relative_to(ROOT) else str(path)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spec", type=Path, default=ROOT / "examples" / "campaigns" / "soak.toml")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--rows", type=int, default=None, help="override the spec's rows per run")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override an option")
    parser.add_argument("--serial-first", action="store_true", help="run the serial loop before the campaign")
    parser.add_argument("--keep", type=Path, default=None, help="keep both sides' outputs in this directory")
    add_record_arguments(parser)
    args = parser.parse_args()
    sets = list(args.set) + ([f"rows={args.rows}"] if args.rows else [])
    campaign = load_spec(args.spec, sets)
    variant = args.spec.stem + (f"-rows{args.rows}" if args.rows else "") + ("-custom" if args.set else "")
    record = Record("campaign", args, variant=variant, parameters={
        "spec": _shown(args.spec),
        "runs": len(campaign.runs), "rows": args.rows, "overrides": sets, "workers": args.workers})
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; spec {args.spec} "
          f"({len(campaign.runs)} runs, overrides {sets or 'none'}); {args.workers} workers")
    with tempfile.TemporaryDirectory() as tmp:
        base = args.keep or Path(tmp)
        sides = {}
        order = ("serial", "campaign") if args.serial_first else ("campaign", "serial")
        for side in order:
            if side == "campaign":
                wall, summary = campaign_side(args.spec, base / "campaign", args.workers, sets)
                sides[side] = wall
                print(f"campaign: {wall:.1f} s wall on {args.workers} workers ({summary['cluster']}); "
                      f"{summary['counts']}, {summary['retried']} retried; table {summary['table']}")
                record.figures["campaign"] = {"wall_s": round(wall, 1), "counts": summary["counts"],
                                              "retried": summary["retried"]}
            else:
                wall, results = serial_side(args.spec, base / "serial", sets)
                sides[side] = wall
                codes = {}
                for _, code, _ in results:
                    codes[code] = codes.get(code, 0) + 1
                per_run = sorted(t for _, _, t in results)
                print(f"serial: {wall:.1f} s wall, {len(results)} runs one after the other "
                      f"(median {per_run[len(per_run) // 2]:.1f} s per run); exit codes {codes}")
                record.figures["serial"] = {"wall_s": round(wall, 1),
                                            "median_run_s": round(per_run[len(per_run) // 2], 1),
                                            "exit_codes": {str(k): v for k, v in codes.items()}}
    print(f"speed-up {sides['serial'] / sides['campaign']:.2f}x ({sides['serial']:.1f} s serial, "
          f"{sides['campaign']:.1f} s campaign on {args.workers} workers); load average now "
          f"{os.getloadavg()[0]:.2f}")
    record.figures["speed_up"] = round(sides["serial"] / sides["campaign"], 2)
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
