"""One case on a worker: its lanes built from the data (one per Monte Carlo seed), the model (perturbed for a
parameter case) run on all of them at once in the target's float32 code (`bench.robustness.lanes`), and each lane's
RMSE and max |error| per measured node against the data's reference. A lane whose estimate leaves the numbers
(not finite, or beyond ±1000 °C) diverged: it gives no figure, the case says how many lanes diverged and why.
With an observer artifact the same lanes (its measurement columns perturbed like any input) also run through the
target's float32 observer: open loop and observer side by side in one case.
"""

from __future__ import annotations

import datetime
import functools
import os
import socket
import time
import zlib
from typing import Any

import numpy as np

from bench.drive.dataset import MEASURED_NODES
from bench.errors import BenchError
from bench.model.fileeval import OUTPUT_INDEX, measured_nodes
from bench.model.metrics import max_abs_error, rmse
from bench.model.runs import drive_matrix, initial_temperatures
from bench.robustness.cases import CLEAN, FILTER_PREFIX
from bench.robustness.channels import channel_index, observer_columns
from bench.robustness.filters import apply_filter
from bench.robustness.kinds import PERTURBATIONS, Lane
from bench.robustness.lanes import jittered_steps, nominal_steps, run_lanes, run_observer_lanes
from target_sim.artifact import ArtifactError, ModelArtifact, load_artifact
from target_sim.observer import has_observer

DIVERGED_ABOVE_C = 1000.0     # a temperature estimate beyond ±1000 °C has left every motor's range: diverged


@functools.lru_cache(maxsize=8)
def study_artifact(path: str, sha256: str) -> ModelArtifact:
    artifact = load_artifact(path)
    if artifact.sha256 != sha256:
        raise BenchError(f"{path} changed since the study began (sha256 {artifact.sha256[:12]}, expected "
                         f"{sha256[:12]}); run the study again into another --out")
    return artifact


@functools.lru_cache(maxsize=8)
def study_dataset(path: str, sha256: str, mapping: str | None, sample_period_s: float | None, rows: int | None):
    """The data file as the study reads it (cut to `rows`), checked against its checksum."""
    from bench.drive.files import load_datasets
    from bench.drive.mapping import load_mapping

    dataset = load_datasets([path], load_mapping(mapping) if mapping else None, sample_period_s)[0]
    if dataset.sha256 != sha256:
        raise BenchError(f"{path} changed since the study began; run the study again into another --out")
    return dataset if rows is None else _head(dataset, rows)


def _head(dataset, rows: int):
    from dataclasses import fields, replace

    cut = {f.name: getattr(dataset, f.name)[:rows] for f in fields(dataset)
           if isinstance(getattr(dataset, f.name), np.ndarray)}
    return replace(dataset, **cut)


def lane_rng(seed: int, kind: str, subject: str, magnitude: float, lane: int) -> np.random.Generator:
    """The random numbers of one lane: the same for a case in any run, on any worker, for every model (common random
    numbers: two models see the same noise)."""
    key = zlib.crc32(f"{kind}/{subject}/{magnitude!r}".encode())
    return np.random.default_rng(np.random.SeedSequence([seed, key, lane]))


def lane_metrics(estimate: np.ndarray, end_s: np.ndarray, dataset, nodes: list[str]) -> dict | None:
    """{node: {rmse, max_abs}} of one lane's (steps, 4) estimate; None when it diverged."""
    if estimate.size == 0:
        return None
    with np.errstate(invalid="ignore"):
        if not np.all(np.isfinite(estimate)) or np.max(np.abs(estimate)) > DIVERGED_ABOVE_C:
            return None
    times = float(dataset.time_s[0]) + end_s
    out = {}
    for node in nodes:
        reference = np.interp(times, dataset.time_s, dataset.column(MEASURED_NODES[node]))
        y = estimate[:, OUTPUT_INDEX[node]].astype(np.float64)
        out[node] = {"rmse": rmse(y, reference), "max_abs": max_abs_error(y, reference)}
    return out


