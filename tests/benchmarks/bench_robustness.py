"""Robustness benchmark (prints figures; not a test): `bench robustness` as a user runs it.

    python tests/benchmarks/bench_robustness.py [--skip-ipm] [--skip-serial] [--rows N] [--seeds N] [--work DIR]
                                                [--ipm-inputs DIR]

1. The default study (the packaged Hammerstein model on the built-in motor's 40 °C validation run, every
   perturbation kind at its defaults) on the embedded local cluster of 2 workers and, in the same sitting, in a
   serial loop (`--serial`): each one's wall time and the peak memory of its whole process tree (the workers
   included, sampled every 0.2 s), and whether the two tables agree.
2. The 60 kW IPM example (`docs/tutorials/own-motor.md`): `bench data --motor`, `bench identify` (its Hammerstein
   model on profiles 1-8), `bench observer` twice (as `bench_observer.py` tunes them: the stator NTC with its
   offset, lag and gradient, and the flux linkage), then the observer study (`examples/robustness/observer.toml`)
   of both observer artifacts on the held-out profile 9: open loop and observer side by side, every kind at its
   defaults, the measurement channels perturbed too. `--ipm-inputs DIR` reuses the data, model and observer
   artifacts an earlier run kept with `--work` (DIR/ipm).

The figures kept: per study (model on data), each node's clean RMSE and the three perturbations that move it most
(Δ RMSE at their largest magnitude, with the Monte Carlo spread), and the worst case. Every figure comes from the
study's own robustness.json. Writes its record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[2]

from bench_accuracy import HELD_OUT, IPM, bench  # noqa: E402
from record import Record, add_record_arguments  # noqa: E402

TOP = 3


class TreeMemory:
    """The peak resident memory of a process and all its descendants, sampled in a thread."""

    def __init__(self, pid: int, period_s: float = 0.2):
        self.root, self.period_s, self.peak = psutil.Process(pid), period_s, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        while not self._stop.is_set():
            try:
                tree = [self.root, *self.root.children(recursive=True)]
            except psutil.Error:
                return
            total = 0
            for proc in tree:
                try:
                    total += proc.memory_info().rss
                except psutil.Error:
                    pass
            self.peak = max(self.peak, total)
            self._stop.wait(self.period_s)

    def stop(self) -> int:
        self._stop.set()
        self._thread.join()
        return self.peak


def study(out: Path, *options: str) -> tuple[dict, float, int]:
    """`bench robustness OPTIONS --out OUT --json` in a fresh process: its summary, wall time and peak tree memory."""
    started = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "bench", "robustness", *options, "--out", str(out), "--json"],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=dict(os.environ, MPLBACKEND="Agg"))
    memory = TreeMemory(process.pid)
    stdout, stderr = process.communicate()
    peak = memory.stop()
    seconds = time.perf_counter() - started
    if process.returncode != 0:
        sys.exit(f"bench robustness {' '.join(options)} failed ({process.returncode}): {stderr.strip()[-600:]}")
    return json.loads(stdout), seconds, peak


def study_figures(report: dict) -> list[dict]:
    """Per (model, data): clean RMSE per node, the top perturbations per node and the worst case."""
    out = []
    for s in report["studies"]:
        out.append({"name": s["name"], "model_sha256": s["model_sha256"], "data": Path(s["data"]).name,
                    "cases": len(s["cases"]), "incomplete": len(s["incomplete"]),
                    "clean_rmse_C": {n: s["clean"][n]["rmse"] for n in s["nodes"]} if s["clean"] else None,
                    "top": {n: [{k: r.get(k) for k in ("perturbation", "magnitude", "unit", "diverged", "d_rmse_C",
                                                      "spread_C")} for r in s["ranking"][n][:TOP]]
                            for n in s["nodes"]}})
    return out


def _print_top(label: str, figures: list[dict]) -> None:
    for s in figures:
        top = s["top"].get("pm", [])
        print(f"{label} {s['name']}: magnet moved most by " + "; ".join(
            f"{r['perturbation']} at {r['magnitude']:g} {r['unit']} "
            + ("(diverged)" if r["diverged"] else f"({r['d_rmse_C']:+.3f} ± {r['spread_C']:.3f} °C)") for r in top))


def _tables_agree(a: Path, b: Path) -> bool:
    """The two studies' sensitivity tables (every case's figures), ignoring where each ran."""
    def cases(path: Path) -> list:
        return [s["cases"] for s in json.loads(path.read_text(encoding="utf-8"))["studies"]]
    return cases(a) == cases(b)


def builtin_study(work: Path, common: list[str], serial: bool) -> dict:
    summary, seconds, peak = study(work / "builtin-2w", *common, "--workers", "2")
    report = json.loads(Path(summary["json"]).read_text(encoding="utf-8"))
    figures = {"cases": summary["cases"], "diverged": summary["diverged"], "not_done": summary["not_done"],
               "workers_2": {"wall_s": round(seconds, 1), "study_wall_s": summary["wall_s"],
                             "peak_tree_MiB": round(peak / 2**20)},
               "studies": study_figures(report)}
    print(f"default study: {summary['cases']} cases on 2 workers in {seconds:.1f} s, peak {peak / 2**20:.0f} MiB")
    _print_top("built-in", figures["studies"])
    if serial:
        serial_summary, serial_s, serial_peak = study(work / "builtin-serial", *common, "--serial")
        figures["serial"] = {"wall_s": round(serial_s, 1), "study_wall_s": serial_summary["wall_s"],
                             "peak_tree_MiB": round(serial_peak / 2**20)}
        figures["speedup"] = round(serial_summary["wall_s"] / summary["wall_s"], 2)
        figures["tables_agree"] = _tables_agree(Path(summary["json"]), Path(serial_summary["json"]))
        print(f"serial loop: {serial_s:.1f} s, peak {serial_peak / 2**20:.0f} MiB; speed-up "
              f"{figures['speedup']}x; tables agree: {figures['tables_agree']}")
    return figures


OBSERVER_SPEC = ROOT / "examples" / "robustness" / "observer.toml"
OBSERVER_DATA = HELD_OUT[:1]      # the observer runs its lanes one by one: one held-out profile keeps it minutes


def ipm_inputs(work: Path, reuse: Path | None) -> tuple[Path, dict[str, Path], dict]:
    """The IPM example's data directory and its observer artifacts by case (ntc, flux); made here, or reused."""
    from bench_observer import EVALUATIONS, ipm_cases, ntc_sensor

    cases = ipm_cases(ntc_sensor())
    if reuse is not None:
        data = reuse
        observers = {case: data / f"observer-{case}.json" for case in ("ntc", "flux")}
        missing = [p for p in (data / "model.json", *observers.values()) if not p.exists()]
        if missing:
            sys.exit(f"--ipm-inputs {reuse} lacks {missing[0].name}; run once with --work to make it")
        return data, observers, {"reused": str(reuse)}
    motor, mapping = str(IPM / "motor.json"), str(IPM / "mapping.json")
    data = work / "ipm"
    bench("data", "--motor", motor, "--out", str(data), "--quiet")
    train = str(data / "profile_0[1-8].csv")
    _, identify_s = bench("identify", "--motor", motor, "--mapping", mapping, "--train", train, "--validate",
                          *(str(data / f) for f in HELD_OUT), "--out", str(data / "model.json"),
                          "--kind", "hammerstein")
    observers, timings = {}, {"identify_s": round(identify_s, 1)}
    for case in ("ntc", "flux"):
        observers[case] = data / f"observer-{case}.json"
        _, seconds = bench("observer", "--model", str(data / "model.json"), "--train", train, "--mapping", mapping,
                           *cases[case], "--criterion", "magnet", "--evaluations", EVALUATIONS,
                           "--out", str(observers[case]))
        timings[f"observer_{case}_s"] = round(seconds, 1)
    return data, observers, timings


