"""Benchmark (not a test): host memory per data row, of the host side of a run and of `bench analyze` of its log.

    python tests/benchmarks/bench_memory.py [--scales 1,10] [--no-tracemalloc] [--work DIR]

Scale 1 is the default 40 °C validation run (36 371 rows, out/data, generated if missing); scale k is that dataset
concatenated k times with continuing time (a CSV written into --work), so Step wraps past 65 535 as in a long run.
For each scale, each measurement runs in a fresh child process:

* host: the target process started and the rows replayed in lockstep with the log written (`run_with_target`,
  what `bench run` does before its analysis);
* analyze: `bench analyze LOG --data CSV --report DIR` of that log (decode, references, metrics, figures, report).

Figures: growth of the resident set (VmHWM after the step minus VmRSS before it, with the peak reset in between
through /proc/self/clear_refs) and, in a second child, the tracemalloc peak (Python and numpy allocations; the
run is slower under tracemalloc), each divided by the rows. The baseline is taken after the modules, the model and
the data are loaded, and for the analysis after a warm-up that loads what costs the same at any length (the
compiled float64 kernel, matplotlib's renderer and fonts: about 85 MB, 2.3 kB a row of the default run), so the
figures are what the rows cost. The last lines give the marginal cost, (peak at 10x - peak at 1x) / (rows at
10x - rows at 1x), which no fixed cost enters. Writes its record (`tests/benchmarks/record.py`).
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

from record import Record, add_record_arguments  # noqa: E402


def _status_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise RuntimeError(f"no {field} in /proc/self/status")


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def scaled_dataset(scale: int, work: Path) -> Path:
    """The default 40 °C dataset, or it concatenated `scale` times with continuing time."""
    import numpy as np

    from bench.drive.dataset import OPTIONAL_COLUMNS, load_dataset, write_dataset
    from bench.drive.generate import ensure_default_datasets

    base = ensure_default_datasets(ROOT / "out" / "data")[40]
    if scale == 1:
        return Path(base)
    path = work / f"cycle_coolant40_x{scale}.csv"
    if path.is_file():
        return path
    data = load_dataset(Path(base))
    names = ["time_s", "torque_Nm", "speed_rpm", "coolant_C", "ambient_C", "winding_C", "rotor_surface_C", "pm_C"]
    names += [c for c in OPTIONAL_COLUMNS if getattr(data, c, None) is not None]
    columns = {name: np.tile(getattr(data, name), scale) for name in names}
    columns["time_s"] = np.arange(data.rows * scale) * data.sample_period_s
    write_dataset(path, columns, {"coolant_setpoint_C": 40.0, "note": f"the 40 °C run x{scale} (bench_memory)"})
    return path


# ---------------------------------------------------------------------------------------------- the children
def child_host(data: Path, log: Path, trace: bool) -> dict:
    from bench.model.default import default_artifact_path
    from bench.model.runs import drive_matrix, initial_temperatures
    from bench.run.execute import run_with_target
    from bench.run.inputs import load_data
    from dbc.transport import BusConfig, resolve
    from target_sim.artifact import load_artifact

    model_path = default_artifact_path()
    artifact = load_artifact(model_path)
    dataset = load_data(data, artifact)
    drive = drive_matrix(dataset)
    initial = initial_temperatures(dataset)
    bus = resolve(BusConfig("udp_multicast"), session_unique=True)
    return _measure(lambda: run_with_target(model_path, artifact, bus, drive, initial, log_path=log,
                                            sample_period_s=dataset.sample_period_s), len(drive), trace,
                    check=lambda outcome: {"replies": outcome.result.replies, "missing": outcome.result.missing})


def child_analyze(data: Path, log: Path, report: Path, trace: bool) -> dict:
    import bench.analysis.canmetrics  # noqa: F401 - imported before the baseline, as the data
    import bench.analysis.report  # noqa: F401
    import bench.commands.analyze  # noqa: F401
    from bench.cli import main
    from bench.drive.dataset import load_dataset

    rows = load_dataset(data).rows
    _warm_up(data)

    args = ["analyze", str(log), "--data", str(data), "--report", str(report), "--quiet", "--json"]
    out = Path(tempfile.mkstemp(suffix=".json")[1])

    def run():
        saved = sys.stdout
        with open(out, "w") as handle:
            sys.stdout = handle
            try:
                return main(args)
            finally:
                sys.stdout = saved

    result = _measure(run, rows, trace, check=lambda status: {"exit": status})
    try:
        summary = json.loads(out.read_text())
        result.update(replies=summary.get("replies"), frames=summary.get("frames_in_log"))
    except ValueError:
        pass
    out.unlink()
    return result


def _warm_up(data: Path) -> None:
    """Load what the analysis loads once whatever the log's length: the offline references' compiled kernels (on
    200 rows) and matplotlib's Agg renderer with its fonts (one small figure with text)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bench.analysis.canmetrics import references
    from bench.model.default import default_artifact_path
    from bench.model.runs import drive_matrix, initial_temperatures
    from bench.run.inputs import load_data
    from target_sim.artifact import load_artifact

    artifact = load_artifact(default_artifact_path())
    dataset = load_data(data, artifact)
    references(artifact, drive_matrix(dataset)[:200], initial_temperatures(dataset))
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0.1, 1000], [0.1, 1000], marker=".", label="warm-up")
    ax.set_yscale("symlog", linthresh=1)      # its tick labels load mathtext
    ax.legend()
    ax.set_title("warm-up (°C)")
    fig.savefig(io.BytesIO(), format="png", dpi=110)
    plt.close(fig)


