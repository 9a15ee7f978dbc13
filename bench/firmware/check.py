"""`bench firmware check`: a whole drive through the emulated firmware and through the Python float32 reference,
every output compared bit for bit.

Both sides run as the target does: the rows' samples are summed per model-step interval (fw_accumulate /
`InputAccumulator.accumulate`), the interval mean taken at its last row (fw_mean / `mean`) and one model step run
on it (fw_step / `Float32Estimator.step`). A mismatch is a model step whose four outputs are not the same 32 bits
on both sides. An observer's model also takes its measurements' raw channels after the drive values; each step
compares each node's 1-sigma, each measurement's innovation and its innovation gate (rejected this step,
sensor flagged: fw_obs_gate) too, and after every CHECKPOINT_EVERY_STEPS-th step
the filter's checkpoint (what ObserverCheckpoint carries) element by element. The drive has the artifact's
`drive_signals` as columns: 4, or 6 with the d/q currents for a model with an electrical loss model. The
emulated run is timed on its own (emulated steps per second, block hook and all) and its counted Cortex-M4 cycles
per step are summarized.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.errors import BenchError
from dbc.contract import CHECKPOINT_EVERY_STEPS, M4_CLOCK_HZ
from target_sim.artifact import ModelArtifact
from target_sim.firmware import FirmwareEstimator, FirmwareFault
from target_sim.losses import reads_currents
from target_sim.model import F32, Float32Estimator, InputAccumulator
from target_sim.observer import Float32Observer, has_observer

Progress = Callable[[int, int], None]    # (rows done, rows), as bench.progress.ProgressBar takes it
PROGRESS_EVERY = 256                      # rows between two progress calls: well under a tenth of a second here


def _bits(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float32).view(np.uint32)


def _run_firmware(model: FirmwareEstimator, samples: np.ndarray, initial, rule: InputAccumulator,
                  progress: Progress | None = None) -> tuple[list[int], np.ndarray, list[int], float]:
    """(rows with a step, results per step, cycles per step, seconds) of the emulated firmware: a result is the four
    outputs, and for an observer's model each node's 1-sigma, each measurement's innovation and gate after them, and
    the filter's checkpoint after every CHECKPOINT_EVERY_STEPS-th step (as the node sends it). `progress` is told
    (rows done, rows) every PROGRESS_EVERY rows: the emulated core is the slow part of a check."""
    rows, results, cycles = [], [], []
    width = model.width
    model.reset(initial)
    started = time.perf_counter()
    for row, sample in enumerate(samples):
        if progress is not None and row % PROGRESS_EVERY == 0:
            progress(row, len(samples))
        model.accumulate(sample)
        if not rule.ends_interval(row):
            continue
        inputs = model.mean()
        if inputs is None:    # cannot happen: the row itself was accumulated
            raise BenchError(f"the firmware's fw_mean found no samples at row {row}")
        if model.observer:
            y = model.step(*inputs[:width], z=inputs[width:])
            sigma, innovations = model.report()
            results.append([*y, *sigma, *innovations, *model.gate(),
                            *_checkpoint_of(model, len(results) + 1, model.checkpoint_size)])
        else:
            results.append(model.step(*inputs))
        cycles.append(model.last_cycles)
        rows.append(row)
    seconds = time.perf_counter() - started
    if progress is not None:
        progress(len(samples), len(samples))
    return rows, np.array(results, dtype=F32).reshape(len(results), -1), cycles, seconds


def _checkpoint_of(model, steps: int, size: int) -> np.ndarray:
    """The filter's checkpoint after the `steps`-th step when the node would send one, else NaN in its place."""
    return np.full(size, np.nan, dtype=F32) if steps % CHECKPOINT_EVERY_STEPS else model.checkpoint()


def _run_reference(artifact: ModelArtifact, samples: np.ndarray, initial) -> np.ndarray:
    """The Python float32 reference's results per step (as `_run_firmware`'s)."""
    width = len(artifact.drive_signals)
    observer = has_observer(artifact)
    model = Float32Observer(artifact) if observer else Float32Estimator(artifact)
    model.reset(initial)
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt, samples.shape[1])
    results = []
    for row, sample in enumerate(samples):
        inputs = acc.add(row, sample)
        if inputs is None:
            continue
        if observer:
            y = model.step(*inputs[:width], z=inputs[width:])
            results.append([*y, *model.sigma(), *model.innovations, *gate_codes(model),
                            *_checkpoint_of(model, len(results) + 1, model.checkpoint_size())])
        else:
            results.append(model.step(*inputs))
    return np.array(results, dtype=F32).reshape(len(results), -1)


def gate_codes(model: Float32Observer) -> np.ndarray:
    """fw_obs_gate's values of the reference after a step: rejected (bit 0) and flagged (bit 1) per measurement."""
    return model.gate.rejected.astype(np.uint8) | (model.gate.flagged.astype(np.uint8) << 1)


