"""From a decoded bus log to the bench's numbers (`bench.analysis.results.RunResults`): references, agreement,
accuracy, timing. The bus load is `bench.analysis.busload`'s, the pass/fail rules `bench.analysis.verdict`'s.

References, both fed with the drive values *as decoded from the frames the host sent* and the initial
temperatures as decoded from the ResetTemps frames, so CAN quantization is the same for all:
* offline float32: `target_sim.model.run_offline`, the target's own code (agreement must be within the 0.01 °C
  quantization of the temperature signals, ±0.005 °C);
* offline float64: the interval means in float64 through the artifact's float64 coefficients: the numba kernel
  `bench.thermal.estimator.run_batch` for the LTI LPTN and the Hammerstein model with loss maps, the float64 twin of
  the target's estimator for the parameter-varying LPTN (which has no batch kernel), for a model with an
  electrical loss model and for the delta realization (x <- x + Δ·(A x + B ũ) about a reference temperature).
A model with an electrical loss model needs the d/q currents: the references then run on the six values of each
row, the currents decoded from the logged DriveCurrents frames (a log without them cannot be compared with such a
model); a loss-map model uses the first four (it ignores DriveCurrents).
The measured winding and PM temperatures (when the dataset is given) are interpolated at the step times
(k+1)·Δt, as in `bench.model.runs`. Yoke and tooth have no measurement: their RMSE is against the float64 model.

CAN agreement is checked on every reply of every segment (`logdecode`): a segment that starts at row s (a
re-initialization after the target was lost) from the state vector of its RESTORE (an echoed StateCheckpoint) or
the temperatures of its RESET is compared with the float32 reference restarted the same way — the target's own
code from that state, decoded from the frames, at row s with the interval accumulator empty — so "CAN =
reference within ±0.005 °C" holds across restarts and checks the restore itself. A checkpoint is the target's
float32 state bit for bit, so the restarted reference is the clean run's exactly (the tests compare them); the
float32 − float64 and RMSE figures describe the model on the clean run.
The faults marked in the log (BenchEvent) and, when the `<log>.faults.json` sidecar is there, their detection,
go into `RunResults.faults`.

Every figure of the CAN values (RMSE, max |CAN − clean run|, the round trip, the plots through `References.can`)
is over the rows `bench.analysis.rowfilter.kept_rows` keeps: a row a check flagged as not the target's own answer
(contested, replayed, off the float32 reference) is left out and counted in `RunResults.figure_rows`.

A model whose values overflow (float32, float64 or both) is judged, not warned about: the reference runs and the
figures ignore numpy's overflow warnings, and the nulls say which values were not finite.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np

from bench.analysis.busload import bus_load
from bench.analysis.logdecode import BusRecord
from bench.analysis.observer_metrics import observer_results, sigma_at
from bench.analysis.results import (
    Accuracy,
    Agreement,
    CycleFigures,
    DataIdentity,
    FaultGap,
    FaultResults,
    FigureRows,
    Heartbeat,
    Integrity,
    MeasuredRmse,
    Memory,
    ModelInfo,
    NodeLabels,
    NodeValues,
    NonFinite,
    Percentiles,
    Replies,
    RunResults,
    Throughput,
    Timing,
    finite_results,
)
from bench.analysis.rowfilter import RowSelection, kept_rows
from bench.analysis.verdict import QUANTIZATION_C, notes
from bench.thermal.estimator import SIGMOID_ROWS, identity_sigmoid, loop_parameters, run_batch
from bench.thermal.excitation import interval_means
from dbc.contract import HEARTBEAT_TIMEOUT_S, M4_CLOCK_HZ, MEASUREMENT_MESSAGES, TEMPERATURE_NODES
from dbc.database import frame_id, temperature_range
from dbc.mutations import FRAME_FAULT_KINDS
from dbc.transport import NOMINAL_BITRATE
from host.results import gap_count, percentiles
from target_sim.artifact import ModelArtifact
from target_sim.costs import memory_estimate
from target_sim.kinds import MODEL_KINDS, is_delta
from target_sim.losses import reads_currents, row_of_width
from target_sim.model import Float32Estimator, InputAccumulator, run_offline
from target_sim.observer import has_observer, run_observer_offline
from target_sim.observer.node import NodeObserver, raw_channels, raw_sources

TEMPERATURES = TEMPERATURE_NODES
AGREEMENT_TOLERANCE_C = QUANTIZATION_C + 1e-9


@dataclass
class References:
    step_rows: np.ndarray           # (steps,) data row after which model step k ran
    step_time_s: np.ndarray         # (steps,) (k+1)·Δt
    f32: np.ndarray                 # (steps, 4) yoke, winding, tooth, magnet
    f64: np.ndarray
    measured_winding: np.ndarray | None
    measured_pm: np.ndarray | None
    can_reference: np.ndarray | None = None   # (steps, 4) float32 restarted as the target was (= f32 if never)
    can: np.ndarray | None = None             # (steps, 4) the CAN values of the kept rows (NaN: not kept)
    kept: np.ndarray | None = None            # (rows,) the rows every figure is over (`rowfilter.kept_rows`)
    figure_rows: FigureRows | None = None     # how many, and those left out by reason
    open_loop: np.ndarray | None = None       # (steps, 4) the open loop's float32 run beside an observer's
    sigma: np.ndarray | None = None           # (steps, 4) an observer's 1-sigma per node, from the target's frames
    rejected: np.ndarray | None = None        # (steps, measurements) the observer's gate rejected the reading
    flagged: np.ndarray | None = None         # (measurements,) the gate flagged the sensor (in a row, latched)
    flagged_steps: np.ndarray | None = None   # (steps, measurements) ... flagged after each step


def segment_estimates(artifact: ModelArtifact, drive: np.ndarray, start_row: int, initial, stop_row: int, *,
                      state=None, measured: np.ndarray | None = None, checkpoint: dict | None = None) -> np.ndarray:
    """(stop_row - start_row, 4): the estimate the target replies with after each row, for a target reset to
    `initial` (or restored to the state vector `state`) at `start_row` (the target's own float32 code and
    interval-mean rule, accumulator empty). A model with an observer steps through it (`target_sim.observer.node`:
    a restore continues the filter from its echoed `checkpoint` {Index: value} when complete, else starts its
    covariance afresh, as the target's does) on `measured`, its raw channels per row (`observed_channels`; NaN:
    none)."""
    observer = NodeObserver(artifact) if has_observer(artifact) else None
    model = observer or Float32Estimator(artifact)
    if state is not None:
        if observer is not None:
            observer.restore(state, checkpoint)
        else:
            model.restore(state)
    else:
        model.reset(initial)
    step = model.step if observer is None else (lambda *values: observer.step(values))
    samples = np.asarray(drive[start_row:stop_row], dtype=np.float64)
    if observer is not None:
        channels = np.full((len(drive), observer.channels), np.nan) if measured is None \
            else np.asarray(measured, dtype=np.float64).reshape(len(drive), -1)
        samples = np.column_stack([samples, channels[start_row:stop_row]])
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt, samples.shape[1])
    estimate = (observer.model if observer is not None else model).y.copy()
    out = np.empty((max(stop_row - start_row, 0), 4), dtype=np.float32)
    for i, sample in enumerate(samples.astype(np.float32)):
        inputs = acc.add(start_row + i, sample)
        if inputs is not None:
            estimate = step(*inputs)
        out[i] = estimate
    return out.astype(np.float64)


def _clean_estimates(refs: References, rows: int, initial) -> np.ndarray:
    """(rows, 4) estimate after each row of the clean run, from its model steps."""
    index = np.searchsorted(refs.step_rows, np.arange(rows), side="right") - 1
    start = np.asarray(initial, dtype=np.float32).astype(np.float64)
    if len(refs.step_rows) == 0:
        return np.tile(start, (rows, 1))
    return np.where(index[:, None] >= 0, refs.f32[np.maximum(index, 0)], start)


def restarted_agreement(artifact: ModelArtifact, record: BusRecord, clean: np.ndarray) -> tuple[np.ndarray, dict]:
    """Every reply of every segment against the float32 reference restarted as that segment was (`clean`, the
    clean run's estimate after each row, is segment 0's).

    Returns (final reference per row (rows, 4), {max_abs: per temperature, compared, saturated})."""
    rows = record.rows
    final = np.full((rows, 4), np.nan)
    worst = np.full(4, np.nan)
    compared = saturated = 0
    for index, segment in enumerate(record.segments):
        if (segment.initial is None and segment.state is None) or not len(segment.reply_rows):
            continue
        stop = int(segment.reply_rows.max()) + 1
        if segment.start_row == 0 and segment.state is None and np.array_equal(segment.initial, record.initial):
            ref = clean[:stop]
        else:
            ref = segment_estimates(artifact, record.drive, segment.start_row, segment.initial, stop,
                                    state=segment.state, measured=observed_channels(record, artifact),
                                    checkpoint=segment.observer_checkpoint)
        offset = segment.start_row
        keep = (segment.reply_rows >= offset) & (segment.reply_rows < rows)
        at = segment.reply_rows[keep]
        expected = ref[at - offset]
        low, high = temperature_range()
        in_range = (expected >= low) & (expected <= high)
        diff = np.abs(np.where(in_range, segment.reply_temps[keep] - expected, np.nan))
        saturated += int(np.count_nonzero(~in_range))
        compared += int(at.size)
        if diff.size:
            worst = np.fmax(worst, np.nanmax(np.where(np.isnan(diff), -np.inf, diff), axis=0))
        owned = at[record.owner[at] == index]
        final[owned] = ref[owned - offset]
    worst = np.where(np.isinf(worst), np.nan, worst)
    return final, {"max_abs": worst, "compared": compared, "saturated": saturated}


def float64_reference(artifact: ModelArtifact, drive: np.ndarray, initial) -> np.ndarray:
    """(steps, 4) outputs of the model in double precision on the float64 interval means of `drive`."""
    means = interval_means(drive, artifact.data_sample_period, artifact.dt)
    if len(means) == 0:
        return np.zeros((0, 4))
    # no batch kernel for a network rebuilt every step, nor for the delta step (the kernel steps x <- A x + B u;
    # it would also compile, about 35 MB, for a run whose default model is delta): the target's estimator in float64
    if not MODEL_KINDS[artifact.kind].linear_block or is_delta(artifact.kind, artifact.realization):
        model = Float32Estimator(artifact, dtype=np.float64)
        model.reset(np.asarray(initial, dtype=np.float64))
        out = np.empty((len(means), 4))
        for k, row in enumerate(means):
            out[k] = model.step(*row)
        return out
    from bench.model.artifact_values import artifact_loss_model, artifact_parameters, shift_form
    from bench.model.runs import step_inputs

    loss_model, motor = artifact_loss_model(artifact)   # its kind's float64 model (bench.motor.losskinds)
    inputs = step_inputs(np.asarray(drive, dtype=np.float64), loss_model, motor, artifact.dt,
                         artifact.data_sample_period)
    if MODEL_KINDS[artifact.kind].input_nonlinearity:
        sig = np.stack([artifact.array("input_nonlinearity", row, dtype=np.float64) for row in SIGMOID_ROWS])
    else:
        sig = identity_sigmoid(np.ones(4))
    a, b, c = shift_form(artifact)
    _, traj = run_batch(a[None], b[None], c[None], loop_parameters(artifact_parameters(artifact))[None], sig[None],
                        inputs, np.asarray(initial, dtype=np.float64), keep_trajectories=True)
    return traj[0]


def observed_channels(record: BusRecord, artifact: ModelArtifact, drive: np.ndarray | None = None) -> np.ndarray | None:
    """(rows, channels) the raw channels the artifact's observer read in each row of the log (its measurement
    channels, and the row's own currents for the flux linkage, from `drive` or the logged rows; NaN: none), None
    without an observer."""
    if not has_observer(artifact):
        return None
    rows = np.asarray(record.drive if drive is None else drive, dtype=np.float64)
    measured = record.measurements if record.measurements.shape[0] == record.rows else None
    return raw_channels(raw_sources(artifact), rows, measured)


def references(artifact: ModelArtifact, drive: np.ndarray, initial, dataset=None,
               measured: np.ndarray | None = None) -> References:
    """The offline float32 and float64 references; for a model with an observer the observer's (the target's own
    code in float32, and in float64) on `measured`, with the open loop's float32 run beside (`open_loop`)."""
    open_loop = rejected = flagged = flagged_steps = None
    if has_observer(artifact):
        z = np.full((len(drive), len(raw_sources(artifact))), np.nan) if measured is None else measured
        run = run_observer_offline(artifact, drive, z, initial)
        step_rows, f32 = run.rows, run.outputs
        rejected, flagged, flagged_steps = run.rejected, run.flagged, run.flagged_steps
        f64 = run_observer_offline(artifact, drive, z, initial, dtype=np.float64).outputs.astype(np.float64)
        open_loop = run_offline(artifact, drive, initial)[1].astype(np.float64)
    else:
        step_rows, f32 = run_offline(artifact, drive, initial)
        f64 = float64_reference(artifact, drive, initial)
    steps = min(len(step_rows), len(f64))
    step_time = (np.arange(steps) + 1) * artifact.dt
    winding = pm = None
    if dataset is not None:
        winding = np.interp(step_time, dataset.time_s, dataset.winding_C)
        pm = np.interp(step_time, dataset.time_s, dataset.pm_C)
    return References(step_rows[:steps], step_time, f32[:steps].astype(np.float64), f64[:steps], winding, pm,
                      open_loop=None if open_loop is None else open_loop[:steps],
                      rejected=None if rejected is None else rejected[:steps], flagged=flagged,
                      flagged_steps=None if flagged_steps is None else flagged_steps[:steps])


