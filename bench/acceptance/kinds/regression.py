"""regression: no figure more than `max_worse_percent` worse than in a stored baseline summary (the `--json` of
`bench run`, `bench host` or `bench analyze`, or a report's metrics.json), given by `--baseline FILE` or by a
top-level `baseline = "FILE"` in the criteria file (relative to it; --baseline replaces it).

    [criteria.no_regression]
    kind = "regression"
    figure = "rmse"           # "rmse" (default), "max_error" (per node) or "cycles" (per step, max)
    nodes = "all"             # of rmse and max_error: the nodes compared (default all)
    max_worse_percent = 5     # the limit: the worst node's change in % of the baseline's figure
    floor = 0.01              # °C (cycles: 1): a baseline figure below it counts as the floor, so a change
                              #  within the CAN quantization of a near-zero figure is no regression

The figures must be comparable: both over the same number of rows, each node's RMSE against the same reference
(measured or the float64 model), the cycles both counted or both estimated; otherwise the check fails and says why.
"""

from __future__ import annotations

from bench.acceptance.kinds import register
from bench.acceptance.kinds._base import Criterion, Kind, Subject, judged, nodes, number
from bench.acceptance.kinds.cycles import step_cycles
from bench.analysis.results import CheckResult, RunResults
from bench.tomlspec import choice

FIGURES = ("rmse", "max_error", "cycles")
WORDS = {"rmse": "RMSE", "max_error": "max error", "cycles": "cycles per model step"}


def _change(new: float, old: float, floor: float) -> float:
    """The change of `new` from `old` in % of `old` (at least `floor`): positive is worse."""
    return (new - old) / max(old, floor) * 100.0


def _node_values(results: RunResults, figure: str):
    accuracy = results.accuracy
    return accuracy.rmse_C if figure == "rmse" else accuracy.max_abs_error_C


def judge(criterion: Criterion, subject: Subject) -> CheckResult:
    results, base = subject.results, subject.baseline
    figure, floor = criterion.params["figure"], criterion.params["floor"]
    what = f"{WORDS[figure]}, change from the baseline"
    source = f"baseline {subject.baseline_path}"
    if base is None:
        return judged(criterion, "%", what, None, why_none="no baseline was given", source=source)
    if base.counts.steps_sent != results.counts.steps_sent:
        return judged(criterion, "%", what, None, source=source,
                      why_none=f"the baseline is over {base.counts.steps_sent} rows and this run over "
                               f"{results.counts.steps_sent}, so their figures do not compare; make both on the "
                               "same data and --rows")
    if figure == "cycles":
        new, how = step_cycles(results)
        old, old_how = step_cycles(base)
        if how != old_how or new is None or old is None:
            return judged(criterion, "%", what, None, source=source,
                          why_none=f"this run's cycles are {how}, the baseline's {old_how}")
        return judged(criterion, "%", f"{what} ({fmt_pair(new, old, 'cycles')})",
                      _change(new, old, max(floor, 1.0)), source=source)
    changes: dict[str, float] = {}
    for node in criterion.params["nodes"]:
        new, old = _node_values(results, figure), _node_values(base, figure)
        ref, old_ref = results.accuracy.rmse_reference.get(node), base.accuracy.rmse_reference.get(node)
        if new is None or old is None or new.get(node) is None or old.get(node) is None:
            return judged(criterion, "%", f"{WORDS[figure]} of {node}, change from the baseline", None,
                          source=source, why_none=f"the {figure} of {node} is missing in the run or in the baseline")
        if ref != old_ref:
            return judged(criterion, "%", f"{WORDS[figure]} of {node}, change from the baseline", None, source=source,
                          why_none=f"this run's {node} figure is against {ref}, the baseline's against {old_ref}")
        changes[node] = _change(new.get(node), old.get(node), floor)
    node = max(changes, key=lambda k: changes[k])
    new_value, old_value = _node_values(results, figure).get(node), _node_values(base, figure).get(node)
    return judged(criterion, "%", f"{WORDS[figure]} of {node}, change from the baseline "
                  f"({fmt_pair(new_value, old_value, '°C')}, the worst node)", changes[node], source=source)


def fmt_pair(new: float, old: float, unit: str) -> str:
    return f"{new:.4g} {unit} against {old:.4g} {unit}"


KIND = Kind("regression", "no figure more than a given % worse than in a stored baseline summary", "%", judge,
            options={"figure": choice(*FIGURES), "nodes": nodes, "floor": number},
            defaults={"figure": "rmse", "nodes": "all", "floor": 0.01},
            limit_key="max_worse_percent")

register(KIND)
