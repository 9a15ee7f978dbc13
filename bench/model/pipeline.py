"""Datasets on disk -> identification -> validation metrics: what `bench identify` and `bench evaluate` share."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from bench.drive.dataset import Dataset, dataset_filename, load_dataset
from bench.drive.generate import ensure_default_datasets
from bench.errors import BenchError
from bench.model.choices import DEPLOYED_REALIZATION
from bench.model.deploy import DEPLOYED_NODES
from bench.model.fileeval import PRECISIONS, evaluate_file, summarize
from bench.model.identify import (
    IDENTIFICATION_COOLANTS,
    VALIDATION_COOLANT,
    Identification,
    identify,
)
from target_sim.artifact import ArtifactError, ModelArtifact, seal, verify


def load_campaign(data_dir: Path | None) -> dict[int, Dataset]:
    """The 20/40/60 °C datasets from data_dir; the default directory is generated when missing."""
    if data_dir is None:
        paths = ensure_default_datasets()
    else:
        data_dir = Path(data_dir)
        names = ", ".join(dataset_filename(c) for c in sorted((*IDENTIFICATION_COOLANTS, VALIDATION_COOLANT)))
        if data_dir.is_file():
            raise BenchError(f"--data {data_dir} is a file; pass the directory that holds {names} "
                             f"(e.g. 'bench data --out DIR' writes them)")
        if not data_dir.is_dir():
            raise BenchError(f"--data {data_dir} does not exist; run 'bench data --out {data_dir}' to create "
                             f"{names} there, or pass the directory that holds them")
        paths = {c: data_dir / dataset_filename(c) for c in (*IDENTIFICATION_COOLANTS, VALIDATION_COOLANT)}
        missing = [str(p) for p in paths.values() if not p.is_file()]
        if missing:
            raise BenchError(f"dataset {missing[0]} is missing; run 'bench data --out {data_dir}' to create it")
    return {c: load_dataset(p) for c, p in sorted(paths.items())}


def identify_from_directory(data_dir: Path | None, progress: Callable | None = None, **options):
    """The built-in motor's campaign: train on the 20 and 60 °C runs, validate on 40 °C."""
    datasets = load_campaign(data_dir)
    result = identify([datasets[c] for c in IDENTIFICATION_COOLANTS], validation=[datasets[VALIDATION_COOLANT]],
                      progress=progress, **options)
    return result, datasets


# the kinds identify compares by default: the Hammerstein model and the network it refines (the packaged artifacts
# record these two, in this order)
COMPARED_KINDS = ("lti-lptn", "hammerstein")


def target_artifact(content: dict) -> ModelArtifact | str:
    """The artifact as the target loads it (sealed and verified), or the sentence with which the target refuses it
    (e.g. a step unstable somewhere in the operating range)."""
    try:
        return verify(seal(content))
    except ArtifactError as exc:
        return str(exc)


def validation_metrics(result: Identification, validation: Sequence[Dataset],
                       realization: str = DEPLOYED_REALIZATION, kinds: Sequence[str] = COMPARED_KINDS) -> dict:
    """Accuracy at the identification Δt on the validation files together, float64 and float32 (the target's
    code), per model kind of `kinds`: {float64: {winding, pm}, float32: {...}, max_abs_f32_minus_f64_C}; a kind whose
    artifact the target would refuse (a step unstable somewhere in the operating range) {"refused": its sentence}."""
    metrics = {}
    for kind in kinds:
        artifact = target_artifact(result.content(kind, realization))
        if isinstance(artifact, str):
            metrics[kind] = {"refused": artifact}
            continue
        pooled = summarize([evaluate_file(artifact, d) for d in validation])
        metrics[kind] = {**{p: {n: pooled["nodes"][n][p] for n in DEPLOYED_NODES} for p in PRECISIONS},
                         "max_abs_f32_minus_f64_C": pooled["max_abs_f32_minus_f64_C"]}
    return metrics