def _rmse(a: np.ndarray, b: np.ndarray) -> float | None:
    ok = np.isfinite(a) & np.isfinite(b)
    with np.errstate(over="ignore"):     # values that left every range: inf, made null with its reason
        return float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2))) if ok.any() else None


def _max_error(a: np.ndarray, b: np.ndarray) -> float | None:
    """max |a − b| over the samples where both are finite (None: none are)."""
    ok = np.isfinite(a) & np.isfinite(b)
    with np.errstate(over="ignore"):
        return float(np.max(np.abs(a[ok] - b[ok]))) if ok.any() else None


def _max_abs(a: np.ndarray) -> float | None:
    a = a[np.isfinite(a)]
    return float(np.max(np.abs(a))) if a.size else None


# ------------------------------------------------------------------------------------------------ metrics
def intended_drive(record: BusRecord, dataset=None) -> tuple[np.ndarray, int]:
    """The drive values the host meant to send, and how many rows never reached the bus intact (faults in real
    time): those come from the dataset when it is given, else they repeat the row before (an approximation)."""
    drive = record.drive.copy()
    lost = ~np.isfinite(drive).all(axis=1)
    if not lost.any():
        return drive, 0
    if dataset is not None:
        from bench.model.runs import drive_matrix

        columns = row_of_width(drive.shape[1])    # the rows carry the d/q currents: so must the data
        if dataset.has_currents or not reads_currents(columns):
            values = drive_matrix(dataset, columns)
            rows = np.flatnonzero(lost[:len(values)])
            drive[rows] = values[rows]
    for row in np.flatnonzero(~np.isfinite(drive).all(axis=1)):
        drive[row] = drive[row - 1] if row > 0 else np.nan_to_num(drive[row])
    return drive, int(np.count_nonzero(lost))


