"""The study's outputs, from its table alone: OUT/report/ with robustness.json (everything), report.md (the
sensitivity table per node, the three perturbations that move each node most, the worst case, the filtering
trade-off), tornado-<study>-<node>.png and filtering-<study>.png; with an observer artifact the open loop and the
observer side by side (two columns of figures per case, two tornado panels, filtering-<study>-observer.png, and
which node the observer measures). Rendered in memory and written at once
(`bench.fileio.write_directory_atomically`): an earlier report is replaced whole or left as it was."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from bench.figures import agg_figure, png_bytes
from bench.fileio import write_directory_atomically
from bench.robustness.store import TABLE_NAME, CaseStore
from bench.robustness.table import OBSERVER, sensitivity

REPORT_DIR = "report"
OUR_FILES = re.compile(r"(report\.md|robustness\.json|(tornado|filtering)-[A-Za-z0-9_.-]+\.png)")


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.]+", "-", text).strip("-")


def _largest(values: list[float]) -> float | None:
    return max(values, key=abs) if values else None


def _sides(analysis: dict, node: str) -> tuple[dict[str, tuple[list[float], list[float]]], set[str]]:
    """Per perturbation (kind and subject), the mean Δ RMSE of `node` at each negative and positive magnitude; and
    the perturbations that diverged."""
    sides: dict[str, tuple[list[float], list[float]]] = {}
    diverged = set()
    for e in analysis["cases"]:
        label = f"{e['kind']} {e['subject']}"
        if e.get("diverged"):
            diverged.add(label)
        elif "nodes" in e and node in e["nodes"]:
            low, high = sides.setdefault(label, ([], []))
            (low if e["magnitude"] < 0 else high).append(e["nodes"][node]["d_rmse_C"]["mean"])
    return sides, diverged


def _reach(sides: dict) -> dict[str, float]:
    return {k: max(abs(v) for v in lo + hi) for k, (lo, hi) in sides.items()}


def _tornado_axis(ax, analysis: dict, node: str, labels: list[str], width: float, title: str) -> None:
    sides, diverged = _sides(analysis, node)
    shown = set()
    for y, label in enumerate(reversed(labels)):
        if label in diverged:
            ax.barh(y, 2 * width, left=-width, color="#e53935", alpha=0.3)
            ax.text(0, y, "diverged", ha="center", va="center", fontsize=8)
            continue
        low, high = sides.get(label, ([], []))
        for value, offset, colour, name in ((_largest(low), -0.2, "#43a047", "negative magnitude"),
                                            (_largest(high), 0.2, "#1e88e5", "positive magnitude")):
            if value is not None:
                ax.barh(y + offset, value, height=0.4, color=colour, label=None if name in shown else name)
                shown.add(name)
    ax.set_yticks(range(len(labels)), list(reversed(labels)), fontsize=8)
    ax.axvline(0, color="black", lw=0.8)
    ax.set_xlim(-1.05 * width, 1.05 * width)
    ax.set_xlabel(f"Δ RMSE of the {node} estimate vs the clean run, °C", fontsize=8)
    ax.set_title(title, fontsize=9)
    if shown:
        ax.legend(fontsize=7, loc="lower right")


def tornado(study: dict, node: str, top: int = 15) -> bytes:
    """Per perturbation (kind and subject), its mean Δ RMSE at its largest magnitude of each sign (a signed kind's
    -x and +x side by side), longest first; a diverged perturbation is a red band marked 'diverged'. With an
    observer: the open loop and the observer in two panels on one scale, the same perturbations in the same rows
    (ordered by the larger of the two reaches)."""
    parts = [(study, "open loop")] + ([(study[OBSERVER], "observer")] if study.get(OBSERVER) else [])
    reach: dict[str, float] = {}
    diverged: set[str] = set()
    for analysis, _ in parts:
        sides, down = _sides(analysis, node)
        diverged |= down
        for label, value in _reach(sides).items():
            reach[label] = max(reach.get(label, 0.0), value)
    order = sorted((k for k in reach if k not in diverged), key=lambda k: reach[k], reverse=True)
    labels = (sorted(diverged) + order)[:top]
    width = max([reach[k] for k in order[:top]] or [1.0]) or 1.0
    fig = agg_figure(7.5 * len(parts), 0.35 * len(labels) + 1.6)
    axes = fig.subplots(1, len(parts), squeeze=False)[0]
    for ax, (analysis, title) in zip(axes, parts, strict=True):
        _tornado_axis(ax, analysis, node, labels, width, title)
    fig.suptitle(f"{study['name']}: {node} (largest magnitude of each sign)", fontsize=10)
    return png_bytes(fig)


def filtering_figure(study: dict, node: str) -> bytes:
    """Error removed (Δ RMSE of the noisy input minus the filtered one) against the delay the filter adds."""
    fig = agg_figure(7, 4.5)
    ax = fig.add_subplot()
    groups: dict[tuple[str, str], list[dict]] = {}
    for item in study["filtering"]:
        groups.setdefault((item["filter"], item["input"]), []).append(item)
    for (kind, channel), items in groups.items():
        items = sorted(items, key=lambda i: i["delay_s"])
        ax.plot([i["delay_s"] for i in items], [i["nodes"][node]["removed_C"] for i in items],
                "o-" if kind == "lowpass" else "s--", label=f"{kind} on {channel} (σ {items[0]['sigma']:g} "
                                                             f"{items[0]['unit']})")
    ax.axhline(0, color="black", lw=0.8)
    ax.set_xlabel("delay added, s")
    ax.set_ylabel(f"{node} error removed, °C (Δ RMSE)")
    ax.set_title(f"{study['name']}: filtering noisy inputs", fontsize=10)
    if groups:
        ax.legend(fontsize=7)
    return png_bytes(fig)


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}g}" if abs(value) < 1e-3 and value else f"{value:.{digits}f}"
    return str(value)


def _moved(entry: dict) -> str:
    return "diverged" if entry["diverged"] else f"{entry['d_rmse_C']:+.3f} °C"


def _figures(e: dict | None, node: str) -> str:
    """A case's cells (Δ RMSE, ±, Δ max, ±, Δ RMSE per unit) for one estimator."""
    if e is None:
        return " | | | | |"
    if e.get("diverged"):
        return f" diverged ({e['diverged_lanes']}/{e['lanes']}) | | | | |"
    if "nodes" in e and node in e["nodes"]:
        f = e["nodes"][node]
        return (f" {f['d_rmse_C']['mean']:+.4f} | {f['d_rmse_C']['std']:.4f} | {f['d_max_C']['mean']:+.3f} | "
                f"{f['d_max_C']['std']:.3f} | {_fmt(f['d_rmse_per_unit'])} |")
    return f" {e['status']}: {e.get('error', '')} | | | | |"


