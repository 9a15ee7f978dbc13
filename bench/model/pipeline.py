"""Datasets on disk -> identification -> validation metrics: what `bench identify` and `bench evaluate` share."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.drive.dataset import Dataset, dataset_filename, ensure_default_datasets, load_dataset
from bench.errors import BenchError
from bench.model.builder import physical_block
from bench.model.identify import (
    IDENTIFICATION_COOLANTS,
    VALIDATION_COOLANT,
    Identification,
    identify,
    prepare_runs,
    simulate_float64,
    winding_pm_metrics,
)
from bench.model.runs import ModelRun, drive_matrix
from target_sim.artifact import seal, verify
from target_sim.model import run_offline


def load_campaign(data_dir: Path | None) -> dict[int, Dataset]:
    """The 20/40/60 °C datasets from data_dir; the default directory is generated when missing."""
    if data_dir is None:
        paths = ensure_default_datasets()
    else:
        paths = {c: Path(data_dir) / dataset_filename(c) for c in (*IDENTIFICATION_COOLANTS, VALIDATION_COOLANT)}
        missing = [str(p) for p in paths.values() if not p.is_file()]
        if missing:
            raise BenchError(f"dataset {missing[0]} is missing; run 'bench data --out {data_dir}' to create it")
    return {c: load_dataset(p) for c, p in sorted(paths.items())}


def identify_from_directory(data_dir: Path | None, progress: Callable | None = None, **options):
    datasets = load_campaign(data_dir)
    result = identify([datasets[c] for c in IDENTIFICATION_COOLANTS], progress=progress, **options)
    return result, datasets


def float32_estimate(content: dict, dataset: Dataset, run: ModelRun) -> np.ndarray:
    """(steps, 4) of the artifact run exactly as the target runs it (float32)."""
    _, outputs = run_offline(verify(seal(content)), drive_matrix(dataset), run.initial)
    return outputs.astype(np.float64)


def validation_metrics(result: Identification, datasets: dict[int, Dataset]) -> dict:
    """Table 5 analogue at the identification Δt on the 40 °C run, plus the float32 deployed model."""
    validation = datasets[VALIDATION_COOLANT]
    run = prepare_runs([validation], result.loss_maps, result.motor, result.dt)[0]
    lti = simulate_float64(physical_block(result.spec("lti-lptn", "physical")), result.lptn.params, None, run)
    ham = result.hammerstein.model
    ham64 = simulate_float64(ham.block, result.lptn.params, ham.sigmoid, run)
    ham32 = float32_estimate(result.content("hammerstein", "balanced"), validation, run)
    return {
        "lti-lptn float64": winding_pm_metrics(lti, run),
        "hammerstein float64": winding_pm_metrics(ham64, run),
        "hammerstein float32 balanced": {
            **winding_pm_metrics(ham32, run),
            "max_abs_f32_minus_f64_C": float(np.max(np.abs(ham32 - ham64))),
        },
    }