def drive_for_model(record: BusRecord, artifact: ModelArtifact) -> BusRecord:
    """The record with the drive values the model uses: all six (with the d/q currents of the logged DriveCurrents)
    for an electrical loss model, the first four for loss maps; ValueError (one sentence) when the log has no
    currents and the model needs them."""
    width = len(artifact.drive_signals)
    if record.drive.shape[1] == width:
        return record
    if record.drive.shape[1] < width:
        raise ValueError(f"model {artifact.model_id:08x} has an {artifact.loss_model} loss model, which needs the d/q "
                         f"currents, and the log's rows carry none (no DriveCurrents frames)")
    return replace(record, drive=record.drive[:, :width])


def measurement_faults(record: BusRecord) -> int:
    """The frame faults the log marks on measurement frames (Measurements, DriveVoltages; a delayed row's mark
    names its first frame, which is its Measurements: the row still arrives whole)."""
    ids = {frame_id(name) for name in MEASUREMENT_MESSAGES}
    return sum(1 for mark in record.marks
               if mark.event == "fault" and mark.frame_id in ids and mark.fault in FRAME_FAULT_KINDS)


def ran_firmware(record: BusRecord) -> bool:
    """The log's target ran the firmware engine: it sent the measured Cortex-M4F cycles (Timing4)."""
    cycles = record.timing.get("m4_cycles")
    return cycles is not None and cycles.size > 0


