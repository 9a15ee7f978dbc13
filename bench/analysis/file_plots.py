"""One figure per evaluated data file: each measured node against the models' float32 estimates and the
copper low-pass baseline, with the error underneath."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bench.fileio import write_atomically

NODE_LABELS = {"winding": "winding", "pm": "PM", "yoke": "yoke", "tooth": "tooth"}


def file_figure(name: str, results: Sequence, labels: Sequence[str], path: Path) -> Path:
    """results: one bench.model.fileeval.FileResult per model (same file); labels: a legend name per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = results[0]
    nodes = list(first.references)
    fig, axes = plt.subplots(2, len(nodes), figsize=(4.2 * len(nodes), 6.5), sharex=True, squeeze=False,
                             gridspec_kw={"height_ratios": [2, 1]})
    minutes = first.evaluation.run.step_time_s / 60
    for col, node in enumerate(nodes):
        top, bottom = axes[0, col], axes[1, col]
        reference = first.references[node]
        top.plot(minutes, reference, color="black", lw=1.2, label="measured")
        baseline = first.baselines.get("copper_lowpass", {}).get(node)
        if baseline is not None:
            top.plot(minutes, baseline, color="gray", lw=0.8, ls="--", label="copper low-pass baseline")
            bottom.plot(minutes, baseline - reference, color="gray", lw=0.8, ls="--")
        for result, label in zip(results, labels, strict=True):
            estimate = np.where(np.abs(result.estimate(node, "float32")) < 600, result.estimate(node, "float32"),
                                np.nan)
            top.plot(minutes, estimate, lw=0.9, label=f"{label} (float32)")
            bottom.plot(minutes, estimate - reference, lw=0.8)
        top.set_title(NODE_LABELS[node])
        top.set_ylabel("°C")
        bottom.set_ylabel("error (°C)")
        bottom.set_xlabel("time (min)")
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(name)
    fig.tight_layout()
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    plt.close(fig)
    return path
