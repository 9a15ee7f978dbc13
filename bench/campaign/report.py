"""The campaign report, from the table alone: OUT/report/report.md with verdicts.png (the verdict of every run
over the axes) and axis-<name>.png per axis (errors, cycles and throughput against the axis' values).

The directory is rendered in memory and written at once (`bench.fileio.write_directory_atomically`): an earlier
report is replaced whole or left as it was.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.campaign.store import DONE, Store, StoreError, summary_of
from bench.figures import agg_figure, png_bytes
from bench.fileio import foreign_entries, write_directory_atomically

REPORT_DIR = "report"
# cell label -> colour of the verdict matrix
COLOURS = {"clean": "#4caf50", "tolerated": "#a5d6a7", "not clean": "#ff9800", "criteria failed": "#fdd835",
           "failed": "#e53935",
           "timeout": "#8e24aa", "lost-worker": "#6d4c41", "not run": "#e0e0e0"}
OUR_FILES = re.compile(r"(report\.md|verdicts\.png|axis-[A-Za-z0-9_.-]+\.png)")


def cell(row: dict[str, Any] | None) -> str:
    """A run's verdict where it is done, else its status."""
    if row is None:
        return "not run"
    return (row["verdict"] or "done") if row["status"] == DONE else row["status"]


def axes_of(rows: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """Axis name -> its values in the order the runs have them."""
    axes: dict[str, list[Any]] = {}
    for row in rows:
        for name, value in json.loads(row["axes"] or "{}").items():
            values = axes.setdefault(name, [])
            if value not in values:
                values.append(value)
    return axes


def _excluded(row: dict) -> str:
    """'10 of 2000 (replayed 10)': the rows a check flagged, which no figure of the run holds; '–' without a verdict."""
    if row.get("rows_kept") is None:
        return "–"
    excluded = json.loads(row["rows_excluded_by_reason"] or "{}")
    total = row["rows_excluded"] or 0
    if not total:
        return "0"
    return f"{total} ({', '.join(f'{k} {n}' for k, n in excluded.items())})"


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _mean(values: Sequence[Any]) -> float | None:
    numbers = [v for v in values if isinstance(v, int | float) and math.isfinite(v)]
    return sum(numbers) / len(numbers) if numbers else None


def _max(values: Sequence[Any]) -> float | None:
    numbers = [v for v in values if isinstance(v, int | float) and math.isfinite(v)]
    return max(numbers) if numbers else None


def verdict_matrix(rows: list[dict[str, Any]]) -> tuple[list[str], list[str], list[list[str]]]:
    """(row labels, column labels, cells): the last axis across, every combination of the others down."""
    axes = axes_of(rows)
    by_axes = {json.dumps(json.loads(r["axes"] or "{}"), sort_keys=True): r for r in rows}
    names = list(axes)
    across = names[-1] if names else None
    down = names[:-1]
    columns = [f"{across}={v}" for v in axes[across]] if across else ["run"]
    labels, cells = [], []
    for combo in itertools.product(*(axes[n] for n in down)):
        chosen = dict(zip(down, combo, strict=True))
        labels.append(", ".join(f"{k}={v}" for k, v in chosen.items()) or (across or "run"))
        line = []
        for value in (axes[across] if across else [None]):
            key = dict(chosen) if across is None else {**chosen, across: value}
            line.append(cell(by_axes.get(json.dumps(key, sort_keys=True))))
        cells.append(line)
    return labels, columns, cells


def _verdict_figure(labels: list[str], columns: list[str], cells: list[list[str]]) -> bytes:
    from matplotlib.colors import to_rgb

    fig = agg_figure(min(2.0 + 1.3 * len(columns), 16), min(1.2 + 0.45 * len(labels), 30))
    ax = fig.add_subplot()
    ax.imshow([[to_rgb(COLOURS.get(c, "#bdbdbd")) for c in line] for line in cells], aspect="auto")
    for i, line in enumerate(cells):
        for j, text in enumerate(line):
            ax.text(j, i, text, ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(columns)), columns, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    ax.set_title("verdict of each run")
    return png_bytes(fig)


def _axis_figure(name: str, values: list[Any], rows: list[dict[str, Any]]) -> bytes:
    """Winding/PM RMSE, max |CAN − float32|, cycles and throughput of the done runs at each value of one axis."""
    fig = agg_figure(10, 7)
    panels = fig.subplots(2, 2)
    series = (
        (panels[0][0], "RMSE (°C)", (("rmse_winding_C", "winding", "o"), ("rmse_pm_C", "PM", "s"))),
        (panels[0][1], "max |CAN − float32| (°C)", (("max_can_minus_float32_C", "all nodes", "o"),)),
        (panels[1][0], "cycles per model step", (("est_c28x_cycles", "C28x (estimate)", "o"),
                                                  ("m4_cycles_p50", "Cortex-M4F p50 (measured)", "s"))),
        (panels[1][1], "throughput (rows/s)", (("throughput_rows_per_s", "rows/s", "o"),)),
    )
    done = [r for r in rows if r["status"] == DONE]
    position = {json.dumps(v): i for i, v in enumerate(values)}
    for ax, title, columns in series:
        for k, (column, label, marker) in enumerate(columns):
            xs, ys = [], []
            for r in done:
                value = json.loads(r["axes"] or "{}").get(name)
                y = r[column]
                if json.dumps(value) in position and isinstance(y, int | float) and math.isfinite(y):
                    xs.append(position[json.dumps(value)] + (k - (len(columns) - 1) / 2) * 0.12)
                    ys.append(y)
            if xs:
                ax.plot(xs, ys, marker, label=label, alpha=0.75, markersize=5)
        if column == "max_can_minus_float32_C":
            ax.axhline(0.005, color="grey", linestyle="--", linewidth=0.8, label="±0.005 °C (CAN resolution)")
        ax.set_title(title, fontsize=10)
        ax.set_xticks(range(len(values)), [str(v) for v in values], rotation=20, ha="right", fontsize=8)
        ax.set_xlim(-0.6, len(values) - 0.4)
        ax.set_ylim(bottom=0)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle(f"by {name} ({len(done)} done run(s))")
    return png_bytes(fig)


def _table(header: list[str], lines: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + \
        ["| " + " | ".join(line) + " |" for line in lines]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", name)


def render(rows: list[dict[str, Any]], meta: dict[str, str], fault_rows: list[dict[str, Any]]) -> dict[str, bytes]:
    """report.md and its PNGs (file name -> bytes) from the table's rows."""
    axes = axes_of(rows)
    files: dict[str, bytes] = {}
    name = meta.get("name", "campaign")
    counts: dict[str, int] = {}
    for r in rows:
        counts[cell(r)] = counts.get(cell(r), 0) + 1
    md = [f"# Campaign {name}", ""]
    if meta.get("description"):
        md += [meta["description"], ""]
    md += [f"Spec `{meta.get('spec_path', '?')}` (sha256 {meta.get('spec_sha256', '?')[:12]}), table "
           f"`{meta.get('table', 'campaign.sqlite')}`; {len(rows)} run(s): "
           + (", ".join(f"{n} {k}" for k, n in sorted(counts.items())) or "none") + ".",
           "", "Axes: " + ("; ".join(f"{k} = {', '.join(map(str, v))}" for k, v in axes.items()) or "none")
           + (f". Fixed: {meta['fixed']}" if meta.get("fixed") else "") + ".", ""]
    walls = [r["wall_s"] for r in rows if r["wall_s"] is not None]
    if walls:
        md += [f"Run wall time: {sum(walls):.1f} s in all, {_mean(walls):.1f} s per run on average "
               f"(a run's own process tree; the campaign's wall time is in the command's output).", ""]

    md += ["## Verdicts", ""]
    labels, columns, cells = verdict_matrix(rows)
    if rows:
        files["verdicts.png"] = _verdict_figure(labels, columns, cells)
        md += ["![verdicts](verdicts.png)", ""]
    md += _table(["", *columns], [[label, *line] for label, line in zip(labels, cells, strict=True)]) + [""]
    md += ["clean: the bench's verdict is clean; tolerated: it exited 0 with injected faults (all detected) or "
           "tolerated gaps; not clean: it exited 1 with its problems listed below; criteria failed: clean, but it "
           "failed acceptance criteria of its `criteria` file; failed, timeout, lost-worker: the run ended without a "
           "verdict (after one retry).", ""]

    md += ["## By axis", ""]
    for axis, values in axes.items():
        figure = f"axis-{_safe(axis)}.png"
        files[figure] = _axis_figure(axis, values, rows)
        md += [f"### {axis}", "", f"![{axis}]({figure})", ""]
        lines = []
        for value in values:
            group = [r for r in rows if json.loads(r["axes"] or "{}").get(axis) == value]
            done = [r for r in group if r["status"] == DONE]
            lines.append([str(value), str(len(group)), str(sum(cell(r) == "clean" for r in group)),
                          str(sum(cell(r) == "not clean" for r in group)), str(len(group) - len(done)),
                          _fmt(_mean([r["rmse_winding_C"] for r in done])), _fmt(_mean([r["rmse_pm_C"] for r in done])),
                          _fmt(_max([r["max_can_minus_float32_C"] for r in done]), 4),
                          _fmt(_mean([r["est_c28x_cycles"] for r in done]), 0),
                          _fmt(_mean([r["m4_cycles_p50"] for r in done]), 0),
                          _fmt(_mean([r["throughput_rows_per_s"] for r in done]), 0),
                          _fmt(_mean([r["wall_s"] for r in group]), 1)])
        md += _table([axis, "runs", "clean", "not clean", "no verdict", "RMSE winding (°C, mean)",
                      "RMSE PM (°C, mean)", "max \\|CAN − float32\\| (°C)", "C28x cycles (est.)",
                      "M4F cycles p50", "rows/s (mean)", "wall s (mean)"], lines) + [""]

    md += ["## Runs", ""]
    faults: dict[str, list[str]] = {}
    for f in fault_rows:
        faults.setdefault(f["run_id"], []).append(f"{f['kind']} {f['injected']}/{_fmt(f['detected'])}")
    lines = []
    for r in rows:
        lines.append([f"`{r['run_id']}`", ", ".join(f"{k}={v}" for k, v in json.loads(r["axes"] or "{}").items()),
                      r["status"], r["verdict"] or "–", str(r["attempts"]), _fmt(r["rmse_winding_C"]),
                      _fmt(r["rmse_pm_C"]), _excluded(r), _fmt(r["max_can_minus_float32_C"], 4),
                      ", ".join(faults.get(r["run_id"], [])) or "–", _fmt(r["est_c28x_cycles"]),
                      _fmt(r["m4_cycles_p50"]), _fmt(r["throughput_rows_per_s"], 0), _fmt(r["wall_s"], 1)])
    md += _table(["run", "axes", "status", "verdict", "attempts", "RMSE winding (°C)", "RMSE PM (°C)",
                  "rows left out of the figures", "max \\|CAN − float32\\| (°C)", "faults injected/detected",
                  "C28x cycles", "M4F cycles p50",
                  "rows/s", "wall s"], lines) + [""]
    trouble = [r for r in rows if cell(r) not in ("clean", "tolerated")]
    if trouble:
        md += ["## Problems", ""]
        for r in trouble:
            summary = summary_of(r)     # the run's own RunSummary: its problems as `bench run` gave them
            said = r["error"] or "; ".join(summary.problems if summary else json.loads(r["problems"] or "[]")) or "–"
            md.append(f"* `{r['run_id']}` ({cell(r)}): {said}")
        md.append("")
    files["report.md"] = "\n".join(md).encode("utf-8")
    return files


def write_report(out_dir: Path) -> Path:
    """(Re)build OUT/report from OUT/campaign.sqlite; the path of report.md. BenchError (one sentence) when the
    table is missing or not a campaign's, or the report directory holds files it did not write."""
    from bench.campaign.store import TABLE_NAME

    out_dir = Path(out_dir)
    with Store(out_dir / TABLE_NAME) as store:
        rows, meta, fault_rows = store.rows(), store.meta(), store.faults()
    target = out_dir / REPORT_DIR
    foreign = [n for n in foreign_entries(target, ()) if not OUR_FILES.fullmatch(n)]
    if foreign:
        raise StoreError(f"{target} holds {foreign[0]}, which the campaign report did not write; move it away or "
                         "choose another directory")
    replaceable = [n for n in foreign_entries(target, ()) if OUR_FILES.fullmatch(n)]
    write_directory_atomically(target, render(rows, meta, fault_rows), replaceable=replaceable)
    return target / "report.md"