def twin_agreement(artifact: ModelArtifact, record: BusRecord, xcp_elf: str | os.PathLike | None = None
                   ) -> tuple[np.ndarray, dict]:
    """Every final reply against the target's twin fed the logged frames (`bench.analysis.twin`), its XCP cells
    laid out by `xcp_elf`."""
    from bench.analysis.twin import run_twin

    run = run_twin(artifact, record, xcp_elf)
    twin = run.estimates
    both = record.answered & np.isfinite(twin).all(axis=1)
    low, high = temperature_range()
    in_range = (twin >= low) & (twin <= high)
    diff = np.where(in_range, np.abs(record.temps - twin), np.nan)[both]
    worst = np.nanmax(np.where(np.isnan(diff), -np.inf, diff), axis=0) if diff.size else np.full(4, np.nan)
    worst = np.where(np.isinf(worst), np.nan, worst)
    return twin, {"max_abs": worst, "compared": int(np.count_nonzero(both)),
                  "saturated": int(np.count_nonzero(~in_range[both])),
                  "downloads_unlike_target": run.downloads_unlike_target}


def compute(record: BusRecord, artifact: ModelArtifact, dataset=None, *, bitrate: int = NOMINAL_BITRATE,
            xcp_elf: str | os.PathLike | None = None) -> tuple[RunResults, References]:
    """The report's metric table (`RunResults`) and the reference trajectories.

    A log whose rows did not all reach the target (faults in real time) is checked against the target's twin,
    and the clean references run on the drive values the host meant to send. So is a log with XCP DOWNLOADs: the
    twin replays them at the addresses of `xcp_elf`, the firmware ELF the target's XCP slave was laid out by (a
    firmware target's own, or a Python target's `--xcp-elf`; None: the Python slave's pages)."""
    if record.initial is None:
        raise ValueError("the log has no complete RESET (ResetTemps1, ResetTemps2, Control RESET)")
    record = drive_for_model(record, artifact)
    drive, lost_rows = intended_drive(record, dataset)
    measured = observed_channels(record, artifact, drive)
    with np.errstate(over="ignore", invalid="ignore"):   # a model that overflows: judged below, not warned about
        refs = references(artifact, drive, record.initial, dataset, measured)
        clean = _clean_estimates(refs, record.rows, record.initial)   # the clean run's estimate after each row
        # a faulted Measurements frame may have been refused by the target's alive-counter check, which the log's
        # host frames do not undergo: only the twin knows which measurements the filter got
        # and a calibration over XCP (a DOWNLOAD in the log) changed the target from that frame on: the twin replays
        # the logged XCP commands in their place, the clean references cannot
        use_twin = bool(lost_rows or (measured is not None and measurement_faults(record)) or record.xcp_downloads)
        if use_twin:
            final_ref, agreement = twin_agreement(artifact, record, xcp_elf)
        else:
            final_ref, agreement = restarted_agreement(artifact, record, clean)
    selection = kept_rows(record, final_ref, tolerance=AGREEMENT_TOLERANCE_C)   # the rows every figure is over
    kept = selection.kept
    answered = record.answered
    at_steps = refs.step_rows if len(refs.step_rows) else np.zeros(0, dtype=np.int64)
    can_at_steps = selection.values(record.temps[at_steps], at_steps)
    refs.can, refs.kept, refs.figure_rows = can_at_steps, kept, selection.counts
    if measured is not None:
        refs.sigma = sigma_at(record, at_steps)
    low, high = temperature_range()
    in_range = (refs.f32 >= low) & (refs.f32 <= high)
    saturated = int(np.count_nonzero(~in_range))
    refs.can_reference = final_ref[at_steps]
    with np.errstate(invalid="ignore", over="ignore"):
        f32_err = refs.f32 - refs.f64
        f64_finite = np.isfinite(refs.f64)
        outside = int(np.count_nonzero(f64_finite & ((refs.f64 < low) | (refs.f64 > high))))
        relative = np.abs(f32_err) / np.maximum(1.0, np.abs(refs.f64))
    both_finite = f64_finite & np.isfinite(refs.f32)
    max_rel = float(relative[both_finite].max()) if both_finite.any() else None
    nulls: dict[str, str] = {}      # metric -> why it is null (JSON and the report hold no inf or NaN)
    non_finite = NonFinite(float32=int(np.count_nonzero(~np.isfinite(refs.f32))),
                           float64=int(np.count_nonzero(~np.isfinite(refs.f64))))
    rmse, rmse_vs, max_error = {}, {}, {}
    rmse_f64 = {name: _rmse(can_at_steps[:, i], refs.f64[:, i]) for i, name in enumerate(TEMPERATURES)}
    max_error_f64 = {name: _max_error(can_at_steps[:, i], refs.f64[:, i]) for i, name in enumerate(TEMPERATURES)}
    for i, name in enumerate(TEMPERATURES):
        measured = {"winding": refs.measured_winding, "magnet": refs.measured_pm}.get(name)
        if measured is not None:
            rmse[name] = _rmse(can_at_steps[:, i], measured)
            max_error[name] = _max_error(can_at_steps[:, i], measured)
            rmse_vs[name] = "measured"
        else:
            rmse[name], max_error[name] = rmse_f64[name], max_error_f64[name]
            rmse_vs[name] = "float64 model"
    model_rmse = {}
    if refs.measured_winding is not None:
        for label, traj in (("float64", refs.f64), ("float32", refs.f32)):
            model_rmse[label] = MeasuredRmse(winding=_rmse(traj[:, 1], refs.measured_winding),
                                             magnet=_rmse(traj[:, 3], refs.measured_pm))
    rtt_us = (record.replied_s - record.sent_s)[kept] * 1e6
    span = (np.nanmax(record.replied_s) - record.sent_s[0]) if answered.any() else float("nan")
    status_gaps = np.diff(record.status_s) if len(record.status_s) > 1 else np.zeros(0)
    timing = record.timing
    info = record.target_info
    firmware = ran_firmware(record)
    estimate = memory_estimate(artifact)
    max_agree = NodeValues(*(None if np.isnan(agreement["max_abs"][i]) else float(agreement["max_abs"][i])
                             for i in range(len(TEMPERATURES))))
    results = RunResults(
        model=ModelInfo(id=f"{artifact.model_id:08x}", kind=artifact.kind, realization=artifact.realization,
                        dt_s=artifact.dt, loss_model=artifact.loss_model,
                        log_model_id=f"{record.model_id:08x}" if record.model_id is not None else None),
        counts=Replies(steps_sent=record.rows, replies=int(np.count_nonzero(answered)),
                       missing=int(record.rows - np.count_nonzero(answered)), sequence_gaps=gap_count(answered),
                       model_steps=int(len(refs.step_rows))),
        agreement=Agreement(
            max_abs_can_minus_float32_C=max_agree,
            can_agrees_with_float32=all(v is None or v <= AGREEMENT_TOLERANCE_C for v in max_agree.values()),
            replies_compared=agreement["compared"], can_reference="target twin" if use_twin else "offline float32",
            rows_lost_on_the_bus=lost_rows, max_abs_can_minus_clean_C=_deviation(record, clean, selection),
            segments=len(record.segments), saturated_values=saturated,
            xcp_downloads_unlike_target=agreement.get("downloads_unlike_target", 0)),
        accuracy=Accuracy(
            max_abs_float32_minus_float64_C=NodeValues(*(
                _max_abs_finite(f32_err[:, i], f"max_abs_float32_minus_float64_C.{name}", nulls)
                for i, name in enumerate(TEMPERATURES))),
            non_finite_values=non_finite, rmse_C=NodeValues(**rmse), rmse_reference=NodeLabels(**rmse_vs),
            model_rmse_vs_measured_C=model_rmse, float64_outside_dbc_range=outside,
            max_rel_float32_minus_float64=max_rel, max_abs_error_C=NodeValues(**max_error),
            rmse_vs_float64_C=NodeValues(**rmse_f64), max_abs_error_vs_float64_C=NodeValues(**max_error_f64)),
        timing=Timing(
            step_time_us=Percentiles(**percentiles(timing.get("measured_us", []))),
            overruns=int(_top(timing.get("overruns")) or 0), est_cycles=_top(timing.get("cycles"), int),
            est_exec_time_us=_top(timing.get("exec_us")), cpu_load_percent=_top(timing.get("cpu_load")),
            # the firmware engine's measured Cortex-M4F figures (Timing4), beside the C28x estimate above
            engine="firmware" if firmware else "python", m4_cycles=cycle_figures(timing.get("m4_cycles")),
            m4_exec_time_us=cycle_figures(timing.get("m4_exec_us"), as_int=False), m4_clock_mhz=M4_CLOCK_HZ / 1e6,
            response_time_us=_response_time(timing.get("response_us")), isr_load_percent=_mean(timing.get("isr_load"))),
        # TargetInfo's flash and RAM: the ELF's measured figures with the firmware engine, else the C28x estimate
        memory=Memory(flash_bytes=info.get("flash_bytes"), ram_bytes=info.get("ram_bytes"),
                      memory_source="firmware ELF" if firmware else "C28x estimate",
                      est_flash_bytes=estimate.flash_bytes, est_ram_bytes=estimate.ram_bytes),
        throughput=Throughput(
            round_trip_us=Percentiles(**percentiles(rtt_us)), wall_time_s=float(span) if np.isfinite(span) else None,
            throughput_steps_per_s=float(record.rows / span) if np.isfinite(span) and span > 0 else None,
            throughput_model_steps_per_s=float(len(refs.step_rows) / span) if np.isfinite(span) and span > 0
            else None),
        integrity=Integrity(
            heartbeat=Heartbeat(frames=int(len(record.status_s)),
                                max_gap_s=float(status_gaps.max()) if status_gaps.size else None,
                                losses=int(np.count_nonzero(status_gaps > HEARTBEAT_TIMEOUT_S))),
            target_rx_errors=record.rx_errors, invalid_frames_in_log=record.invalid,
            # the target's frames the host's checks reject, by message: none of their values is used
            rejected_target_frames=record.rejected,
            # frames that pass those checks but are not of this session (a replayed or forged frame), by reason
            foreign_frames=record.foreign, contested_rows=int(np.count_nonzero(record.contested)),
            target_faults_seen=_fault_names(record.faults_seen), frames_in_log=record.frames,
            log_complete=record.complete, log_stopped=record.stopped, log_unclosed=record.unclosed,
            last_row=record.rows - 1, log=str(record.path), rejected_host_frames=record.rejected_host,
            restores_not_from_target=[[s.start_row, s.checkpoint] for s in record.segments
                                      if s.checkpoint is not None]),
        faults=fault_metrics(record),
        bus_load=bus_load(record, record.frame_data, artifact.data_sample_period, bitrate),
        figure_rows=selection.counts,
        observer=observer_results(record, artifact, refs),
        data=data_identity(dataset, record.rows))
    results.notes = notes(results)
    return finite_results(results, nulls), refs