def _measure(fn, rows: int, trace: bool, check) -> dict:
    import gc
    import tracemalloc

    gc.collect()
    baseline_kb = _status_kb("VmRSS")
    peak_reset = _reset_peak()
    if trace:
        tracemalloc.start()
    started = time.perf_counter()
    outcome = fn()
    seconds = time.perf_counter() - started
    out = {"rows": rows, "seconds": round(seconds, 1), "baseline_MB": round(baseline_kb / 1024, 1), **check(outcome)}
    if trace:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        out["tracemalloc_peak_MB"] = round(peak / 2**20, 1)
        out["tracemalloc_B_per_row"] = round(peak / rows)
    else:
        hwm_kb = _status_kb("VmHWM")
        out["rss_growth_MB"] = round((hwm_kb - baseline_kb) / 1024, 1)
        out["rss_B_per_row"] = round((hwm_kb - baseline_kb) * 1024 / rows)
        out["peak_reset"] = peak_reset
    return out


# ---------------------------------------------------------------------------------------------- the parent
def run_child(kind: str, *args: str, trace: bool) -> dict:
    argv = [sys.executable, __file__, "--child", kind, *args] + (["--trace"] if trace else [])
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"the {kind} child failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scales", default="1,10", help="comma-separated multiples of the default run (1,10)")
    parser.add_argument("--no-tracemalloc", action="store_true", help="RSS only (faster)")
    parser.add_argument("--work", type=Path, default=None, help="directory for the data, logs and reports")
    parser.add_argument("--child", choices=("host", "analyze"), help=argparse.SUPPRESS)
    parser.add_argument("--trace", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--data", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--log", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--report", type=Path, help=argparse.SUPPRESS)
    add_record_arguments(parser)
    args = parser.parse_args()
    if args.child == "host":
        print(json.dumps(child_host(args.data, args.log, args.trace)))
        return
    if args.child == "analyze":
        print(json.dumps(child_analyze(args.data, args.log, args.report, args.trace)))
        return
    os.chdir(ROOT)
    record = Record("memory", args, parameters={"scales": args.scales, "tracemalloc": not args.no_tracemalloc})
    work = args.work or Path(tempfile.mkdtemp(prefix="bench-memory-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"work directory {work}", flush=True)
    traces = (False,) if args.no_tracemalloc else (False, True)
    results: dict[tuple[str, str], list[dict]] = {}
    for scale in (int(s) for s in args.scales.split(",")):
        data = scaled_dataset(scale, work)
        log = work / f"run_x{scale}.blf"
        for trace in traces:
            what = "tracemalloc" if trace else "RSS"
            host = run_child("host", "--data", str(data), "--log", str(log), trace=trace)
            print(f"x{scale} host run ({what}): {json.dumps(host)}", flush=True)
            report = work / f"report_x{scale}_{what}"
            analyzed = run_child("analyze", "--data", str(data), "--log", str(log), "--report", str(report),
                                 trace=trace)
            print(f"x{scale} bench analyze ({what}): {json.dumps(analyzed)}", flush=True)
            results.setdefault(("host run", what), []).append(host)
            results.setdefault(("bench analyze", what), []).append(analyzed)
    record.figures["measurements"] = []
    for (step, what), runs in results.items():
        key = "tracemalloc_peak_MB" if what == "tracemalloc" else "rss_growth_MB"
        per_row = {f"x{round(r['rows'] / runs[0]['rows'])}": round(r[key] * 2**20 / r["rows"]) for r in runs}
        line = f"{step}, {what}: per row " + ", ".join(f"{scale} {value} B" for scale, value in per_row.items())
        marginal = None
        if len(runs) > 1 and runs[-1]["rows"] > runs[0]["rows"]:
            marginal = round((runs[-1][key] - runs[0][key]) * 2**20 / (runs[-1]["rows"] - runs[0]["rows"]))
            line += f"; marginal {marginal} B per row"
        print(line, flush=True)
        record.figures["measurements"].append({"step": step, "measure": what, "runs": runs,
                                               "bytes_per_row": per_row, "marginal_bytes_per_row": marginal})
    record.write()


if __name__ == "__main__":
    main()
