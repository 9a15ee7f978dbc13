"""Figures like the paper's Figs. 6 and 7: float32 estimates of one realization vs the reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.fileio import write_atomically


def realization_figure(evaluations: dict, realization: str, path: Path, title: str) -> Path:
    """Winding (top) and PM (bottom) float32 estimates at every Δt against the measured reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dts = sorted(dt for (name, dt) in evaluations if name == realization)
    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    first = evaluations[realization, dts[0]].run
    for ax, col, ref_name, label in ((axes[0], 1, "ref_winding", "winding"), (axes[1], 3, "ref_pm", "PM")):
        ax.plot(first.step_time_s / 60, getattr(first, ref_name), color="black", lw=1.2, label="reference")
        for dt in dts:
            ev = evaluations[realization, dt]
            est = ev.float32[:, col]
            est = np.where(np.abs(est) < 300, est, np.nan)  # a diverged float32 model leaves the plot
            ax.plot(ev.run.step_time_s / 60, est, lw=0.8, label=f"float32, Δt = {dt:g} s")
        ax.set_ylabel(f"{label} temperature (°C)")
        ax.set_ylim(0, 200)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=3)
    axes[1].set_xlabel("time (min)")
    fig.suptitle(title)
    fig.tight_layout()
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
    return path
