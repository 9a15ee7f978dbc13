"""The report's PNG figures (matplotlib, Agg backend, imported only when a report is written).

Each function draws into `out`: a path (written through a temporary name and renamed) or a binary file object
(the report renders its figures into memory and writes its directory at once, `bench.analysis.report`). Values
that are not finite (a model that overflowed) are left out of the curves, never drawn as inf. A series longer than
2·PLOT_BUCKETS points (the default run has 14 548 model steps) is drawn as its envelope: the minimum and the maximum
of each of PLOT_BUCKETS equal slices, so every excursion stays visible at the figure's resolution and a long run
costs a figure no more memory than a short one.

The CAN values drawn are those of the rows every figure is over (`References.can`, `bench.analysis.rowfilter`): a
row a check flagged as not the target's own answer is not drawn, and the figure says how many were left out. A
model whose values left every range is drawn without numpy's overflow warnings (the report's nulls say why)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from bench.analysis.canmetrics import TEMPERATURES, References
from bench.analysis.logdecode import BusRecord
from bench.analysis.results import BusLoad

LABELS = {"yoke": "stator yoke", "winding": "stator winding", "tooth": "stator tooth", "magnet": "permanent magnet"}
ORDER = (1, 3, 0, 2)  # winding, magnet, yoke, tooth


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out) -> None:
    if hasattr(out, "write"):
        fig.savefig(out, format="png", dpi=110)
        return
    path = Path(out)
    tmp = path.with_name(f".{path.stem}.partial.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)


PLOT_BUCKETS = 2_000     # the figures are 1210 pixels wide: 4000 points draw every excursion


def _envelope(t: np.ndarray, y: np.ndarray, buckets: int = PLOT_BUCKETS) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) as is when short, else the minimum and maximum of y in each of `buckets` slices, both at the slice's
    mid time (NaN where a slice has no finite value)."""
    y = np.asarray(y, dtype=float)
    n = len(y)
    if n <= 2 * buckets:
        return t, y
    size = -(-n // buckets)
    padded = np.full(size * buckets, np.nan)
    padded[:n] = y
    padded = padded.reshape(buckets, size)
    tt = np.full(size * buckets, np.nan)
    tt[:n] = t
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # an all-NaN slice: NaN, drawn as a gap
        low, high = np.nanmin(padded, axis=1), np.nanmax(padded, axis=1)
        mid = np.nanmean(tt.reshape(buckets, size), axis=1)
    return np.repeat(mid, 2), np.column_stack([low, high]).ravel()


def _band(t: np.ndarray, low: np.ndarray, high: np.ndarray,
          buckets: int = PLOT_BUCKETS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, low, high) as is when short, else per slice the smallest low and the largest high at the slice's mid time
    (a band drawn over a long run keeps every excursion, like `_envelope`)."""
    n = len(t)
    if n <= 2 * buckets:
        return t, low, high
    size = -(-n // buckets)

    def sliced(values, fill):
        padded = np.full(size * buckets, fill)
        padded[:n] = values
        return padded.reshape(buckets, size)

    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return (np.nanmean(sliced(t, np.nan), axis=1), np.nanmin(sliced(low, np.nan), axis=1),
                np.nanmax(sliced(high, np.nan), axis=1))


def _can(record: BusRecord, refs: References) -> np.ndarray:
    """(steps, 4) the CAN values drawn: the kept rows' (NaN elsewhere)."""
    if refs.can is not None:
        return refs.can
    return record.temps[refs.step_rows] if len(refs.step_rows) else np.zeros((0, 4))


def _excluded_label(refs: References) -> str:
    """'; N flagged rows not drawn' when the row rule left rows out."""
    rows = refs.figure_rows
    return f"; {rows.excluded_total} flagged rows not drawn" if rows is not None and rows.excluded_total else ""


def _finite(values) -> np.ndarray:
    """The values as floats, NaN where they are not finite (matplotlib leaves NaN out of a curve)."""
    values = np.asarray(values, dtype=float)
    return np.where(np.isfinite(values), values, np.nan)


def _gap_spans_h(record: BusRecord, refs: References) -> list[tuple[float, float]]:
    """The marked gaps (rows restart..lost) as spans of model time in hours."""
    if not len(refs.step_rows):
        return []
    spans = []
    for gap in record.gaps:
        first, last = gap["rows"]
        t0, t1 = np.interp([first - 1, last + 1], refs.step_rows, refs.step_time_s) / 3600.0
        spans.append((float(t0), float(t1)))
    return spans


def _shade_gaps(ax, spans: list[tuple[float, float]], label: bool) -> None:
    for i, (t0, t1) in enumerate(spans):
        ax.axvspan(t0, t1, color="tab:purple", alpha=0.25, lw=0,
                   label="marked gap (target lost, re-initialized)" if label and i == 0 else None)
        ax.axvline(t1, color="tab:purple", lw=0.6, ls=":")


def temperatures(path: Path, record: BusRecord, refs: References, title: str) -> None:
    """CAN temperatures vs measured reference vs offline float64 and float32 model, per node."""
    plt = _pyplot()
    fig, axes = plt.subplots(4, 1, figsize=(11, 12), sharex=True)
    t_h = refs.step_time_s / 3600.0
    spans = _gap_spans_h(record, refs)
    can = _can(record, refs)
    f64, f32 = _finite(refs.f64), _finite(refs.f32)
    for ax, i in zip(axes, ORDER, strict=True):
        name = TEMPERATURES[i]
        measured = {"winding": refs.measured_winding, "magnet": refs.measured_pm}.get(name)
        if measured is not None:
            ax.plot(*_envelope(t_h, measured), color="0.55", lw=1.6, label="measured (reference)")
        if refs.sigma is not None:   # an observer: its ±2σ about the CAN estimate, and the open loop beside it
            low, high = can[:, i] - 2 * refs.sigma[:, i], can[:, i] + 2 * refs.sigma[:, i]
            ax.fill_between(*_band(t_h, _finite(low), _finite(high)), color="tab:red", alpha=0.15, lw=0,
                            label="observer ±2σ (the target's Uncertainty frames)")
        if refs.open_loop is not None:
            ax.plot(*_envelope(t_h, _finite(refs.open_loop[:, i])), color="tab:green", lw=1.0,
                    label="offline float32, open loop")
        ax.plot(*_envelope(t_h, f64[:, i]), color="tab:blue", lw=1.0, label="offline float64")
        ax.plot(*_envelope(t_h, f32[:, i]), color="tab:orange", lw=1.0, ls="--", label="offline float32")
        ax.plot(*_envelope(t_h, can[:, i]), color="tab:red", lw=0, marker=".", ms=1.2,
                label=f"CAN (target, float32{_excluded_label(refs)})")
        _shade_gaps(ax, spans, ax is axes[0])
        ax.set_ylabel(f"{LABELS[name]} (°C)")
        ax.grid(alpha=0.3)
        finite = np.concatenate([f64[:, i], f32[:, i], can[:, i]])
        finite = finite[np.isfinite(finite)]
        if finite.size and (np.ptp(finite) > 1e3):
            ax.set_yscale("symlog", linthresh=100)
    axes[0].legend(loc="best", fontsize=8, markerscale=6)
    axes[-1].set_xlabel("time (h)")
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def float32_error(path: Path, record: BusRecord, refs: References) -> None:
    """float32 − float64 (the precision loss of the target's arithmetic) and CAN − float32 (the transport)."""
    plt = _pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    t_h = refs.step_time_s / 3600.0
    with np.errstate(invalid="ignore", over="ignore"):
        err = _finite(refs.f32 - refs.f64)
    for i in ORDER:
        top.plot(*_envelope(t_h, err[:, i]), lw=0.8, label=LABELS[TEMPERATURES[i]])
    top.set_ylabel("float32 − float64 (°C)")
    if np.isfinite(err).any() and np.nanmax(np.abs(err)) > 10:
        top.set_yscale("symlog", linthresh=0.01)
    top.grid(alpha=0.3)
    top.legend(fontsize=8)
    can = _can(record, refs)
    reference = refs.can_reference if refs.can_reference is not None else refs.f32
    with np.errstate(invalid="ignore", over="ignore"):
        diff = _finite(can - reference)
    for i in ORDER:
        bottom.plot(*_envelope(t_h, diff[:, i]), lw=0, marker=".", ms=1, label=LABELS[TEMPERATURES[i]])
    _shade_gaps(bottom, _gap_spans_h(record, refs), False)
    bottom.axhline(0.005, color="k", lw=0.6, ls=":")
    bottom.axhline(-0.005, color="k", lw=0.6, ls=":")
    bottom.set_ylabel("CAN − float32 (°C)")
    bottom.set_title(f"CAN − float32 of the kept rows{_excluded_label(refs)}", fontsize=9)
    if np.isfinite(diff).any() and np.nanmax(np.abs(diff)) > 0.05:
        bottom.set_yscale("symlog", linthresh=0.01)
    bottom.set_xlabel("time (h)")
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def step_time_histogram(path: Path, measured_us: np.ndarray, est_us: float | None,
                        m4_us: float | None = None) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    values = np.asarray(measured_us, dtype=float)
    values = values[np.isfinite(values)]
    if values.size:
        high = np.percentile(values, 99.9)
        ax.hist(np.clip(values, 0, high), bins=80, color="tab:blue", alpha=0.8,
                label=f"measured on the target process (n = {values.size})")
    if est_us is not None:
        ax.axvline(est_us, color="tab:red", lw=1.5, label=f"estimated C28x @ 90 MHz: {est_us:.1f} µs")
    if m4_us is not None:
        ax.axvline(m4_us, color="tab:green", lw=1.5,
                   label=f"measured Cortex-M4F @ 90 MHz (emulated firmware, p50): {m4_us:.1f} µs")
    ax.set_xlabel("model step time (µs)")
    ax.set_ylabel("model steps")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def bus_load(path: Path, load: BusLoad) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    start = np.asarray(load.window_start_s, dtype=float)
    percent = np.asarray(load.window_percent, dtype=float)
    if start.size:
        ax.step(start, percent, where="post", color="tab:blue",
                label=f"this replay, per {load.window_s:g} s of log time")
    if load.data_rate_percent is not None:
        ax.axhline(load.data_rate_percent, color="tab:red",
                   label=f"at the data rate (5 Hz): {load.data_rate_percent:.2f} %")
    ax.axhline(100.0, color="k", lw=0.6, ls=":")
    ax.set_xlabel("log time (s)")
    ax.set_ylabel(f"bus load at {load.bitrate / 1000:g} kbit/s (%)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
