"""Observer firmware benchmark (prints figures; not a test): the observer's generated C (Bierman-Thornton UD, the
fw_obs_* functions beside the model, bench/firmware/observergen.py and udgen.py) against the open loop and the same
observer deploying its steady-state gain, in the emulated Cortex-M4F, run as a user runs it.

    python tests/benchmarks/bench_firmware_observer.py [--skip-ipm] [--work DIR] [--rows N]

Observers of the Hammerstein model:
1. the built-in motor's winding sensor (`bench observer`, trained on the 20 and 60 °C runs; checked on the 40 °C run);
2. the 60 kW IPM example (`bench data --motor`, `bench identify` on profiles 1-8; checked on the held-out profile 9)
   with (a) its stator NTC (`bench observer --measure ntc_C` with the motor file's offset, lag and gradient: a lag
   state), (b) the flux linkage (`--measure none --flux`), (c) both (two measurements per row), (d) the winding
   temperature from the stator resistance (`--measure none --resistance`) and (e) the flux linkage with it.
For each, `bench firmware build` and `bench firmware check` of the open-loop artifact and of the observer's: the
Cortex-M4 cycles per model step (open loop: fw_step; observer: fw_obs_step, the model step, the covariance's
prediction and the update), bit for bit against the Python float32 reference (outputs, each node's 1-sigma, each
innovation and the periodic checkpoint), the model's own flash (`fw_model.o`: code and constants) and the image's
flash and RAM. The tuning takes two filter runs (`--evaluations 2`): its Q and R change no cycle count. For (b), (c)
and (e), `bench run --engine firmware` over CAN too (exit status, verdict, max |CAN - float32|, the steps that used each
measurement, the measured cycles per step; the load average beside). Writes its record
(docs/results/firmware_observer.json; see tests/benchmarks/record.py) for the results page.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_accuracy import HELD_OUT, IPM, bench  # noqa: E402
from bench_observer import BUILTIN_VALIDATION, ipm_cases, ntc_sensor  # noqa: E402
from record import Record, add_record_arguments  # noqa: E402

GOAL_CYCLES = 3000        # issue 25: predict + update (the whole observer step) of the Hammerstein model
ROWS = 4000


def firmware_figures(model: Path, out: Path, data: list[str], rows: int) -> dict:
    """`bench firmware build` and `check` of one artifact: cycles, bit-exactness, flash and RAM."""
    built, build_s = bench("firmware", "build", "--model", str(model), "--out", str(out))
    checked, check_s = bench("firmware", "check", "--model", str(model), "--firmware", built["elf"], "--rows",
                             str(rows), *data)
    return {"cycles": checked["cycles"], "exec_us_at_90MHz": checked["exec_us_at_90MHz"],
            "mismatches": checked["mismatches"], "steps": checked["steps"], "updates": checked.get("updates"),
            "updates_per_measurement": checked.get("updates_per_measurement"),
            "model_flash": built["model_flash"], "flash_bytes": built["flash_bytes"], "ram_bytes": built["ram_bytes"],
            "stack_used_bytes": checked["stack_used_bytes"], "build_s": round(build_s, 1),
            "check_s": round(check_s, 1)}


def steady_variant(observer: Path) -> Path:
    """The same observer (Q, R, K_ss) deploying the steady-state gain: observer-steady.json beside it."""
    from bench.observer.section import with_observer
    from target_sim.artifact import dumps, load_artifact

    artifact = load_artifact(observer)
    out = observer.with_name(observer.stem + "-steady.json")
    out.write_text(dumps(with_observer(artifact, {**artifact.content["observer"], "form": "steady"})),
                   encoding="utf-8")
    return out


def compare(name: str, open_loop: Path, observer: Path, work: Path, data: list[str], rows: int) -> dict:
    """Open loop, observer (UD) and its steady-state-gain variant of one case, and what the observer adds."""
    from target_sim.artifact import load_artifact
    from target_sim.observer import state_count

    section = load_artifact(observer).content["observer"]
    plain = firmware_figures(open_loop, work / f"fw-{name}-open-loop", data, rows)
    closed = firmware_figures(observer, work / f"fw-{name}-observer", data, rows)
    steady = firmware_figures(steady_variant(observer), work / f"fw-{name}-steady", data, rows)
    added = {"cycles_p50": closed["cycles"]["p50"] - plain["cycles"]["p50"],
             "model_flash_bytes": closed["model_flash"]["bytes"] - plain["model_flash"]["bytes"],
             "model_code_bytes": closed["model_flash"]["code"] - plain["model_flash"]["code"],
             "model_constants_bytes": closed["model_flash"]["constants"] - plain["model_flash"]["constants"],
             "flash_bytes": closed["flash_bytes"] - plain["flash_bytes"],
             "ram_bytes": closed["ram_bytes"] - plain["ram_bytes"]}
    print(f"{name}: {state_count(section)} filter states; cycles per step open loop {plain['cycles']['p50']}, "
          f"observer {closed['cycles']['p50']} (max {closed['cycles']['max']}; goal {GOAL_CYCLES}); "
          f"mismatches {closed['mismatches']} of {closed['steps']} steps ({closed['updates']} updated); "
          f"fw_model.o +{added['model_flash_bytes']} B (code +{added['model_code_bytes']}, constants "
          f"+{added['model_constants_bytes']}), RAM +{added['ram_bytes']} B; steady-state gain "
          f"{steady['cycles']['p50']} cycles, mismatches {steady['mismatches']} of {steady['steps']}")
    return {"case": name, "states": state_count(section),
            "measurement": ", ".join(m["name"] for m in section["measurements"]),
            "open_loop": plain, "observer": closed, "steady": steady, "added": added,
            "goal_met": closed["cycles"]["max"] <= GOAL_CYCLES}


def builtin_motor(work: Path, rows: int) -> list[dict]:
    """The built-in motor's winding sensor as `bench observer` builds it (its default: the winding's output bias,
    five states) and without a bias (the four-state filter issue 25's goal was set for)."""
    from bench.model.default import default_artifact_path

    cases = []
    for name, extra in (("built-in winding sensor", ()), ("built-in winding sensor, --bias none", ("--bias", "none"))):
        model = work / f"builtin-observer{'-' + extra[-1] if extra else ''}.json"
        bench("observer", "--evaluations", "2", *extra, "--out", str(model))
        cases.append(compare(name, default_artifact_path("hammerstein"), model, work, ["--data", BUILTIN_VALIDATION],
                             rows))
    return cases


def ipm_example(work: Path, rows: int) -> tuple[list[dict], list[dict]]:
    motor, mapping = str(IPM / "motor.json"), str(IPM / "mapping.json")
    data = work / "ipm"
    train = str(data / "profile_0[1-8].csv")
    held_out = [str(data / f) for f in HELD_OUT]
    if not (data / "model.json").is_file():      # a --work directory keeps them from an earlier run
        bench("data", "--motor", motor, "--out", str(data), "--quiet")
        bench("identify", "--motor", motor, "--mapping", mapping, "--train", train, "--validate", *held_out,
              "--out", str(data / "model.json"), "--kind", "hammerstein")
    cases, runs = [], []
    for case, args in ipm_cases(ntc_sensor()).items():
        model = work / f"ipm-{case}-observer.json"
        bench("observer", "--model", str(data / "model.json"), "--train", train, "--mapping", mapping, *args,
              "--evaluations", "2", "--out", str(model))
        cases.append(compare(f"IPM example {case}", data / "model.json", model, work,
                             ["--mapping", mapping, "--data", held_out[0]], rows))
        if "flux" in case:
            runs.append(can_run(case, model, work, ["--mapping", mapping, "--data", held_out[0]], rows))
    return cases, runs


def can_run(name: str, model: Path, work: Path, data: list[str], rows: int) -> dict:
    """`bench run --engine firmware` of one observer over CAN: exit status, verdict, agreement, updates, cycles."""
    load = os.getloadavg()[0]
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "bench", "run", "--model", str(model), *data, "--rows", str(rows),
                           "--engine", "firmware", "--log", str(work / f"run-{name}.blf"), "--no-report", "--json"],
                          capture_output=True, text=True, env=dict(os.environ, MPLBACKEND="Agg"))
    seconds = time.perf_counter() - started
    if not done.stdout.strip().startswith("{"):
        sys.exit(f"bench run of {name} failed ({done.returncode}): {done.stderr.strip()[-600:]}")
    summary = json.loads(done.stdout)
    metrics = summary["metrics"]
    observer = metrics.get("observer") or {}
    used = {slot: m["model_steps_updated"] for slot, m in (observer.get("measurements") or {}).items()}
    out = {"case": name, "exit": done.returncode, "verdict": summary.get("verdict"), "rows": rows,
           "model_steps": metrics.get("model_steps"), "missing": summary.get("missing"),
           "max_abs_can_minus_float32_C": max((metrics.get("max_abs_can_minus_float32_C") or {}).values(),
                                              default=None),
           "can_reference": metrics.get("can_reference"), "steps_updated": observer.get("model_steps_updated"),
           "steps_updated_per_slot": used, "m4_cycles": metrics.get("m4_cycles"), "wall_s": round(seconds, 1),
           "load_average": round(load, 2)}
    print(f"bench run --engine firmware, IPM {name}, {rows} rows: exit {out['exit']}, {out['verdict']}; max |CAN - "
          f"f32| {out['max_abs_can_minus_float32_C']} °C; {out['steps_updated']} of {out['model_steps']} steps "
          f"updated ({used}); cycles {out['m4_cycles']}; {seconds:.0f} s at load {load:.1f}")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-ipm", action="store_true", help="only the built-in motor")
    parser.add_argument("--work", type=Path, default=None, help="keep the artifacts, ELFs and IPM files here")
    parser.add_argument("--rows", type=int, default=ROWS, help=f"rows of each check (default {ROWS})")
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("firmware_observer", args, parameters={"rows": args.rows, "goal_cycles": GOAL_CYCLES,
                                                          "held_out": HELD_OUT[0]})
    with tempfile.TemporaryDirectory() as tmp:
        work = (args.work or Path(tmp)).resolve()
        work.mkdir(parents=True, exist_ok=True)
        cases, runs = builtin_motor(work, args.rows), []
        if not args.skip_ipm:
            ipm, runs = ipm_example(work, args.rows)
            cases += ipm
    record.figures["cases"] = cases
    record.figures["can_runs"] = runs
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