def build_lanes(task: dict[str, Any], artifact: ModelArtifact, dataset) -> list[Lane]:
    """The case's lanes: the drive columns, then the observer's measurement columns (`channels.lane_columns`)."""
    extra = [dataset.column(c) for c in observer_columns(artifact)]
    drive = np.column_stack([drive_matrix(dataset, artifact.drive_signals), *extra]).astype(np.float64)
    base = Lane(drive, initial_temperatures(dataset), dataset.sample_period_s, artifact.dt)
    kind, subject, magnitude = task["kind"], task["subject"], task["magnitude"]
    if kind == CLEAN:
        return [base]
    if kind.startswith(FILTER_PREFIX):
        noise = PERTURBATIONS["noise"]
        lanes = [noise.apply(base, artifact, subject, magnitude, lane_rng(task["seed"], "noise", subject,
                                                                          magnitude, i))
                 for i in range(task["lanes"])] + [base]
        index = channel_index(artifact, subject)
        return [lane.with_column(index, apply_filter(kind.removeprefix(FILTER_PREFIX), lane.drive[:, index],
                                                     task["tau_s"], lane.sample_period_s).astype(np.float64))
                for lane in lanes]
    perturbation = PERTURBATIONS[kind]
    return [perturbation.apply(base, artifact, subject, magnitude, lane_rng(task["seed"], kind, subject,
                                                                            magnitude, i))
            for i in range(task["lanes"])]


def lane_set(estimates: list[np.ndarray], steps, dataset, nodes: list[str]) -> dict[str, Any]:
    """{outcome: ok | diverged, reason, lanes} of one estimator's lanes (the open loop's or the observer's)."""
    metrics = [lane_metrics(y, s.end_s, dataset, nodes) for y, s in zip(estimates, steps, strict=True)]
    diverged = sum(m is None for m in metrics)
    reason = f"the estimate left ±{DIVERGED_ABOVE_C:g} °C or became NaN in {diverged} of {len(metrics)} lane(s)"
    return {"outcome": "diverged" if diverged else "ok", "reason": reason if diverged else None, "lanes": metrics}


def run_case(task: dict[str, Any]) -> dict[str, Any]:
    """{outcome: ok | diverged, reason, lanes: [per-lane {node: {rmse, max_abs}} or None], nodes} of the open loop;
    with an observer artifact also `observer`: the same of the observer on the same lanes."""
    source = task["source"]
    artifact = study_artifact(source["model_path"], source["model_sha256"])
    dataset = study_dataset(source["data_path"], source["data_sha256"], source["mapping"],
                            source["sample_period_s"], source["rows"])
    nodes = [n for n in OUTPUT_INDEX if n in measured_nodes(dataset)]
    observed = has_observer(artifact)
    kind = task["kind"]
    if kind in PERTURBATIONS:
        try:
            artifact = PERTURBATIONS[kind].model(artifact, task["subject"], task["magnitude"])
        except ArtifactError as exc:       # the perturbed model is refused: it would not run on the target
            refused = {"outcome": "diverged", "reason": f"the perturbed model is refused: {exc}",
                       "lanes": [None] * task["lanes"]}
            return {**refused, "nodes": nodes, **({"observer": refused} if observed else {})}
    lanes = build_lanes(task, artifact, dataset)
    steps = [nominal_steps(lane.drive, lane.sample_period_s, lane.dt) if lane.boundaries_s is None else
             jittered_steps(lane.drive, lane.sample_period_s, lane.boundaries_s) for lane in lanes]
    initial = np.stack([lane.initial for lane in lanes], axis=1)
    result = {**lane_set(run_lanes(artifact, steps, initial), steps, dataset, nodes), "nodes": nodes}
    if observed:
        result["observer"] = lane_set(run_observer_lanes(artifact, steps, initial), steps, dataset, nodes)
    return result


def now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def evaluate_case(task: dict[str, Any]) -> dict[str, Any]:
    """One case's outcome for the table (runs on a Dask worker, or in the driver for a serial loop); a problem of
    the inputs is a failed case with its sentence, never an exception."""
    started, clock = now(), time.perf_counter()
    try:
        result, status, error = run_case(task), "done", None
    except (BenchError, ValueError, OSError) as exc:
        result, status, error = None, "failed", str(exc)
    return {"case_id": task["case_id"], "status": status, "error": error, "result": result,
            "wall_s": round(time.perf_counter() - clock, 3), "started_at": started, "finished_at": now(),
            "worker": _worker_name()}