def side_by_side(report: dict, node: str = "pm") -> list[dict]:
    """Per (observer model, data): the clean RMSE and the three perturbations that move `node` most, open loop
    and observer, and what the observer measures."""
    out = []
    for s in report["studies"]:
        obs = s.get("observer")
        if not obs:
            continue

        def top(part: dict) -> list[dict]:
            return [{k: r.get(k) for k in ("perturbation", "magnitude", "unit", "diverged", "d_rmse_C", "spread_C")}
                    for r in part["ranking"][node][:TOP]]

        out.append({"name": s["name"], "data": Path(s["data"]).name, "model_sha256": s["model_sha256"],
                    "measurements": obs["measurements"], "measured_nodes": obs["measured_nodes"],
                    "cases": len(s["cases"]), "incomplete": len(s["incomplete"]) + len(obs["incomplete"]),
                    "clean_rmse_C": {"open_loop": s["clean"][node]["rmse"] if s["clean"] else None,
                                     "observer": obs["clean"][node]["rmse"] if obs["clean"] else None},
                    "top": {"open_loop": top(s), "observer": top(obs)}})
    return out


def _print_side_by_side(figures: list[dict]) -> None:
    def line(rows: list[dict]) -> str:
        return "; ".join(f"{r['perturbation']} at {r['magnitude']:g} {r['unit']} " + (
            "(diverged)" if r["diverged"] else f"({r['d_rmse_C']:+.3f} ± {r['spread_C']:.3f} °C)") for r in rows)
    for s in figures:
        measured = ", ".join(f"{m['kind']} of the {m['node']}" for m in s["measurements"])
        print(f"IPM {s['name']} ({measured}): magnet clean RMSE open loop {s['clean_rmse_C']['open_loop']:.3f}, "
              f"observer {s['clean_rmse_C']['observer']:.3f} °C")
        print(f"  open loop: {line(s['top']['open_loop'])}")
        print(f"  observer:  {line(s['top']['observer'])}")


