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

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.errors import UsageError
from bench.robustness.filters import FILTERS
from bench.robustness.kinds import PERTURBATIONS
from bench.tomlspec import read_spec, spec_tables

SECTIONS = ("study", "perturbations", "filters")
STUDY_KEYS = ("name", "description", "seeds", "seed", "kinds")
FILTER_KEYS = ("kinds", "time_constants", "inputs", "enabled")
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


def _numbers(where: str, value: Any) -> tuple[float, ...]:
    if not isinstance(value, list) or not value:
        raise SpecError(f"{where} must be a non-empty list of numbers, e.g. [1.0, 2.0]")
    if any(isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) for v in value):
        raise SpecError(f"{where} must list finite numbers, not {value!r}")
    return tuple(float(v) for v in value)


def _names(where: str, value: Any, known: tuple[str, ...]) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise SpecError(f"{where} must be a non-empty list of names, e.g. [{', '.join(map(repr, known[:2]))}]")
    bad = [v for v in value if v not in known]
    if bad:
        raise SpecError(f"{where} names {bad[0]!r}, which is not one of {', '.join(known)}")
    return tuple(value)


def _kind_choice(where: str, kind, table: Any, subjects: tuple[str, ...]) -> KindChoice | None:
    if not isinstance(table, dict):
        raise SpecError(f"{where} must be a table, [{where.rsplit(': ', 1)[-1]}]")
    if table.get("enabled", True) is False:
        return None
    if not isinstance(table.get("enabled", True), bool):
        raise SpecError(f"{where} enabled must be true or false")
    chosen = _names(f"{where} subjects", table["subjects"], subjects) if "subjects" in table else None
    magnitudes = {}
    for key, value in table.items():
        if key in ("subjects", "enabled"):
            continue
        if key not in subjects:
            raise SpecError(f"{where} has an unknown key {key!r}; use subjects, enabled or a subject of "
                            f"{kind.name}: {', '.join(subjects)}")
        values = _numbers(f"{where} {key}", value)
        for v in values:
            problem = kind.problem(v)
            if problem:
                raise SpecError(f"{where} {key}: {v:g} {problem}")
        magnitudes[key] = values
    return KindChoice(chosen, magnitudes)


def parse_spec(text: str, path: Path | None, subjects: dict[str, tuple[str, ...]]) -> RobustnessSpec:
    """The spec of `text`; `subjects` names each kind's subjects across the study's models (a key of a subject no
    model has is a mistake)."""
    where = str(path) if path is not None else "the spec"
    doc = spec_tables(text, where, SECTIONS, SpecError)
    study = doc.get("study", {})
    bad = [k for k in study if k not in STUDY_KEYS]
    if bad:
        raise SpecError(f"{where}: [study] has an unknown key {bad[0]!r}; use {', '.join(STUDY_KEYS)}")
    name, description = study.get("name", path.stem if path else "robustness"), study.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise SpecError(f"{where}: [study] name and description must be strings")
    seeds, seed = study.get("seeds", DEFAULT_SEEDS), study.get("seed", 0)
    if isinstance(seeds, bool) or not isinstance(seeds, int) or not 1 <= seeds <= MAX_SEEDS:
        raise SpecError(f"{where}: [study] seeds must be a whole number from 1 to {MAX_SEEDS}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SpecError(f"{where}: [study] seed must be a whole number, 0 or more")
    names = PERTURBATIONS.names()
    wanted = _names(f"{where}: [study] kinds", study["kinds"], names) if "kinds" in study else names
    tables = doc.get("perturbations", {})
    unknown = [k for k in tables if k not in names]
    if unknown:
        raise SpecError(f"{where}: [perturbations.{unknown[0]}] is not a perturbation kind; use "
                        f"{', '.join(names)}")
    kinds = {}
    for name_ in names:
        if name_ not in wanted:
            continue
        choice = _kind_choice(f"{where}: [perturbations.{name_}]", PERTURBATIONS[name_], tables.get(name_, {}),
                              subjects.get(name_, ()))
        if choice is not None:
            kinds[name_] = choice
    filters = doc.get("filters", {})
    bad = [k for k in filters if k not in FILTER_KEYS]
    if bad:
        raise SpecError(f"{where}: [filters] has an unknown key {bad[0]!r}; use {', '.join(FILTER_KEYS)}")
    filter_kinds = _names(f"{where}: [filters] kinds", filters["kinds"], FILTERS) if "kinds" in filters else FILTERS
    if filters.get("enabled", True) is False:
        filter_kinds = ()
    taus = _numbers(f"{where}: [filters] time_constants", filters["time_constants"]) \
        if "time_constants" in filters else DEFAULT_TIME_CONSTANTS
    if any(t <= 0 for t in taus):
        raise SpecError(f"{where}: [filters] time_constants must be positive seconds")
    inputs = _names(f"{where}: [filters] inputs", filters["inputs"], subjects.get("noise", ())) \
        if "inputs" in filters else None
    return RobustnessSpec(path, text, name, description, seeds, seed, kinds, tuple(filter_kinds), taus, inputs)


def load_spec(path: Path | None, subjects: dict[str, tuple[str, ...]]) -> RobustnessSpec:
    """The spec in `path` (None: every kind at its defaults); SpecError for a missing or bad one."""
    if path is None:
        return parse_spec("", None, subjects)
    text = read_spec(path, "the robustness spec",
                     "give the path of a TOML spec, e.g. examples/robustness/default.toml", SpecError)
    return parse_spec(text, Path(path), subjects)