def _same(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per step: every value the same 32 bits (a NaN innovation, no update, on both sides counts as the same)."""
    return ((_bits(a) == _bits(b)) | (np.isnan(a) & np.isnan(b))).all(axis=1)


def check_firmware(artifact: ModelArtifact, elf: str | Path | bytes, drive: np.ndarray, initial,
                   measurement: np.ndarray | None = None, progress: Progress | None = None) -> dict:
    """The JSON report of `bench firmware check` (FirmwareError for a bad ELF, BenchError for an emulator fault; one
    sentence each). An observer's model also takes its measurements' raw channels per row (rows, channels) (NaN:
    no reading in that row; `target_sim.observer.node.raw_channels`), and each step's 1-sigma, innovations and the
    periodic checkpoint are compared too. `progress` follows the emulated rows (as a replay's bar)."""
    label = elf if isinstance(elf, bytes) else str(elf)
    model = FirmwareEstimator(artifact, elf)
    drive = np.asarray(drive, dtype=F32)
    width = len(artifact.drive_signals)
    if drive.ndim != 2 or drive.shape[1] != width:
        where = f" ({artifact.path})" if artifact.path is not None else ""
        given = drive.shape[1] if drive.ndim == 2 else 0
        hint = (f"; its {artifact.loss_model} loss model needs the d/q currents (data columns i_d_A, i_q_A)"
                if reads_currents(artifact.drive_signals) else "")
        raise BenchError(f"model {artifact.model_id:08x}{where} runs on {width} drive values per row "
                         f"({', '.join(artifact.drive_signals)}), the data gives {given}{hint}")
    samples = drive
    if model.observer:
        raw = None if measurement is None else np.asarray(measurement, dtype=F32).reshape(len(measurement), -1)
        if raw is None or len(raw) != len(drive) or raw.shape[1] != model.channels:
            raise BenchError(f"model {artifact.model_id:08x} has an observer: the check needs its measurements' "
                             f"{model.channels} raw channel(s) per row beside the drive")
        samples = np.column_stack([drive, raw])
    rule = InputAccumulator(artifact.data_sample_period, artifact.dt, samples.shape[1])
    try:
        rows, firmware, cycles, seconds = _run_firmware(model, samples, initial, rule, progress)
    except FirmwareFault as exc:
        raise BenchError(f"the firmware {label} faulted in the emulated core: {exc}") from None
    reference = _run_reference(artifact, samples, initial)
    if reference.shape != firmware.shape:     # both follow one row rule: a bug if not
        raise BenchError(f"the firmware ran {len(firmware)} model steps, the reference {len(reference)}")
    differ = np.flatnonzero(~_same(firmware, reference))
    first = None
    if differ.size:
        k = int(differ[0])
        first = {"step": k, "row": rows[k], "firmware": [float(v) for v in firmware[k]],
                 "reference": [float(v) for v in reference[k]],
                 "firmware_hex": [float(v).hex() for v in firmware[k]],
                 "reference_hex": [float(v).hex() for v in reference[k]]}
    counted = np.asarray(cycles, dtype=float)
    figures = {"p50": int(round(float(np.percentile(counted, 50)))), "max": int(counted.max())} if cycles else \
        {"p50": None, "max": None}
    used = np.isfinite(reference[:, 8: 8 + model.measurements]) if model.observer else None
    updates = int(np.count_nonzero(used.any(axis=1))) if used is not None else None
    per_measurement = [int(n) for n in used.sum(axis=0)] if used is not None else None
    gates = reference[:, 8 + model.measurements: 8 + 2 * model.measurements].astype(np.uint8) \
        if model.observer else None
    return {
        "kind": artifact.kind, "observer": model.observer, "updates": updates,
        "updates_per_measurement": per_measurement, "realization": artifact.realization,
        "rejected_per_measurement": None if gates is None else [int(n) for n in (gates & 1).sum(axis=0)],
        "flagged_per_measurement": None if gates is None else [bool(b) for b in (gates & 2).any(axis=0)],
        "dt": artifact.dt,
        "rows": int(len(drive)), "steps": int(len(firmware)),
        "mismatches": int(differ.size), "first_mismatch": first,
        "cycles": figures,
        "exec_us_at_90MHz": {key: None if value is None else round(value * 1e6 / M4_CLOCK_HZ, 2)
                             for key, value in figures.items()},
        "flash_bytes": model.memory["flash_bytes"], "ram_bytes": model.memory["ram_bytes"],
        "stack_used_bytes": model.fw.stack_used(),
        "emulated_steps_per_s": round(len(firmware) / seconds, 1) if seconds > 0 else None,
        "emulated_rows_per_s": round(len(drive) / seconds, 1) if seconds > 0 else None,
    }
