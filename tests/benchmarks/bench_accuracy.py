"""Accuracy benchmark (prints figures; not a test): what the documented commands estimate, run as a user runs them.

    python tests/benchmarks/bench_accuracy.py [--skip-ipm] [--work DIR]

1. The built-in motor, packaged model: `bench evaluate --json` (the Table 5 analogue on the 40 °C validation run,
   LTI LPTN and Hammerstein at Δt 0.5, 1, 2, 4 s, the Hammerstein block refitted at each Δt other than the
   artifact's) and `bench evaluate --dt 0.5 --realization balanced --json` (what the deployed delta realization
   gains in float32 over the balanced one).
2. Your own motor: the three commands of the IPM example (`docs/tutorials/own-motor.md`): `bench data`,
   `bench identify --all-kinds`, `bench evaluate` of both kinds on the two held-out profiles, each timed, with
   the pooled float32 RMSE and max error per node, the baselines, and the parameters that ended on a bound.

Every figure comes from the commands' own `--json`. Writes its record (`tests/benchmarks/record.py`).
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

IPM = ROOT / "examples" / "motor-ipm"
HELD_OUT = ("profile_09.csv", "profile_10.csv")


def bench(*argv: str) -> tuple[dict, float]:
    """`bench ARGV --json` in a fresh process: its JSON and wall time (exit on failure, with its last words)."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "bench", *argv, "--json"], capture_output=True, text=True,
                          cwd=ROOT, env=dict(os.environ, MPLBACKEND="Agg"))
    seconds = time.perf_counter() - started
    if done.returncode != 0 or not done.stdout.strip().startswith("{"):
        sys.exit(f"bench {' '.join(argv)} failed ({done.returncode}): {done.stderr.strip()[-600:]}")
    return json.loads(done.stdout), seconds


def _node_figures(nodes: dict) -> dict:
    """Per node, float32 (as the target runs it) RMSE and max |error|, and the float64 RMSE."""
    return {node: {"rmse_C": v["float32"]["rmse"], "max_abs_C": v["float32"]["max_abs"],
                   "rmse_float64_C": v["float64"]["rmse"]} for node, v in nodes.items()}


def builtin_motor() -> dict:
    table, seconds = bench("evaluate")
    balanced, _ = bench("evaluate", "--dt", "0.5", "--realization", "balanced")
    rows = [{"kind": r["model"], "dt_s": r["dt"], "realization": r["realization"],
             "nodes": _node_figures({n: {"float32": r["float32"][n], "float64": r["float64"][n]}
                                     for n in r["float32"]}),
             "max_abs_f32_minus_f64_C": r["max_abs_f32_minus_f64_C"]} for r in table["rows"]]
    for row in rows:
        print(f"built-in {row['kind']:12} Δt {row['dt_s']:g} s: winding RMSE {row['nodes']['winding']['rmse_C']:.3f}, "
              f"PM {row['nodes']['pm']['rmse_C']:.3f} °C, |f32 - f64| {row['max_abs_f32_minus_f64_C']:.1e} °C")
    balanced_rows = {r["model"]: r["max_abs_f32_minus_f64_C"] for r in balanced["rows"] if r["dt"] == 0.5}
    print(f"balanced realization at Δt 0.5 s: |f32 - f64| {balanced_rows}")
    return {"model_sha256": table["sha256"], "validation": table["validation"], "evaluate_s": round(seconds, 1),
            "table5": rows, "balanced_max_abs_f32_minus_f64_C": balanced_rows}


def ipm_example(work: Path) -> dict:
    motor, mapping = str(IPM / "motor.json"), str(IPM / "mapping.json")
    data = work / "ipm"
    _, data_s = bench("data", "--motor", motor, "--out", str(data), "--quiet")
    identified, identify_s = bench(
        "identify", "--motor", motor, "--mapping", mapping, "--train", str(data / "profile_0[1-8].csv"),
        "--validate", *(str(data / f) for f in HELD_OUT), "--out", str(data / "model.json"), "--all-kinds")
    evaluated, evaluate_s = bench(
        "evaluate", "--model", str(data / "model.json"), "--model", str(data / "model-lti-lptn.json"),
        "--mapping", mapping, "--data", *(str(data / f) for f in HELD_OUT))
    models = []
    for m in evaluated["models"]:
        pooled = m["pooled"]
        models.append({"kind": m["kind"], "dt_s": m["dt"], "loss_model": m["loss_model"], "steps": pooled["steps"],
                       "nodes": _node_figures(pooled["nodes"]),
                       "baselines": {name: {node: {"rmse_C": v["rmse"], "max_abs_C": v["max_abs"]}
                                            for node, v in nodes.items()}
                                     for name, nodes in pooled["baselines"].items()},
                       "max_abs_f32_minus_f64_C": pooled["max_abs_f32_minus_f64_C"]})
        print(f"IPM example {m['kind']:12}: winding RMSE {models[-1]['nodes']['winding']['rmse_C']:.3f}, "
              f"PM {models[-1]['nodes']['pm']['rmse_C']:.3f} °C (held-out, pooled, float32)")
    on_bounds = identified.get("parameters_on_bounds") or []
    print(f"IPM example: bench data {data_s:.1f} s, bench identify {identify_s:.1f} s, bench evaluate "
          f"{evaluate_s:.1f} s; {len(on_bounds)} parameters on a bound")
    return {"data_s": round(data_s, 1), "identify_s": round(identify_s, 1), "evaluate_s": round(evaluate_s, 1),
            "held_out": list(HELD_OUT), "prior": identified.get("prior"), "bounds": identified.get("bounds"),
            "parameters_on_bounds": on_bounds, "models": models}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--skip-ipm", action="store_true", help="only the built-in motor")
    parser.add_argument("--work", type=Path, default=None, help="keep the IPM example's files here")
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("accuracy", args, parameters={"ipm": not args.skip_ipm})
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    record.figures["builtin"] = builtin_motor()
    if not args.skip_ipm:
        with tempfile.TemporaryDirectory(prefix="bench-accuracy-") as tmp:
            record.figures["ipm"] = ipm_example(args.work or Path(tmp))
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