def _top(analysis: dict, node: str) -> str:
    return "; ".join(f"**{r['perturbation']}** ({_moved(r)} at {r['magnitude']:g} {r['unit']})"
                     for r in analysis["ranking"][node][:3])


def _clean(analysis: dict) -> str:
    return ", ".join(f"{n} RMSE {analysis['clean'][n]['rmse']:.3f} °C, max |e| {analysis['clean'][n]['max_abs']:.3f} °C"
                     for n in analysis["nodes"])


def _observer_lines(observer: dict) -> list[str]:
    measured = ", ".join(f"{m['kind']} ({', '.join(m['columns'])}) of the {m['node']}"
                         for m in observer.get("measurements", []))
    lines = [f"Observer ({observer.get('form', '?')} form): it measures {measured or '?'}. Its measurement "
             "channels are perturbed like any input (a dropped sample: no reading that step, predict only). Open "
             "loop and observer run on the same perturbed lanes; the figures are side by side below.", ""]
    if observer["clean"]:
        lines += ["Clean run with the observer: " + _clean(observer), ""]
    return lines


def _filtering_lines(analysis: dict, name: str, title: str, image: str) -> list[str]:
    lines = [f"### {title}", "", f"![filtering]({image})", "",
             "| filter | input (σ) | τ s | delay s | " + " | ".join(
                 f"{n} removed °C | {n} clean cost °C" for n in analysis["nodes"]) + " |",
             "|---|---|---|---|" + "---|---|" * len(analysis["nodes"])]
    for item in analysis["filtering"]:
        lines.append(f"| {item['filter']} | {item['input']} ({item['sigma']:g} {item['unit']}) | "
                     f"{item['tau_s']:g} | {item['delay_s']:.2f} | " + " | ".join(
                         f"{item['nodes'][n]['removed_C']:+.4f} | "
                         f"{_fmt(item['clean_cost_C'].get(n))}" for n in analysis["nodes"]) + " |")
    return [*lines, ""]


def _worst(analysis: dict) -> str:
    return "; ".join(f"{n}: {w['perturbation']} at {w['magnitude']:g} {w['unit']} ({_moved(w)})"
                     for n, w in analysis["worst"].items() if w)