def ipm_study(work: Path, common: list[str], reuse: Path | None) -> dict:
    data, observers, timings = ipm_inputs(work, reuse)
    models = [a for case in ("ntc", "flux") for a in ("--model", str(observers[case]))]
    summary, seconds, peak = study(work / "ipm-observer-study", *common, "--spec", str(OBSERVER_SPEC), *models,
                                   "--mapping", str(IPM / "mapping.json"),
                                   "--data", *(str(data / f) for f in OBSERVER_DATA), "--workers", "2")
    report = json.loads(Path(summary["json"]).read_text(encoding="utf-8"))
    figures = {**timings, "spec": OBSERVER_SPEC.name, "seeds": report["study"]["seeds"], "cases": summary["cases"],
               "diverged": summary["diverged"], "not_done": summary["not_done"], "wall_s": round(seconds, 1),
               "peak_tree_MiB": round(peak / 2**20), "data": list(OBSERVER_DATA),
               "observers": side_by_side(report)}
    print(f"IPM example, observer study: {summary['cases']} cases on 2 workers in {seconds:.1f} s")
    _print_side_by_side(figures["observers"])
    return figures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--skip-ipm", action="store_true", help="only the built-in motor")
    parser.add_argument("--skip-serial", action="store_true", help="no serial loop to compare with")
    parser.add_argument("--rows", type=int, default=None, help="only the first N rows of each data file")
    parser.add_argument("--seeds", type=int, default=None, help="Monte Carlo seeds per random case")
    parser.add_argument("--work", type=Path, default=None, help="keep the studies here")
    parser.add_argument("--ipm-inputs", type=Path, default=None, metavar="DIR",
                        help="reuse the IPM example's data, model.json and observer-{ntc,flux}.json in DIR")
    add_record_arguments(parser)
    args = parser.parse_args()
    common = [*(["--rows", str(args.rows)] if args.rows else []), *(["--seeds", str(args.seeds)] if args.seeds
                                                                     else [])]
    record = Record("robustness", args, parameters={"rows": args.rows, "seeds": args.seeds,
                                                    "ipm": not args.skip_ipm, "serial": not args.skip_serial,
                                                    "ipm_inputs_reused": args.ipm_inputs is not None})
    with tempfile.TemporaryDirectory(prefix="bench-robustness-") as scratch:
        work = args.work or Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        record.figures["builtin"] = builtin_study(work, common, serial=not args.skip_serial)
        if not args.skip_ipm:
            record.figures["ipm_observer"] = ipm_study(work, common, args.ipm_inputs)
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
