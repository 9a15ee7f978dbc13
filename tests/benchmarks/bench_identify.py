"""Benchmark (not a test): wall time of PSO 220x100 and of the Hammerstein LM fit, and peak memory.

    python tests/benchmarks/bench_identify.py [--data DIR]

The first call of the compiled kernel is timed separately (numba compiles or loads its cache). Writes its record
(`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from record import Record, add_record_arguments  # noqa: E402

from bench.drive.dataset import load_dataset  # noqa: E402
from bench.drive.generate import ensure_default_datasets  # noqa: E402
from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps  # noqa: E402
from bench.model.builder import ModelSpec, physical_block  # noqa: E402
from bench.model.hammerstein_fit import fit_hammerstein  # noqa: E402
from bench.model.identify import prepare_runs  # noqa: E402
from bench.model.lptn_fit import batch_cost, identify_lptn  # noqa: E402
from bench.thermal.parameters import TABLE1  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data", type=Path, default=None)
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("identify", args, parameters={"swarm": 220, "iterations": 100, "train": "20 and 60 °C runs",
                                                  "dt_s": 0.5})
    paths = ensure_default_datasets(args.data)
    datasets = [load_dataset(paths[c]) for c in (20, 60)]
    maps = nominal_loss_maps()
    runs = prepare_runs(datasets, maps, VIRTUAL_MOTOR, 0.5)
    started = time.perf_counter()
    batch_cost([TABLE1.as_vector()], runs, 0.5, [1.0] * 4)
    first_call = time.perf_counter() - started
    print(f"kernel first call (compile or cache load): {first_call:.2f} s")
    started = time.perf_counter()
    fit = identify_lptn(runs, 0.5)
    pso = time.perf_counter() - started
    print(f"PSO swarm 220 x 100 iterations on 2 x 7274 s at dt 0.5 s: {pso:.1f} s "
          f"({fit.evaluations} model runs, cost {fit.cost:.4f})")
    record.figures.update(kernel_first_call_s=round(first_call, 2), pso_s=round(pso, 1),
                          pso_model_runs=fit.evaluations, pso_cost=fit.cost, lm={})
    base = physical_block(ModelSpec("lti-lptn", fit.params, 0.5, "zoh", "physical", maps, VIRTUAL_MOTOR))
    for path in ("statespace", "polynomial"):
        started = time.perf_counter()
        ham = fit_hammerstein(base, fit.params, runs, path=path)
        seconds = time.perf_counter() - started
        print(f"LM Hammerstein ({path}, {ham.coordinates} coordinates), 100 iterations: "
              f"{seconds:.1f} s, RMS {ham.cost_initial:.4f} -> {ham.cost_final:.4f} °C")
        record.figures["lm"][path] = {"seconds": round(seconds, 1), "rms_initial_C": ham.cost_initial,
                                      "rms_final_C": ham.cost_final}
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory: {peak:.0f} MB")
    record.figures["peak_rss_MB"] = round(peak)
    record.write()


if __name__ == "__main__":
    main()
