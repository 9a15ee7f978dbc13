"""A study expanded into cases: per model and data file, the clean run, every (kind, subject, magnitude) of the
spec, and the filtering cases (a noisy input, a filter, a time constant). A case's id is a slug and a hash of
everything that makes its result (model and data checksums, rows, kind, subject, magnitude, seeds), so the same
case has the same id in any invocation and `--resume` recognizes it.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from bench.robustness.kinds import PERTURBATIONS
from bench.robustness.spec import RobustnessSpec
from target_sim.artifact import ModelArtifact

CLEAN = "clean"
FILTER_PREFIX = "filter:"


@dataclass(frozen=True)
class StudyInput:
    """One model on one data file: where the workers find them (the same paths on every worker)."""

    model_path: str
    model_sha256: str
    data_path: str
    data_sha256: str
    mapping: str | None
    sample_period_s: float | None
    rows: int | None


@dataclass(frozen=True)
class Case:
    case_id: str
    index: int
    source: StudyInput
    kind: str                   # a perturbation kind, "clean", or "filter:<filter kind>"
    subject: str
    magnitude: float
    unit: str
    lanes: int                  # Monte Carlo seeds (1 for a deterministic kind)
    seed: int
    tau_s: float | None = None  # a filtering case's time constant

    def task(self) -> dict[str, Any]:
        return {**asdict(self), "source": asdict(self.source)}

    @property
    def filter(self) -> str | None:
        return self.kind.removeprefix(FILTER_PREFIX) if self.kind.startswith(FILTER_PREFIX) else None


def case_id(source: StudyInput, kind: str, subject: str, magnitude: float, lanes: int, seed: int,
            tau_s: float | None) -> str:
    key = {"model": source.model_sha256, "data": source.data_sha256, "rows": source.rows, "mapping": source.mapping,
           "sample_period": source.sample_period_s, "kind": kind, "subject": subject, "magnitude": magnitude,
           "lanes": lanes, "seed": seed, "tau": tau_s}
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:10]
    slug = "_".join([Path(source.model_path).stem, Path(source.data_path).stem, kind.replace(":", "-"), subject,
                     f"{magnitude:g}"] + ([f"tau{tau_s:g}"] if tau_s is not None else []))
    return f"{re.sub(r'[^A-Za-z0-9.]+', '-', slug)[:80]}-{digest}"


def model_cases(source: StudyInput, artifact: ModelArtifact, spec: RobustnessSpec, first: int) -> list[Case]:
    """The cases of one model on one data file, numbered from `first`."""
    cases: list[Case] = []

    def add(kind: str, subject: str, magnitude: float, unit: str, lanes: int, tau_s: float | None = None) -> None:
        cid = case_id(source, kind, subject, magnitude, lanes, spec.seed, tau_s)
        cases.append(Case(cid, first + len(cases), source, kind, subject, magnitude, unit, lanes, spec.seed, tau_s))

    add(CLEAN, "-", 0.0, "", 1)
    for name, choice in spec.kinds.items():
        kind = PERTURBATIONS[name]
        own = kind.subjects(artifact)
        for subject in (s for s in (choice.subjects or own) if s in own):
            for magnitude in choice.magnitudes.get(subject) or kind.defaults(artifact, subject):
                add(name, subject, magnitude, kind.unit(artifact, subject), spec.seeds if kind.random else 1)
    noise = spec.kinds.get("noise")
    if noise is not None:
        kind = PERTURBATIONS["noise"]
        own = kind.subjects(artifact)
        for subject in (s for s in (spec.filter_inputs or noise.subjects or own) if s in own):
            sigma = max(noise.magnitudes.get(subject) or kind.defaults(artifact, subject))
            for filter_kind in spec.filter_kinds:
                for tau in spec.time_constants:
                    add(FILTER_PREFIX + filter_kind, subject, sigma, kind.unit(artifact, subject), spec.seeds, tau)
    return cases
