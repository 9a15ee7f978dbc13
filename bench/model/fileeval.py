"""A model artifact on any number of data files: per-file and pooled accuracy of every measured node, in float64
and float32 (the target's code), beside the baselines the artifact records (bench.model.baselines).

Every file is its own run from its own initial state; pooled figures are over all model steps of all files
(MSE and max |error| over the union, NRMSE against the pooled reference's spread).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.drive.dataset import MEASURED_NODES, Dataset
from bench.model.artifact_eval import ArtifactEvaluation, evaluate_artifact
from bench.model.baselines import NODES as BASELINE_NODES
from bench.model.baselines import baseline_estimates
from bench.model.metrics import error_metrics
from target_sim.artifact import OUTPUTS, ModelArtifact

PRECISIONS = ("float64", "float32")
# model output index of each measured node (OUTPUTS: yoke, winding, tooth, magnet)
OUTPUT_INDEX = {"winding": OUTPUTS.index("winding"), "pm": OUTPUTS.index("magnet"), "yoke": OUTPUTS.index("yoke"),
                "tooth": OUTPUTS.index("tooth")}


@dataclass(frozen=True)
class FileResult:
    """One file: the estimates, and per node the reference at the model's step times."""

    dataset: Dataset
    evaluation: ArtifactEvaluation
    references: dict[str, np.ndarray]
    baselines: dict[str, dict[str, np.ndarray]]

    def estimate(self, node: str, precision: str) -> np.ndarray:
        return getattr(self.evaluation, precision)[:, OUTPUT_INDEX[node]]


def measured_nodes(dataset: Dataset) -> list[str]:
    return [node for node, column in MEASURED_NODES.items() if dataset.has(column)]


def evaluate_file(artifact: ModelArtifact, dataset: Dataset) -> FileResult:
    evaluation = evaluate_artifact(artifact, dataset)
    times = evaluation.run.step_time_s
    references = {node: np.interp(times, dataset.time_s, dataset.column(MEASURED_NODES[node]))
                  for node in measured_nodes(dataset)}
    baselines = baseline_estimates(artifact.content.get("provenance", {}).get("baselines", {}), evaluation.run)
    return FileResult(dataset, evaluation, references, baselines)


def _node_metrics(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    estimate = np.concatenate([e for e, _ in pairs])
    reference = np.concatenate([r for _, r in pairs])
    with np.errstate(over="ignore", invalid="ignore"):
        return error_metrics(estimate, reference)


def summarize(results: Sequence[FileResult]) -> dict:
    """{nodes: {node: {float64, float32}}, baselines: {name: {node: metrics}}, max_abs_f32_minus_f64_C} over the
    given files together (one file: that file's figures)."""
    nodes = [n for n in OUTPUT_INDEX if all(n in r.references for r in results)]
    out: dict = {"steps": int(sum(len(r.evaluation.run.step_time_s) for r in results)), "nodes": {}}
    for node in nodes:
        out["nodes"][node] = {p: _node_metrics([(r.estimate(node, p), r.references[node]) for r in results])
                              for p in PRECISIONS}
    names = [b for b in results[0].baselines if all(b in r.baselines for r in results)] if results else []
    out["baselines"] = {b: {node: _node_metrics([(r.baselines[b][node], r.references[node]) for r in results])
                            for node in BASELINE_NODES} for b in names}
    out["max_abs_f32_minus_f64_C"] = max(r.evaluation.max_abs_f32_minus_f64 for r in results)
    return out


def evaluate_files(artifact: ModelArtifact, datasets: Sequence[Dataset]) -> tuple[list[FileResult], dict]:
    """(per-file results, report {files: [...], pooled: {...}})."""
    results = [evaluate_file(artifact, d) for d in datasets]
    files = [{"file": str(r.dataset.path), "sha256": r.dataset.sha256, "rows": r.dataset.rows, **summarize([r])}
             for r in results]
    return results, {"files": files, "pooled": summarize(results)}
