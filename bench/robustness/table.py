"""The sensitivity table from the study's table alone: per model, data file and node, each case's Δ RMSE and
Δ max |error| against the clean run (mean and spread over the Monte Carlo lanes, and per unit of the magnitude),
the ranking of the perturbations by how far they move each node, the worst case, and the filtering trade-off.
Rows in the spec's order: the same table from a resumed study as from one run straight through.

With an observer artifact each case holds two sets of lanes, the open loop's and the observer's on the same
perturbed inputs: each gets its own entries, ranking, worst case and filtering trade-off (`ESTIMATORS`), the
study's `observer` part beside the open loop's."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from bench.campaign.store import DONE
from bench.robustness.cases import CLEAN, FILTER_PREFIX
from bench.robustness.filters import delay_s


def _spread(values: list[float]) -> dict[str, float]:
    v = np.asarray(values, dtype=np.float64)
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
            "min": float(v.min()), "max": float(v.max())}


OPEN_LOOP, OBSERVER = "open_loop", "observer"
ESTIMATORS = (OPEN_LOOP, OBSERVER)


def estimator_result(result: dict, estimator: str) -> dict | None:
    """The outcome, reason and lanes of one estimator in a case's result (None: the case has no observer)."""
    if estimator == OPEN_LOOP:
        return result
    return {**result[OBSERVER], "nodes": result["nodes"]} if OBSERVER in result else None


def case_entry(row: dict[str, Any], clean: dict | None, estimator: str = OPEN_LOOP) -> dict[str, Any]:
    """One case's row of the sensitivity table, for the open loop or the observer."""
    entry = {"case_id": row["case_id"], "kind": row["kind"], "subject": row["subject"],
             "magnitude": row["magnitude"], "unit": row["unit"], "lanes": row["lanes"], "status": row["status"]}
    if row["tau_s"] is not None:
        entry["tau_s"] = row["tau_s"]
    if row["status"] != DONE:
        return {**entry, "error": row["error"]}
    result = estimator_result(json.loads(row["result"]), estimator)
    if result["outcome"] == "diverged":
        diverged = sum(m is None for m in result["lanes"])
        return {**entry, "diverged": True, "diverged_lanes": diverged, "reason": result["reason"]}
    if clean is None:
        return {**entry, "error": "the clean run has no result"}
    nodes = {}
    for node in result["nodes"]:
        d_rmse = [lane[node]["rmse"] - clean[node]["rmse"] for lane in result["lanes"]]
        d_max = [lane[node]["max_abs"] - clean[node]["max_abs"] for lane in result["lanes"]]
        per_unit = abs(row["magnitude"]) if row["magnitude"] else None
        nodes[node] = {"d_rmse_C": _spread(d_rmse), "d_max_C": _spread(d_max),
                       "d_rmse_per_unit": float(np.mean(d_rmse)) / per_unit if per_unit else None,
                       "d_max_per_unit": float(np.mean(d_max)) / per_unit if per_unit else None,
                       "rmse_C": float(np.mean([lane[node]["rmse"] for lane in result["lanes"]]))}
    return {**entry, "diverged": False, "nodes": nodes}


def _label(entry: dict) -> str:
    return f"{entry['kind']} {entry['subject']}"


def ranking(entries: list[dict], node: str) -> list[dict]:
    """Perturbations (kind, subject) by the largest |mean Δ RMSE| of `node` over their magnitudes; a diverged one
    first."""
    best: dict[str, dict] = {}
    for e in entries:
        if e.get("diverged"):
            best[_label(e)] = {"perturbation": _label(e), "kind": e["kind"], "subject": e["subject"],
                               "magnitude": e["magnitude"], "unit": e["unit"], "diverged": True, "d_rmse_C": None}
            continue
        if "nodes" not in e or node not in e["nodes"]:
            continue
        value = e["nodes"][node]["d_rmse_C"]["mean"]
        current = best.get(_label(e))
        if current is None or (not current["diverged"] and abs(value) > abs(current["d_rmse_C"])):
            best[_label(e)] = {"perturbation": _label(e), "kind": e["kind"], "subject": e["subject"],
                               "magnitude": e["magnitude"], "unit": e["unit"], "diverged": False,
                               "d_rmse_C": value, "spread_C": e["nodes"][node]["d_rmse_C"]["std"]}
    return sorted(best.values(), key=lambda r: (not r["diverged"], -abs(r["d_rmse_C"] or 0.0)))