def data_identity(dataset, rows: int) -> DataIdentity | None:
    """Which data the log replayed: the dataset's first `rows` rows (None without a dataset)."""
    return None if dataset is None else DataIdentity(rows=int(rows), sha256=dataset.rows_sha256(rows))


def _response_time(values) -> Percentiles | None:
    """p50/p99/max of the model steps' response times (Timing5), None without them."""
    return Percentiles(**percentiles(values)) if values is not None and len(values) else None


def _mean(values) -> float | None:
    return round(float(np.mean(values)), 3) if values is not None and len(values) else None


def _top(values, kind=float):
    """The largest of a per-step timing series, None when there is none."""
    return kind(values.max()) if values is not None and values.size else None


def _max_abs_finite(a: np.ndarray, where: str, nulls: dict[str, str]) -> float | None:
    """max |a|, or None with the reason in `nulls` when some of `a` is not finite (a model that overflowed)."""
    bad = int(np.count_nonzero(~np.isfinite(a)))
    if bad:
        nulls[where] = f"{bad} of its {a.size} values are not finite (the model overflowed)"
        return None
    return _max_abs(a)


def _deviation(record: BusRecord, clean: np.ndarray, selection: RowSelection) -> NodeValues:
    """Per temperature, the largest |CAN - the clean run's float32 estimate| over the kept rows: zero unless
    faults changed what the model saw (rows lost in real time)."""
    with np.errstate(invalid="ignore", over="ignore"):
        diff = np.abs(selection.values(record.temps) - clean)
    return NodeValues(*(_max_abs(diff[:, i]) for i in range(len(TEMPERATURES))))


