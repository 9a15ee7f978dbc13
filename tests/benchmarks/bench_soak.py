"""Fault-injection soak (prints figures; not a test): lockstep runs back to back, each with dropped and
corrupted drive frames and one killed target, on a real target process and a real bus.

    python tests/benchmarks/bench_soak.py [--runs 10] [--rows N] [--drop 0.01] [--corrupt 0.001] [--kills 1]
                                          [--reply-drop P] [--reply-corrupt P] [--seed S] [--reply-timeout S]
                                          [--data FILE] [-i ... -c ...]

Default: 10 runs of the full 40 °C validation run (36 371 rows), 1 % drop + 0.1 % corruption per drive frame and
one SIGKILL of the target per run (the runner restarts it, the host restores it from its last StateCheckpoint),
fault seed S + run number; `--reply-drop`/`--reply-corrupt` add the target's reply faults. A clean run of the
same rows comes first, as the reference. Goals: every run completes with every row answered, zero undetected
faults, zero lost log frames (every frame the host logged reads back from the log file), CAN = offline float32
restarted as the target was within ±0.005 °C, and the clean run's temperatures outside the marked gaps within
0.005 °C (the restore is exact, so in fact equal, inside the gaps too). Writes its record
(`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from record import Record, add_record_arguments  # noqa: E402

from bench.analysis.canmetrics import compute  # noqa: E402
from bench.analysis.logdecode import decode_log  # noqa: E402
from bench.drive.dataset import load_dataset  # noqa: E402
from bench.drive.generate import ensure_default_datasets  # noqa: E402
from bench.model.default import default_artifact_path  # noqa: E402
from bench.model.runs import drive_matrix, initial_temperatures  # noqa: E402
from bench.run.execute import run_with_target  # noqa: E402
from dbc.transport import add_bus_arguments, config_from_args, resolve  # noqa: E402
from host.canlog import read_log  # noqa: E402
from host.faults import KINDS, parse_faults  # noqa: E402
from target_sim.artifact import load_artifact  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--rows", type=int, default=None, help="rows per run (default: all 36 371)")
    parser.add_argument("--drop", type=float, default=0.01)
    parser.add_argument("--corrupt", type=float, default=0.001)
    parser.add_argument("--kills", type=int, default=1)
    parser.add_argument("--reply-drop", type=float, default=0.0, help="probability per temperature reply frame")
    parser.add_argument("--reply-corrupt", type=float, default=0.0, help="probability per temperature reply frame")
    parser.add_argument("--seed", type=int, default=100, help="fault seed of run 0 (run i uses seed + i)")
    parser.add_argument("--reply-timeout", type=float, default=0.05)
    parser.add_argument("--data", type=Path, default=None, help="dataset (default: the 40 °C run in out/data)")
    add_bus_arguments(parser)
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("soak", args, parameters={k: getattr(args, k) for k in (
        "runs", "rows", "drop", "corrupt", "kills", "reply_drop", "reply_corrupt", "seed", "reply_timeout")})
    bus = resolve(config_from_args(args), session_unique=True)
    model_path = default_artifact_path()
    artifact = load_artifact(model_path)
    dataset = load_dataset(args.data or ensure_default_datasets(ROOT / "out" / "data")[40])
    drive = drive_matrix(dataset)[: args.rows] if args.rows else drive_matrix(dataset)
    initial = initial_temperatures(dataset)
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; bus {bus.describe()}; "
          f"model {artifact.kind} {artifact.model_id:08x}; {len(drive)} rows of {dataset.path}")
    print(f"faults per run: drop={args.drop:g}, corrupt={args.corrupt:g} per drive frame, kill={args.kills}, "
          f"reply_drop={args.reply_drop:g}, reply_corrupt={args.reply_corrupt:g} per reply frame; "
          f"seeds {args.seed}..{args.seed + args.runs - 1}; reply timeout {args.reply_timeout:g} s")

    def one_run(log: Path, faults=None):
        started = time.perf_counter()
        outcome = run_with_target(model_path, artifact, bus, drive, initial, sample_period_s=dataset.sample_period_s,
                                  log_path=log, reply_timeout_s=args.reply_timeout, faults=faults)
        decoded = decode_log(log)
        results, _ = compute(decoded, artifact, dataset)
        metrics = results.to_json()
        read_back = sum(1 for _ in read_log(log))
        return outcome.result, decoded, metrics, read_back, time.perf_counter() - started

    totals: Counter = Counter()
    detected_totals: Counter = Counter()
    with tempfile.TemporaryDirectory() as tmp:
        clean, clean_decoded, clean_metrics, clean_back, clean_s = one_run(Path(tmp) / "clean.blf")
        print(f"clean: {clean.rows_sent} rows, {clean.replies} answered, replay {clean.wall_time_s:.1f} s "
              f"({clean.rows_per_s:.0f} rows/s), {clean_s:.1f} s with start/stop/analysis, max |CAN - float32| "
              f"{max(clean_metrics['max_abs_can_minus_float32_C'].values()):.4f} °C")
        soak_started = time.perf_counter()
        completed = answered_all = 0
        worst_ref = worst_clean_outside = worst_clean_all = 0.0
        lost_frames = undetected = unexplained = 0
        walls = []
        per_run = []
        for run in range(args.runs):
            spec = parse_faults([f"drop={args.drop}", f"corrupt={args.corrupt}", f"kill={args.kills}",
                                 f"reply_drop={args.reply_drop}", f"reply_corrupt={args.reply_corrupt}"],
                                seed=args.seed + run)
            log = Path(tmp) / f"soak{run}.blf"
            result, decoded, metrics, read_back, wall = one_run(log, spec)
            f = result.faults
            walls.append(wall)
            totals.update(f["injected"])
            detected_totals.update({k: v for k, v in f["detected"].items() if v})
            completed += result.aborted is None and result.rows_sent == len(drive)
            answered_all += metrics["missing"] == 0 and result.missing == 0
            lost = (result.log_frames or 0) - read_back
            lost_frames += lost
            undetected += f["undetected"] or 0
            unexplained += f["unexplained_deadline_misses"] + f["unexplained_heartbeat_losses"]
            ref = max(v for v in metrics["max_abs_can_minus_float32_C"].values() if v is not None)
            worst_ref = max(worst_ref, ref)
            diff = np.abs(decoded.temps - clean_decoded.temps)
            outside = np.ones(len(diff), dtype=bool)
            for gap in f["gaps"]:
                outside[gap["rows"][0]:gap["rows"][1] + 1] = False
            outside_max = float(np.nanmax(diff[outside])) if outside.any() else 0.0
            all_max = float(np.nanmax(diff))
            worst_clean_outside = max(worst_clean_outside, outside_max)
            worst_clean_all = max(worst_clean_all, all_max)
            per_run.append({"rows": result.rows_sent, "answered": result.replies, "injected": f["injected"],
                            "detected": f["detected"], "retransmitted_rows": f["retransmitted_rows"],
                            "gaps_s": [round(g["duration_s"], 2) for g in f["gaps"]], "log_frames": result.log_frames,
                            "lost_log_frames": lost, "max_abs_can_minus_restarted_float32_C": ref,
                            "max_abs_can_minus_clean_outside_gaps_C": outside_max,
                            "max_abs_can_minus_clean_C": all_max, "wall_s": round(wall, 1)})
            gaps = ", ".join(f"rows {g['rows'][0]}-{g['rows'][1]} ({g['duration_s']:.2f} s)" for g in f["gaps"])
            print(f"run {run}: {result.rows_sent} rows, {result.replies} answered, "
                  + ", ".join(f"{k} {f['injected'][k]}/{f['detected'][k]}" for k in f["injected"])
                  + f" injected/detected; {f['retransmitted_rows']} rows retransmitted; gap {gaps or '-'}; "
                  f"log {result.log_frames} frames, {lost} lost; max |CAN - restarted float32| {ref:.4f} °C, "
                  f"|CAN - clean| {outside_max:.4f} °C outside the gaps, {all_max:.4f} °C over all rows; "
                  f"unexplained late replies {f['unexplained_deadline_misses']}; replay {result.wall_time_s:.1f} s, "
                  f"{wall:.1f} s in all")
        soak_s = time.perf_counter() - soak_started
    print(f"soak: {args.runs} runs x {len(drive)} rows in {soak_s:.0f} s ({np.mean(walls):.1f} s per run); "
          f"completed {completed}/{args.runs}, every row answered in {answered_all}/{args.runs}")
    print("injected/detected: " + ", ".join(f"{k} {totals[k]}/{detected_totals[k]}" for k in KINDS if totals[k])
          + f"; undetected {undetected}; lost log frames {lost_frames}; unexplained late replies or heartbeat "
          f"losses {unexplained}")
    print(f"max |CAN - restarted float32| {worst_ref:.4f} °C; max |CAN - clean run| {worst_clean_outside:.4f} °C "
          f"outside the marked gaps, {worst_clean_all:.4f} °C over all rows")
    ok = (completed == answered_all == args.runs and undetected == 0 and lost_frames == 0
          and worst_ref <= 0.005 + 1e-9 and worst_clean_outside <= 0.005 + 1e-9)
    print("soak goals met" if ok else "soak goals NOT met")
    record.parameters["data_rows"] = len(drive)
    record.figures.update(
        runs=per_run, soak_s=round(soak_s), completed=completed, answered_all=answered_all,
        injected={k: totals[k] for k in KINDS if totals[k]},
        detected={k: detected_totals[k] for k in KINDS if totals[k]},
        undetected=undetected, lost_log_frames=lost_frames, unexplained=unexplained,
        max_abs_can_minus_restarted_float32_C=worst_ref, max_abs_can_minus_clean_outside_gaps_C=worst_clean_outside,
        max_abs_can_minus_clean_C=worst_clean_all, goals_met=bool(ok))
    record.write()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
