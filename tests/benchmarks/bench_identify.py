"""Benchmark (not a test): wall time of PSO 220x100 and of the Hammerstein LM fit, and peak memory.

    python tests/benchmarks/bench_identify.py [--data DIR]

The first call of the compiled kernel is timed separately (numba compiles or loads its cache).
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

from bench.drive.dataset import load_dataset
from bench.drive.generate import ensure_default_datasets
from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps
from bench.model.builder import ModelSpec, physical_block
from bench.model.hammerstein_fit import fit_hammerstein
from bench.model.identify import prepare_runs
from bench.model.lptn_fit import batch_cost, identify_lptn
from bench.thermal.parameters import TABLE1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data", type=Path, default=None)
    args = parser.parse_args()
    paths = ensure_default_datasets(args.data)
    datasets = [load_dataset(paths[c]) for c in (20, 60)]
    maps = nominal_loss_maps()
    runs = prepare_runs(datasets, maps, VIRTUAL_MOTOR, 0.5)
    started = time.perf_counter()
    batch_cost([TABLE1.as_vector()], runs, 0.5, [1.0] * 4)
    print(f"kernel first call (compile or cache load): {time.perf_counter() - started:.2f} s")
    started = time.perf_counter()
    fit = identify_lptn(runs, 0.5)
    pso = time.perf_counter() - started
    print(f"PSO swarm 220 x 100 iterations on 2 x 7274 s at dt 0.5 s: {pso:.1f} s "
          f"({fit.evaluations} model runs, cost {fit.cost:.4f})")
    base = physical_block(ModelSpec("lti-lptn", fit.params, 0.5, "zoh", "physical", maps, VIRTUAL_MOTOR))
    for path in ("statespace", "polynomial"):
        started = time.perf_counter()
        ham = fit_hammerstein(base, fit.params, runs, path=path)
        print(f"LM Hammerstein ({path}, {ham.coordinates} coordinates), 100 iterations: "
              f"{time.perf_counter() - started:.1f} s, RMS {ham.cost_initial:.4f} -> {ham.cost_final:.4f} °C")
    print(f"peak resident memory: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
