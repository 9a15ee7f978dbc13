"""What every criterion kind shares: the criterion as read from the file, what it is judged on, and the one way a
figure is compared with its limit (the figure must not exceed it)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bench.analysis.results import CheckResult, NodeValues, RunResults
from dbc.contract import TEMPERATURE_NODES as NODES


@dataclass(frozen=True)
class Criterion:
    """One named check of a criteria file: its kind, its limit and the kind's own options."""

    name: str
    kind: str
    limit: float
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Subject:
    """What the criteria judge: the figures of a run or a log (None: there are none, e.g. a log that could not be
    analyzed), and the stored baseline's figures for a regression gate."""

    results: RunResults | None
    baseline: RunResults | None = None
    baseline_path: str | None = None


@dataclass(frozen=True)
class Kind:
    """A kind of criterion: its name, what it checks, the key that holds its limit and the unit, the options it
    takes (name -> parser raising ValueError with the reason) and how a figure is had."""

    name: str
    summary: str
    unit: str
    judge: Callable[[Criterion, Subject], CheckResult]
    options: dict[str, Callable[[Any], Any]] = field(default_factory=dict)
    defaults: dict[str, Any] = field(default_factory=dict)
    limit_key: str = "max"


def number(value: Any) -> float:
    """A finite number >= 0 (ValueError otherwise)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise ValueError("must be a number >= 0")
    return float(value)


def nodes(value: Any) -> tuple[str, ...]:
    """'magnet', ["winding", "magnet"] or "all" -> the node names."""
    if value == "all":
        return NODES
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not items or any(v not in NODES for v in items):
        raise ValueError(f"must be a node ({', '.join(NODES)}), a list of them, or \"all\"")
    return tuple(dict.fromkeys(items))


def fmt(value: float) -> str:
    return f"{value:.4g}"


def judged(criterion: Criterion, unit: str, what: str, figure: float | None, *, why_none: str = "",
           source: str | None = None) -> CheckResult:
    """The check of `figure` against the criterion's limit; a figure that could not be had fails, saying why."""
    name, limit = criterion.name, criterion.limit
    unit_text = f" {unit}" if unit else ""
    if figure is None:
        passed, message = False, f"{name}: {what} cannot be judged ({why_none or 'no figure'})"
    else:
        passed = figure <= limit
        relation = "<=" if passed else ">"
        message = f"{name}: {what} {fmt(figure)}{unit_text} {relation} limit {fmt(limit)}{unit_text}"
    if source:
        message += f" ({source})"
    return CheckResult(name=name, kind=criterion.kind, what=what, figure=figure, limit=limit, unit=unit,
                       passed=passed, message=message, source=source)


def worst_node(values: dict[str, float | None]) -> tuple[str | None, float | None, list[str]]:
    """The node with the largest figure, that figure, and the nodes without one."""
    present = {k: v for k, v in values.items() if v is not None}
    missing = [k for k, v in values.items() if v is None]
    if not present:
        return None, None, missing
    node = max(present, key=lambda k: present[k])
    return node, present[node], missing


def node_figures(results: RunResults, chosen: tuple[str, ...], against: str, reported: NodeValues,
                 vs_float64: NodeValues | None) -> tuple[dict[str, float | None], dict[str, str]]:
    """Per chosen node, a figure against `against` ("reported": what the run's RMSE is against, "measured",
    "float64"), and per node without one the reason."""
    labels = results.accuracy.rmse_reference
    out: dict[str, float | None] = {}
    why: dict[str, str] = {}
    for node in chosen:
        if against == "float64":
            out[node] = vs_float64.get(node) if vs_float64 is not None else None
            if vs_float64 is None:
                why[node] = "the results predate the figures against the float64 model"
        elif against == "measured" and labels.get(node) != "measured":
            out[node] = None
            why[node] = f"the data has no measurement of the {node} temperature"
        else:
            out[node] = reported.get(node)
        if out[node] is None and node not in why:
            why[node] = f"no {node} figure (no reply kept, or not finite)"
    return out, why


def node_check(criterion: Criterion, subject: Subject, unit: str, measure: str, reported: NodeValues,
               vs_float64: NodeValues | None) -> CheckResult:
    """A per-node error criterion (RMSE, max error): the worst chosen node against the limit; a chosen node without
    a figure fails it."""
    results = subject.results
    assert results is not None
    against = criterion.params["against"]
    figures, why = node_figures(results, criterion.params["nodes"], against, reported, vs_float64)
    node, worst, missing = worst_node(figures)
    if missing:
        what = f"{measure} of {missing[0]}"
        return judged(criterion, unit, what, None, why_none=why[missing[0]])
    reference = results.accuracy.rmse_reference.get(node) if against == "reported" else (
        "measured" if against == "measured" else "float64 model")
    many = len(criterion.params["nodes"]) > 1
    what = f"{measure} of {node} against {reference}" + (" (the worst node)" if many else "")
    return judged(criterion, unit, what, worst)
