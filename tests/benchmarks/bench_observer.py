"""Observer benchmark (prints figures; not a test): open loop against the Kalman observer, run as a user runs it.

    python tests/benchmarks/bench_observer.py [--skip-ipm] [--work DIR] [--criterion NAME ...]

1. The built-in motor, packaged Hammerstein artifact, the winding thermocouple `winding_C` as the measurement:
   `bench observer --criterion C --out M` (tuned on the 20 and 60 °C runs; C each of --criterion, default `nodes`:
   the winding and magnet, the magnet no worse than the open loop), then `bench evaluate --model M
   --data out/data/cycle_coolant40.csv` (open loop and observer per node, float32, and the time until a magnet
   started ±30 K off stays within 2 K). (The built-in motor's files have no voltage columns: no flux linkage.)
2. The 60 kW IPM example (`docs/tutorials/own-motor.md`): `bench data --motor`, `bench identify` (the Hammerstein
   model on profiles 1-8), then five observers tuned on profiles 1-8 (each criterion) and evaluated on the
   held-out profiles 9 and 10: (a) the stator NTC (`--measure ntc_C` with the offset, lag and gradient of the
   motor file's `stator_ntc` sensor: a lag state), (b) the flux linkage (`--measure none --flux`, ψ_0 and α_B
   calibrated on profiles 1-8), (c) both, (d) the winding temperature from the stator resistance (`--measure none
   --resistance`, R_s0 and L_q calibrated on profiles 1-8 at low speed), (e) the flux linkage with it; and `bench
   numerics --observer` of (c) on profile 9 (each covariance form over the whole profile in float32, 5 states).

Every figure comes from the commands' own `--json`; each command is timed. Writes its record
(`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

from bench_accuracy import HELD_OUT, IPM, bench  # noqa: E402
from record import Record, add_record_arguments  # noqa: E402

CRITERIA = ("nodes",)      # the default of --criterion
BUILTIN_VALIDATION = "out/data/cycle_coolant40.csv"
EVALUATIONS = "150"      # Nelder-Mead converges within about 100-150 filter runs on these files
NUMERICS_CASE = "ntc+flux"     # the IPM filter whose covariance forms the method page compares
NTC_SENSOR = "stator_ntc"


def _metrics(m: dict) -> dict:
    return {"rmse_C": m["rmse"], "max_abs_C": m["max_abs"]}


def observer_figures(evaluated: dict) -> dict:
    """Per file of `bench evaluate`'s observer report: open loop and observer per node, the recovery times (None:
    never within the band by the end of the file) and the observer's |float32 - float64|."""
    (model,) = evaluated["models"]
    obs = model["observer"]
    return {"node": obs["node"], "column": obs["column"], "form": obs["form"], "states": obs.get("states"),
            "measurements": obs.get("measurements"),
            "files": [{"file": Path(f["file"]).name, "measured_node": f["measured_node"],
                       "measured_nodes": f.get("measured_nodes", [f["measured_node"]]),
                       "nodes": {node: {"open_loop": _metrics(m["open_loop"]), "observer": _metrics(m["observer"])}
                                 for node, m in f["nodes"].items()},
                       "recovery": f["recovery"], "max_abs_f32_minus_f64_C": f["max_abs_f32_minus_f64_C"]}
                      for f in obs["files"]]}


def tuning_figures(tuned: dict) -> dict:
    """What `bench observer` tuned: Q per node, R, the criterion's value and how many filter runs it took."""
    return {"q_C2_per_step": tuned["q_C2_per_step"], "q_per_step": tuned["q_per_step"], "R_C2": tuned["R_C2"],
            "R_scale": tuned["R_scale"], "criterion_value": tuned["criterion_value"],
            "evaluations": tuned["evaluations"], "measurement": tuned["measurement"],
            "measurements": tuned["measurements"], "form": tuned["form"]}


def tune_and_evaluate(work: Path, criterion: str, observer_args: list[str], evaluate_args: list[str],
                      label: str, case: str = "") -> dict:
    model = work / f"observer-{criterion}{'-' + case.replace('+', '-') if case else ''}.json"
    tuned, tune_s = bench("observer", *observer_args, "--criterion", criterion, "--evaluations", EVALUATIONS,
                          "--out", str(model))
    evaluated, evaluate_s = bench("evaluate", "--model", str(model), *evaluate_args)
    figures = observer_figures(evaluated)
    for f in figures["files"]:
        pm = f["nodes"]["pm"]
        times = ", ".join(f"{r['offset_K']:+g} K {_seconds(r['open_loop_s'])} -> {_seconds(r['observer_s'])}"
                          for r in f["recovery"])
        print(f"{label} {case or criterion:10} {f['file']}: magnet RMSE open loop {pm['open_loop']['rmse_C']:.3f}, "
              f"observer {pm['observer']['rmse_C']:.3f} °C; within 2 K: {times}")
    print(f"{label} {criterion:10}: bench observer {tune_s:.1f} s, bench evaluate {evaluate_s:.1f} s")
    return {"criterion": criterion, "case": case, "tuning": tuning_figures(tuned), "observer_s": round(tune_s, 1),
            "evaluate_s": round(evaluate_s, 1), "model": model, **figures}


def _seconds(value: float | None) -> str:
    return "never" if value is None else f"{value:.0f} s"


