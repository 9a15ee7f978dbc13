"""Accuracy benchmark (prints figures; not a test): what the documented commands estimate, run as a user runs them.

    python tests/benchmarks/bench_accuracy.py [--skip-ipm] [--work DIR]

1. The built-in motor, packaged model: `bench evaluate --json` (the Table 5 analogue on the 40 °C validation run,
   LTI LPTN and Hammerstein at Δt 0.5, 1, 2, 4 s, the Hammerstein block refitted at each Δt other than the
   artifact's) and `bench evaluate --dt 0.5 --realization balanced --json` (what the deployed delta realization
   gains in float32 over the balanced one).
2. Your own motor: the three commands of the IPM example (`docs/tutorials/own-motor.md`): `bench data`,
   `bench identify --all-kinds`, `bench evaluate` of both kinds on the two held-out profiles, each timed, with
   the pooled float32 RMSE and max error per node, the baselines, and the parameters that ended on a bound.
3. The same identification from three priors (issue 24's table): the example's own, `table1` (another motor's)
   at bounds 0.5-2 (what `bench motor template` gives a new user) and `--prior auto`; per prior the held-out
   RMSE and max of winding and PM for both kinds, the parameters on a bound and frozen, the Hammerstein ridge
   and stator weight the cross-validation chose, the named prior's scale factors, and the wall and CPU time of
   `bench identify` with its split.

Every figure comes from the commands' own `--json`. Writes its record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

from record import Record, add_record_arguments  # noqa: E402

IPM = ROOT / "examples" / "motor-ipm"
HELD_OUT = ("profile_09.csv", "profile_10.csv")


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


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


TABLE1_PRIOR = '{"parameters": "table1", "bounds": [0.5, 2]}\n'   # bench motor template's thermal_prior
PRIORS = ("own", "table1 0.5-2", "auto")


def ipm_data(work: Path) -> tuple[Path, float]:
    """The IPM example's ten profiles (`bench data`) and the seconds it took."""
    data = work / "ipm"
    _, data_s = bench("data", "--motor", str(IPM / "motor.json"), "--out", str(data), "--quiet")
    return data, data_s


def identify_ipm(work: Path, data: Path, prior: str) -> dict:
    """`bench identify --all-kinds` of the IPM example from `prior` (PRIORS): its JSON, wall and CPU time, artifact."""
    option = {"own": (), "auto": ("--prior", "auto")}.get(prior)
    if option is None:
        (work / "table1.json").write_text(TABLE1_PRIOR, encoding="utf-8")
        option = ("--prior", str(work / "table1.json"))
    out = work / prior.split()[0] / "model.json"
    cpu = children_cpu_s()
    identified, seconds = bench(
        "identify", "--motor", str(IPM / "motor.json"), "--mapping", str(IPM / "mapping.json"), "--train",
        str(data / "profile_0[1-8].csv"), "--validate", *(str(data / f) for f in HELD_OUT), "--out", str(out),
        "--all-kinds", *option)
    return {"json": identified, "seconds": seconds, "cpu_s": children_cpu_s() - cpu, "out": out,
            "load_average": os.getloadavg()[0]}


def evaluate_ipm(data: Path, identified: dict) -> tuple[dict, float]:
    """Both kinds on the held-out profiles, wherever --kind auto put them (identify's `artifacts`)."""
    artifacts = identified["artifacts"]
    return bench("evaluate", "--model", artifacts["hammerstein"], "--model", artifacts["lti-lptn"],
                 "--mapping", str(IPM / "mapping.json"), "--data", *(str(data / f) for f in HELD_OUT))


def ipm_example(data: Path, data_s: float, own: dict) -> dict:
    """The tutorial's commands with the example's own prior: per kind and node, and the baselines."""
    identified, identify_s = own["json"], own["seconds"]
    evaluated, evaluate_s = evaluate_ipm(data, identified)
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
            "parameters_on_bounds": on_bounds, "deployed_kind": identified.get("deployed_kind"), "models": models}


def prior_row(data: Path, prior: str, run: dict) -> dict:
    """One row of the priors table: held-out figures of both kinds, bounds, frozen, ridge, time."""
    identified = run["json"]
    evaluated, _ = evaluate_ipm(data, identified)
    models = {m["kind"]: _node_figures(m["pooled"]["nodes"]) for m in evaluated["models"]}
    selection = identified.get("regularization") or {}
    row = {"prior": prior, "identify_s": round(run["seconds"], 1), "identify_cpu_s": round(run["cpu_s"], 1),
           "timings_s": {k: round(v, 1) for k, v in identified["timings_s"].items()},
           "load_average": round(run["load_average"], 2),
           "on_bounds": [h["name"] for h in identified.get("parameters_on_bounds") or []],
           "frozen": list((identified.get("polish") or {}).get("frozen") or []),
           "ridge_factor": selection.get("factor"), "cv_rms_C": selection.get("cv_rms_C"),
           "cv_limit_rms_C": selection.get("cv_limit_rms_C"), "stator_weight": selection.get("stator_weight"),
           "prior_scales": (identified.get("adapted_prior") or {}).get("scales"),
           "prior_paths": (identified.get("adapted_prior") or {}).get("paths"), "models": models}
    print(f"IPM example, prior {prior}: identify {run['seconds']:.1f} s ({run['cpu_s']:.1f} CPU-s, "
          f"{row['timings_s']}), ridge {row['ridge_factor']}, on a bound {row['on_bounds']}, frozen {row['frozen']}; "
          + "; ".join(f"{kind} winding {m['winding']['rmse_C']:.3f}/{m['winding']['max_abs_C']:.2f}, PM "
                      f"{m['pm']['rmse_C']:.3f}/{m['pm']['max_abs_C']:.2f}" for kind, m in models.items()),
          flush=True)
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--skip-ipm", action="store_true", help="only the built-in motor")
    parser.add_argument("--work", type=Path, default=None, help="keep the IPM example's files here")
    parser.add_argument("--skip-priors", action="store_true", help="not the IPM example from three priors")
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("accuracy", args, parameters={"ipm": not args.skip_ipm,
                                                  "priors": not (args.skip_ipm or args.skip_priors)})
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    record.figures["builtin"] = builtin_motor()
    if not args.skip_ipm:
        with tempfile.TemporaryDirectory(prefix="bench-accuracy-") as tmp:
            work = args.work or Path(tmp)
            data, data_s = ipm_data(work)
            runs = {prior: identify_ipm(work, data, prior) for prior in (PRIORS if not args.skip_priors else
                                                                         PRIORS[:1])}
            record.figures["ipm"] = ipm_example(data, data_s, runs["own"])
            if not args.skip_priors:
                record.figures["ipm_priors"] = [prior_row(data, prior, run) for prior, run in runs.items()]
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