def markdown(meta: dict, studies: list[dict]) -> str:
    lines = [f"# Robustness: {meta.get('name', 'study')}", ""]
    if meta.get("description"):
        lines += [meta["description"], ""]
    lines += [f"Seeds per random case: {meta.get('seeds')}; table `{TABLE_NAME}`. Δ values are the perturbed run "
              "minus the clean run of the same model on the same data (the target's float32 code); ± is the "
              "standard deviation over the Monte Carlo seeds. *diverged*: the estimate left the numbers.", ""]
    for study in studies:
        observer = study.get(OBSERVER)
        lines += [f"## {study['name']}", "", f"model `{study['model']}` (sha256 {study['model_sha256'][:12]}), "
                  f"data `{study['data']}`", ""]
        if study["clean"]:
            lines += ["Clean run" + (", open loop" if observer else "") + ": " + _clean(study), ""]
        if observer:
            lines += _observer_lines(observer)
        measured = set(observer.get("measured_nodes", [])) if observer else set()
        ids = {e["case_id"]: e for e in observer["cases"]} if observer else {}
        cells = "| Δ RMSE °C | ± | Δ max °C | ± | Δ RMSE per unit |"
        for node in study["nodes"]:
            heading = f"### {node}" + (" (measured by the observer)" if node in measured or
                                       (node == "pm" and "magnet" in measured) else "")
            lines += [heading, ""]
            if observer:
                lines += [f"The three perturbations that move it most, open loop: {_top(study, node)}.", "",
                          f"With the observer: {_top(observer, node)}.", ""]
            else:
                lines += [f"The three perturbations that move it most: {_top(study, node)}.", ""]
            lines += [f"![tornado](tornado-{_slug(study['name'])}-{node}.png)", ""]
            if observer:
                lines += ["| perturbation | magnitude | open loop: " + cells[2:] + " observer: " + cells[2:],
                          "|---|---|" + "---|" * 10]
            else:
                lines += ["| perturbation | magnitude " + cells, "|---|---|" + "---|" * 5]
            for e in study["cases"]:
                head = f"| {e['kind']} {e['subject']} | {e['magnitude']:g} {e['unit']} |"
                lines.append(head + _figures(e, node) + (_figures(ids.get(e["case_id"]), node)[1:]
                                                         if observer else ""))
            lines.append("")
        if _worst(study):
            lines += ["Worst case found" + (", open loop" if observer else "") + ": " + _worst(study), ""]
        if observer and _worst(observer):
            lines += ["Worst case found, observer: " + _worst(observer), ""]
        if study["filtering"]:
            lines += _filtering_lines(study, study["name"], "Filtering the noisy inputs" + (
                ", open loop" if observer else ""), f"filtering-{_slug(study['name'])}.png")
        if observer and observer["filtering"]:
            lines += _filtering_lines(observer, study["name"], "Filtering the noisy inputs, observer",
                                      f"filtering-{_slug(study['name'])}-observer.png")
        if study["incomplete"]:
            lines += [f"Not done: {len(study['incomplete'])} case(s) (failed or lost); resume the study.", ""]
    return "\n".join(lines) + "\n"


def build_report(out: Path) -> dict:
    """{meta, studies} of the study in `out`, from its table alone."""
    with CaseStore(out / TABLE_NAME) as store:
        meta = store.meta()
        rows = store.rows()
    info = json.loads(meta.get("study", "{}"))
    if "case_ids" in meta:      # the last invocation's cases (a table resumed with another spec holds others too)
        wanted = set(json.loads(meta["case_ids"]))
        rows = [r for r in rows if r["case_id"] in wanted]
    studies = sensitivity(rows, info.get("sample_periods"), info.get("observers"))
    return {"study": info, "studies": studies}


def write_report(out: Path) -> Path:
    """OUT/report from OUT's table; returns the report.md path."""
    report = build_report(out)
    files = {"robustness.json": (json.dumps(report, indent=1, allow_nan=False) + "\n").encode(),
             "report.md": markdown(report["study"], report["studies"]).encode()}
    for study in report["studies"]:
        for node in study["nodes"]:
            files[f"tornado-{_slug(study['name'])}-{node}.png"] = tornado(study, node)
        node = "pm" if "pm" in study["nodes"] else (study["nodes"] or [None])[0]
        if study["filtering"] and node:
            files[f"filtering-{_slug(study['name'])}.png"] = filtering_figure(study, node)
        observer = study.get(OBSERVER)
        if observer and observer["filtering"] and node:
            files[f"filtering-{_slug(study['name'])}-observer.png"] = filtering_figure(
                {**observer, "name": f"{study['name']}, observer"}, node)
    target = out / REPORT_DIR
    earlier = [e.name for e in target.iterdir() if OUR_FILES.fullmatch(e.name)] if target.is_dir() else []
    write_directory_atomically(target, files, replaceable=earlier)
    return out / REPORT_DIR / "report.md"