def _public(run: dict) -> dict:
    return {k: v for k, v in run.items() if k != "model"}


def builtin_motor(work: Path, criteria: tuple[str, ...]) -> dict:
    runs = [tune_and_evaluate(work, c, [], ["--data", BUILTIN_VALIDATION], "built-in") for c in criteria]
    return {"validation": Path(BUILTIN_VALIDATION).name, "runs": [_public(r) for r in runs]}


def numerics(model: Path, data: str, criterion: str) -> dict:
    forms, numerics_s = bench("numerics", "--observer", "--model", str(model), "--data", data, "--mapping",
                              str(IPM / "mapping.json"))
    for row in forms["rows"]:
        print(f"IPM {row['form']:13}: min eig P {row['min_eigenvalue']:.4g}, max |P-Pᵀ|/|P| "
              f"{row['max_symmetry_error']:.1e}, max |f32 - f64| {row['max_abs_f32_minus_f64_C']:.1e} °C")
    return {"case": NUMERICS_CASE, "criterion": criterion, "data": Path(forms["data"]).name,
            "realization": forms["realization"], "dt_s": forms["dt"], "deployed_form": forms["deployed_form"],
            "rows": forms["rows"], "seconds": round(numerics_s, 1)}


def ntc_sensor() -> dict:
    """The IPM example's stator NTC as its motor file describes it (offset, lag)."""
    motor = json.loads((IPM / "motor.json").read_text(encoding="utf-8"))
    found = _named(motor, NTC_SENSOR)
    if not found:
        sys.exit(f"{IPM / 'motor.json'} has no sensor {NTC_SENSOR!r}")
    return found[0]


def _named(node, name: str) -> list[dict]:
    """Every dict named `name` anywhere in the motor file (the sensors, wherever the file nests them)."""
    if isinstance(node, dict):
        return ([node] if node.get("name") == name else []) + [s for v in node.values() for s in _named(v, name)]
    if isinstance(node, list):
        return [s for v in node for s in _named(v, name)]
    return []


def ipm_cases(sensor: dict) -> dict[str, list[str]]:
    """The IPM example's measurements: (a) the NTC, (b) the flux linkage, (c) both, (d) the winding resistance, (e)
    the flux linkage with the winding resistance (the NTC and the resistance would share the sensor slot over CAN)."""
    ntc = ["--measure", "ntc_C", "--offset", f"{sensor['offset']:g}", "--lag", f"{sensor['lag_s']:g}",
           "--gradient", f"{sensor.get('gradient', 0.0):g}"]
    # the IPM's winding-resistance calibration leaves 65 K RMS (the tuning then switches it off): `bench observer`
    # refuses it unless forced; the cases keep it to record what it does
    resistance = ["--resistance", "--resistance-force"]
    return {"ntc": ntc, "flux": ["--measure", "none", "--flux"], "ntc+flux": [*ntc, "--flux"],
            "res": ["--measure", "none", *resistance], "flux+res": ["--measure", "none", "--flux", *resistance]}


def ipm_example(work: Path, criteria: tuple[str, ...]) -> dict:
    motor, mapping = str(IPM / "motor.json"), str(IPM / "mapping.json")
    data = work / "ipm"
    _, data_s = bench("data", "--motor", motor, "--out", str(data), "--quiet")
    train = str(data / "profile_0[1-8].csv")
    held_out = [str(data / f) for f in HELD_OUT]
    _, identify_s = bench("identify", "--motor", motor, "--mapping", mapping, "--train", train,
                          "--validate", *held_out, "--out", str(data / "model.json"), "--kind", "hammerstein")
    sensor = ntc_sensor()
    common = ["--model", str(data / "model.json"), "--train", train, "--mapping", mapping]
    runs = [tune_and_evaluate(data, criterion, [*common, *args], ["--mapping", mapping, "--data", *held_out], "IPM",
                              case) for criterion in criteria for case, args in ipm_cases(sensor).items()]
    print(f"IPM example: bench data {data_s:.1f} s, bench identify {identify_s:.1f} s")
    model = next(r["model"] for r in runs if r["case"] == NUMERICS_CASE and r["criterion"] == criteria[0])
    return {"held_out": list(HELD_OUT), "sensor": {"column": "ntc_C", "offset_C": sensor["offset"],
                                                   "lag_s": sensor["lag_s"], "gradient": sensor.get("gradient")},
            "data_s": round(data_s, 1), "identify_s": round(identify_s, 1), "runs": [_public(r) for r in runs],
            "numerics": numerics(model, held_out[0], criteria[0])}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--skip-ipm", action="store_true", help="only the built-in motor")
    parser.add_argument("--work", type=Path, default=None, help="keep the artifacts and the IPM example's files here")
    parser.add_argument("--criterion", nargs="+", default=list(CRITERIA),
                        help=f"tuning criteria to run (default {' '.join(CRITERIA)})")
    add_record_arguments(parser)
    args = parser.parse_args()
    criteria = tuple(args.criterion)
    record = Record("observer", args, parameters={"ipm": not args.skip_ipm, "criteria": list(criteria)})
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="bench-observer-") as tmp:
        work = (args.work or Path(tmp)).resolve()
        work.mkdir(parents=True, exist_ok=True)
        record.figures["builtin"] = builtin_motor(work, criteria)
        if not args.skip_ipm:
            record.figures["ipm"] = ipm_example(work, criteria)
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