def fault_metrics(record: BusRecord) -> FaultResults | None:
    """Faults marked in the log (BenchEvent), gaps and restarts, and detection from the sidecar; None if none.

    The target's reply faults are not marked in the log (the host learns of them only by detecting them): their
    counts come from the sidecar, which has them from the target's journal."""
    from host.faults import DETECTION, KINDS, REPLY_KINDS, fault_problems, read_sidecar

    sidecar = read_sidecar(record.path)
    if not record.marks and sidecar is None:
        return None
    marked: dict[str, int] = {}
    for mark in record.marks:
        if mark.event == "fault" and mark.fault:
            marked[mark.fault] = marked.get(mark.fault, 0) + 1
    for kind in REPLY_KINDS:
        if sidecar and sidecar.get("injected", {}).get(kind):
            marked[kind] = int(sidecar["injected"][kind])
    kinds = [k for k in KINDS if marked.get(k) or (sidecar and sidecar.get("injected", {}).get(k) is not None)]
    gaps = []
    for gap in record.gaps:
        duration = (gap["reinit_s"] - gap["lost_s"]) if gap["reinit_s"] is not None else None
        gaps.append(FaultGap(rows=list(gap["rows"]), lost_row=gap["lost_row"], restart_row=gap["restart_row"],
                             duration_s=None if duration is None else round(duration, 3),
                             start_s=gap["lost_s"] - (record.frame_s[0] if record.frames else 0.0)))
    side = sidecar or {}
    return FaultResults(
        injected={k: marked.get(k, 0) for k in kinds},
        injected_total=sum(marked.values()),
        detected=None if sidecar is None else {k: side.get("detected", {}).get(k) for k in kinds},
        undetected=side.get("undetected"),
        detection={k: DETECTION[k] for k in kinds},
        sidecar_injected_total=side.get("injected_total"),
        retransmitted_rows=sum(1 for m in record.marks if m.event == "retransmit"),
        gaps=gaps,
        reinitializations=sum(1 for s in record.segments if s.recovery),
        unexplained_deadline_misses=side.get("unexplained_deadline_misses"),
        unexplained_deadline_miss_rows=side.get("unexplained_deadline_miss_rows", []),
        seed=side.get("seed"),
        mode=None if sidecar is None else side.get("mode", "lockstep"),
        # what the run's own fault summary does not explain (undetected faults, late replies, refused frames, ...)
        sidecar_problems=None if sidecar is None else fault_problems(sidecar),
        sidecar=None if sidecar is None else str(record.path.with_name(record.path.name + ".faults.json")),
        late_replies=side.get("late_replies"))


def _fault_names(bits: int) -> list[str]:
    from dbc import FaultBit
    return [bit.name for bit in FaultBit if bit & bits]


def cycle_figures(values, *, as_int: bool = True) -> CycleFigures | None:
    """{p50, max} of per-step figures (Timing4), None when there are none (the Python engine sends none)."""
    if values is None or len(values) == 0:
        return None
    arr = np.asarray(values, dtype=float)
    p50, top = float(np.percentile(arr, 50)), float(arr.max())
    return CycleFigures(int(round(p50)), int(top)) if as_int else CycleFigures(round(p50, 1), top)
