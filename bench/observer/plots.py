"""The observer's figure per file (`bench evaluate --plots DIR` with an observer): each node the file measures,
the reference, the open loop and the observer's estimate with its ±2σ band (from the float32 filter's own
covariance, C P Cᵀ), the measured nodes marked in their titles (their error is not an estimate's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.figures import agg_figure, png_bytes
from bench.fileio import write_bytes_atomically
from bench.model.fileeval import OUTPUT_INDEX

BAND_SIGMAS = 2.0


def observer_figure(result, path: Path) -> Path:
    """Write `result`'s (an `ObserverFileResult` with its trace) figure to `path`; returns the path."""
    trace = result.trace
    nodes = list(trace["references"])
    fig = agg_figure(9.0, 2.4 * len(nodes))
    minutes = np.asarray(trace["time_s"]) / 60.0
    for row, node in enumerate(nodes):
        ax = fig.add_subplot(len(nodes), 1, row + 1)
        i = OUTPUT_INDEX[node]
        estimate, sigma = trace["observer"][:, i], trace["sigma"][:, i]
        ax.fill_between(minutes, estimate - BAND_SIGMAS * sigma, estimate + BAND_SIGMAS * sigma, color="C1",
                        alpha=0.25, linewidth=0, label="observer ±2σ")
        ax.plot(minutes, trace["references"][node], color="k", linewidth=1.0, label="measured")
        ax.plot(minutes, trace["open_loop"][:, i], color="C0", linewidth=0.9, label="open loop")
        ax.plot(minutes, estimate, color="C1", linewidth=0.9, label="observer")
        measured = " (measured by the observer: not an estimate)" if node in result.measured_nodes else ""
        ax.set_title(f"{result.name}: {node}{measured}", fontsize=9)
        ax.set_ylabel("°C")
        if row == 0:
            ax.legend(fontsize=8, loc="best")
    ax.set_xlabel("time (min)")
    write_bytes_atomically(path, png_bytes(fig))
    return path
