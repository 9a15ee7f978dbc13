"""`bench firmware check`: a whole drive through the emulated firmware and through the Python float32 reference,
every output compared bit for bit.

Both sides run as the target does: the rows' samples are summed per model-step interval (fw_accumulate /
`InputAccumulator.accumulate`), the interval mean taken at its last row (fw_mean / `mean`) and one model step run
on it (fw_step / `Float32Estimator.step`). A mismatch is a model step whose four outputs are not the same 32 bits
on both sides. The drive has the artifact's `drive_signals` as columns: 4, or 6 with the d/q currents for a model
with an electrical loss model. The emulated run is timed on its own (emulated steps per second, block hook and all)
and its counted Cortex-M4 cycles per step are summarized.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bench.errors import BenchError
from dbc.contract import M4_CLOCK_HZ
from target_sim.artifact import ModelArtifact
from target_sim.firmware import FirmwareEstimator, FirmwareFault
from target_sim.losses import reads_currents
from target_sim.model import F32, Float32Estimator, InputAccumulator


def _bits(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float32).view(np.uint32)


def _run_firmware(model: FirmwareEstimator, drive: np.ndarray, initial, rule: InputAccumulator
                  ) -> tuple[list[int], np.ndarray, list[int], float]:
    """(rows with a step, outputs, cycles per step, seconds) of the emulated firmware."""
    rows, outputs, cycles = [], [], []
    model.reset(initial)
    started = time.perf_counter()
    for row, sample in enumerate(drive):
        model.accumulate(sample)
        if not rule.ends_interval(row):
            continue
        inputs = model.mean()
        if inputs is None:    # cannot happen: the row itself was accumulated
            raise BenchError(f"the firmware's fw_mean found no samples at row {row}")
        outputs.append(model.step(*inputs))
        cycles.append(model.last_cycles)
        rows.append(row)
    seconds = time.perf_counter() - started
    return rows, np.array(outputs, dtype=F32).reshape(-1, 4), cycles, seconds


def _run_reference(artifact: ModelArtifact, drive: np.ndarray, initial) -> np.ndarray:
    model = Float32Estimator(artifact)
    model.reset(initial)
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt, len(artifact.drive_signals))
    outputs = []
    for row, sample in enumerate(drive):
        inputs = acc.add(row, sample)
        if inputs is not None:
            outputs.append(model.step(*inputs))
    return np.array(outputs, dtype=F32).reshape(-1, 4)


def check_firmware(artifact: ModelArtifact, elf: str | Path | bytes, drive: np.ndarray, initial) -> dict:
    """The JSON report of `bench firmware check` (FirmwareError for a bad ELF, BenchError for an emulator fault; one
    sentence each)."""
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
    rule = InputAccumulator(artifact.data_sample_period, artifact.dt, width)
    try:
        rows, firmware, cycles, seconds = _run_firmware(model, drive, initial, rule)
    except FirmwareFault as exc:
        raise BenchError(f"the firmware {label} faulted in the emulated core: {exc}") from None
    reference = _run_reference(artifact, drive, initial)
    if reference.shape != firmware.shape:     # both follow one row rule: a bug if not
        raise BenchError(f"the firmware ran {len(firmware)} model steps, the reference {len(reference)}")
    differ = np.flatnonzero((_bits(firmware) != _bits(reference)).any(axis=1))
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
    return {
        "kind": artifact.kind, "realization": artifact.realization, "dt": artifact.dt,
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
