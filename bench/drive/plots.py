"""PNG plots of a dataset: normalized torque and speed (like paper Fig. 2) and the measured temperatures.

matplotlib is imported here only, with the Agg backend, so commands that do not plot never load it.
"""

from __future__ import annotations

import io
from pathlib import Path

from bench.drive.dataset import Dataset
from bench.drive.motor import VIRTUAL_MOTOR, MotorSpec
from bench.drive.sequence import TestSequence
from bench.fileio import write_bytes_atomically


def plot_dataset(dataset: Dataset, png: Path, spec: MotorSpec = VIRTUAL_MOTOR) -> Path:
    """Three panels over time: T/T_peak, n/n_max, and winding, PM, coolant and ambient temperatures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = dataset.time_s
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True, gridspec_kw={"height_ratios": [1, 1, 1.6]})
    axes[0].plot(t, dataset.torque_Nm / spec.peak_torque_Nm, lw=0.5, color="tab:blue")
    axes[0].set_ylabel("torque (normalized)")
    axes[1].plot(t, dataset.speed_rpm / spec.max_speed_rpm, lw=0.5, color="tab:orange")
    axes[1].set_ylabel("speed (normalized)")
    for name, label, color in (("winding_C", "winding", "tab:red"), ("pm_C", "PM (rotor surface + 5 °C)", "tab:purple"),
                               ("coolant_C", "coolant inlet", "tab:blue"), ("ambient_C", "ambient", "tab:gray")):
        axes[2].plot(t, dataset.column(name), lw=0.7, color=color, label=label)
    axes[2].set_ylabel("temperature (°C)")
    axes[2].set_xlabel("time (s)")
    axes[2].legend(loc="upper right", fontsize=8, ncol=2)
    for phase in TestSequence().phases:
        for ax in axes:
            ax.axvline(phase.start_s, color="k", lw=0.4, alpha=0.4)
        axes[0].annotate(phase.name, (phase.start_s + 30, 1.02), xycoords=("data", "axes fraction"), fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    setpoint = dataset.coolant_setpoint_C
    title = dataset.name if setpoint is None else f"{dataset.name}: coolant inlet {setpoint:g} °C"
    fig.suptitle(title)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    write_bytes_atomically(png, buffer.getvalue())
    plt.close(fig)
    return png