def filtering(entries: list[dict], noise: list[dict], sample_period_s: float) -> list[dict]:
    """Each filtering case: the error it removes (Δ RMSE of the noisy input minus that of the filtered one) against
    the delay it adds, and what the filter costs on the clean input (its last lane)."""
    out = []
    noisy = {(e["subject"], e["magnitude"]): e for e in noise if "nodes" in e}
    for e in entries:
        base = noisy.get((e["subject"], e["magnitude"]))
        if base is None or "nodes" not in e:
            continue
        kind = e["kind"].removeprefix(FILTER_PREFIX)
        item = {"case_id": e["case_id"], "filter": kind, "input": e["subject"], "sigma": e["magnitude"],
                "unit": e["unit"], "tau_s": e["tau_s"], "delay_s": delay_s(kind, e["tau_s"], sample_period_s),
                "nodes": {}}
        for node, figures in e["nodes"].items():
            item["nodes"][node] = {"removed_C": base["nodes"][node]["d_rmse_C"]["mean"]
                                   - figures["d_rmse_C"]["mean"], "filtered_d_rmse_C": figures["d_rmse_C"]["mean"]}
        out.append(item)
    return out


def _clean_lane_costs(rows: list[dict], clean: dict, estimator: str) -> dict[str, dict[str, float]]:
    """A filter case's last lane is the clean input filtered: its Δ RMSE is what the filter's delay costs."""
    costs = {}
    for row in rows:
        if row["status"] == DONE and row["kind"].startswith(FILTER_PREFIX):
            result = estimator_result(json.loads(row["result"]), estimator)
            last = result["lanes"][-1]
            if last is not None:
                costs[row["case_id"]] = {n: last[n]["rmse"] - clean[n]["rmse"] for n in result["nodes"]}
    return costs


def analysis(group: list[dict], estimator: str, period: float) -> dict | None:
    """One estimator's part of a (model, data file) study: clean figures, entries, ranking, worst case per node,
    filtering trade-off; None when the cases have no such estimator (an observer on a model without one)."""
    clean_row = next((r for r in group if r["kind"] == CLEAN and r["status"] == DONE), None)
    clean_result = estimator_result(json.loads(clean_row["result"]), estimator) if clean_row else None
    if clean_row and clean_result is None:
        return None
    clean = clean_result["lanes"][0] if clean_result and clean_result["outcome"] == "ok" else None
    entries = [case_entry(r, clean, estimator) for r in group if r["kind"] != CLEAN]
    filters = [e for e in entries if e["kind"].startswith(FILTER_PREFIX)]
    perturbations = [e for e in entries if not e["kind"].startswith(FILTER_PREFIX)]
    nodes = clean_result["nodes"] if clean_result else []
    trade = filtering(filters, [e for e in perturbations if e["kind"] == "noise"], period)
    costs = _clean_lane_costs(group, clean, estimator) if clean else {}
    for item in trade:
        item["clean_cost_C"] = costs.get(item["case_id"], {})
    rank = {node: ranking(perturbations, node) for node in nodes}
    return {"clean": clean, "nodes": nodes, "cases": perturbations, "ranking": rank,
            "worst": {node: (rank[node][0] if rank[node] else None) for node in nodes}, "filtering": trade,
            "incomplete": [e["case_id"] for e in entries if e["status"] != DONE]}


def sensitivity(rows: list[dict[str, Any]], sample_period_s: dict[str, float] | None = None,
                observers: dict[str, dict] | None = None) -> list[dict]:
    """Per (model, data file): the open loop's analysis and, for a model with an observer, the observer's under
    `observer` (with what it measures, `observers[model]`). `rows`: the store's rows, in the spec's order."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for row in rows:
        groups.setdefault((row["model"], row["data"]), []).append(row)
    studies = []
    for (model, data), group in groups.items():
        period = (sample_period_s or {}).get(data, 0.2)
        study = {"model": model, "model_sha256": group[0]["model_sha256"], "data": data,
                 "name": f"{Path(model).stem} on {Path(data).stem}", **analysis(group, OPEN_LOOP, period)}
        observed = analysis(group, OBSERVER, period)
        if observed is not None:
            study[OBSERVER] = {**(observers or {}).get(model, {}), **observed}
        studies.append(study)
    return studies


def finite(value: Any) -> bool:
    return isinstance(value, float) and math.isfinite(value)
