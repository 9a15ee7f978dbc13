"""A robustness spec (TOML): which perturbations at which magnitudes, how many Monte Carlo seeds, which filters.
Everything is optional; what a spec leaves out takes the kind's defaults (`bench robustness --spec` with no spec
runs every kind at its defaults).

    [study]
    name = "default"                # optional: a title for the report
    description = "..."
    seeds = 8                       # Monte Carlo seeds of the random kinds (noise, dropout, jitter)
    seed = 0                        # the base the seeds are drawn from
    kinds = ["noise", "bias"]       # optional: only these kinds (default: all)

    [perturbations.noise]           # one table per kind, all keys optional
    subjects = ["torque", "speed"]  # only these subjects (channels, parameter groups, nodes)
    torque = [2.0, 8.0]             # the magnitudes of one subject, in the kind's unit
    enabled = false                 # leave the kind out

    [filters]                       # the filtering trade-off on the noisy inputs
    kinds = ["lowpass", "moving-mean"]
    time_constants = [0.5, 1, 2, 5] # s
    inputs = ["torque"]             # default: every channel the noise kind perturbs

Every problem is one sentence naming the file and the key (`SpecError`, exit status 2), found before anything
is run or written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.errors import UsageError
from bench.robustness.filters import FILTERS
from bench.robustness.kinds import PERTURBATIONS
from bench.tomlspec import (
    Check,
    TableSpec,
    flag,
    names,
    numbers,
    read_spec,
    spec_tables,
    string,
    whole_at_least,
    whole_between,
)

SECTIONS = ("study", "perturbations", "filters")
DEFAULT_SEEDS = 8
DEFAULT_TIME_CONSTANTS = (0.5, 1.0, 2.0, 5.0)
MAX_SEEDS = 1000


class SpecError(UsageError):
    """A robustness spec that cannot be used: one sentence naming the file and the key (exit status 2)."""


@dataclass(frozen=True)
class KindChoice:
    """What the spec says of one kind: its subjects (None: all) and magnitudes per subject (absent: defaults)."""

    subjects: tuple[str, ...] | None = None
    magnitudes: dict[str, tuple[float, ...]] = field(default_factory=dict)


@dataclass(frozen=True)
class RobustnessSpec:
    path: Path | None
    text: str
    name: str = "robustness"
    description: str = ""
    seeds: int = DEFAULT_SEEDS
    seed: int = 0
    kinds: dict[str, KindChoice] = field(default_factory=dict)   # the kinds to run, in the registry's order
    filter_kinds: tuple[str, ...] = FILTERS
    time_constants: tuple[float, ...] = DEFAULT_TIME_CONSTANTS
    filter_inputs: tuple[str, ...] | None = None


def _magnitudes(kind) -> Check:
    """A subject's magnitudes: finite numbers, each one the kind allows."""
    def check(value: Any) -> tuple[float, ...]:
        values = numbers(value)
        for v in values:
            problem = kind.problem(v)
            if problem:
                raise ValueError(f"holds {v:g}, which {problem}")     # "C_w holds -120, which must be above -100 %"
        return values
    return check


def _kind_table(kind, subjects: tuple[str, ...]) -> TableSpec:
    keys: dict[str, Check] = {"subjects": names(subjects), "enabled": flag}
    keys.update({subject: _magnitudes(kind) for subject in subjects})
    return TableSpec(f"[perturbations.{kind.name}]", keys,
                     advice=f"use subjects, enabled or a subject of {kind.name}: {', '.join(subjects)}")


def _study_table(kinds: tuple[str, ...]) -> TableSpec:
    return TableSpec("[study]", {"name": string, "description": string, "seeds": whole_between(1, MAX_SEEDS),
                                 "seed": whole_at_least(0), "kinds": names(kinds)})


def _positive_seconds(value: Any) -> tuple[float, ...]:
    values = numbers(value)
    if any(t <= 0 for t in values):
        raise ValueError("must be positive seconds")
    return values


def _filters_table(noise_subjects: tuple[str, ...]) -> TableSpec:
    return TableSpec("[filters]", {"kinds": names(FILTERS), "time_constants": _positive_seconds,
                                   "inputs": names(noise_subjects), "enabled": flag})


def parse_spec(text: str, path: Path | None, subjects: dict[str, tuple[str, ...]]) -> RobustnessSpec:
    """The spec of `text`; `subjects` names each kind's subjects across the study's models (a key of a subject no
    model has is a mistake)."""
    where = str(path) if path is not None else "the spec"
    doc = spec_tables(text, where, SECTIONS, SpecError)
    kind_names = PERTURBATIONS.names()
    study = _study_table(kind_names).read(doc.get("study", {}), where, SpecError)
    tables = doc.get("perturbations", {})
    unknown = [k for k in tables if k not in kind_names]
    if unknown:
        raise SpecError(f"{where}: [perturbations.{unknown[0]}] is not a perturbation kind; use "
                        f"{', '.join(kind_names)}")
    kinds = {}
    for name in study.get("kinds", kind_names):
        table = _kind_table(PERTURBATIONS[name], subjects.get(name, ())).read(tables.get(name, {}), where, SpecError)
        if table.pop("enabled", True):
            kinds[name] = KindChoice(table.pop("subjects", None), table)
    kinds = {name: kinds[name] for name in kind_names if name in kinds}     # the registry's order
    filters = _filters_table(subjects.get("noise", ())).read(doc.get("filters", {}), where, SpecError)
    filter_kinds = filters.get("kinds", FILTERS) if filters.get("enabled", True) else ()
    return RobustnessSpec(path, text, study.get("name", path.stem if path else "robustness"),
                          study.get("description", ""), study.get("seeds", DEFAULT_SEEDS), study.get("seed", 0),
                          kinds, tuple(filter_kinds), filters.get("time_constants", DEFAULT_TIME_CONSTANTS),
                          filters.get("inputs"))


def load_spec(path: Path | None, subjects: dict[str, tuple[str, ...]]) -> RobustnessSpec:
    """The spec in `path` (None: every kind at its defaults); SpecError for a missing or bad one."""
    if path is None:
        return parse_spec("", None, subjects)
    text = read_spec(path, "the robustness spec",
                     "give the path of a TOML spec, e.g. examples/robustness/default.toml", SpecError)
    return parse_spec(text, Path(path), subjects)
