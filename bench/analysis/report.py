"""The bench report: a Markdown page with the metric table, linking PNG figures, built from a bus log.

`analyze_log` is what `bench run` (after its run) and `bench analyze LOG` (on any log of ours) both call, so the
two reports are the same for the same log.

The report directory is written at once: the figures are rendered into memory, then report.md, metrics.json and
the PNGs go into a temporary directory beside it that is renamed into place (`bench.fileio.
write_directory_atomically`). A full disk or a Ctrl-C leaves the earlier report as it was, never a new figure
beside an old report.md; the sentence names the file that could not be written. A directory holding anything
else than an earlier report is not replaced (one sentence).
"""

from __future__ import annotations

import gc
import io
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from bench.analysis import plots
from bench.analysis.canmetrics import TEMPERATURES, compute
from bench.analysis.logdecode import BusRecord, decode_log
from bench.analysis.results import Acceptance, FaultResults, RunResults
from bench.analysis.verdict import counts_text, problems
from bench.errors import BenchError
from bench.fileio import foreign_entries, write_directory_atomically
from target_sim.artifact import ModelArtifact

FIGURES = {"temperatures": "temperatures.png", "float32_error": "float32_error.png",
           "step_time": "step_time.png", "bus_load": "bus_load.png"}
REPORT_FILES = ("report.md", "metrics.json", *FIGURES.values())
# what a report directory may hold to be replaced: a report's files, and the temporary figure files an earlier
# version left when it was killed while drawing
REPLACEABLE = frozenset(REPORT_FILES) | {f".{Path(name).stem}.partial.png" for name in FIGURES.values()}


def check_report_dir(report_dir: Path, option: str = "--report") -> None:
    """BenchError (one sentence) when `report_dir` holds anything but an earlier report: it would not be replaced."""
    try:
        foreign = foreign_entries(Path(report_dir), REPLACEABLE)
    except OSError as exc:
        raise BenchError(f"cannot read {option} {report_dir} ({exc.strerror or exc}); choose another {option}"
                         ) from None
    if foreign:
        shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise BenchError(f"{option} {report_dir} holds {shown}, which is not a report this bench wrote; choose an "
                         f"empty or new directory for {option}")


def analyze_log(log_path: str | Path, artifact: ModelArtifact, dataset=None, *, report_dir: str | Path | None = None,
                bitrate: int | None = None, run_info: dict | None = None,
                extra_problems: list[str] | None = None, gate=None,
                xcp_elf: str | Path | None = None) -> tuple[RunResults, list[str]]:
    """Decode the log, compute the metrics against the references, write the report if `report_dir`.

    `extra_problems` (what the live run saw, e.g. the host's) are listed in the report too; `gate` (a
    `bench.acceptance.criteria.Gate`) judges the acceptance criteria, which go into the results and the report;
    `xcp_elf` lays out the twin that replays the log's XCP calibrations (`canmetrics.compute`)."""
    record = decode_log(log_path)
    results, refs = compute(record, artifact, dataset, **({"bitrate": bitrate} if bitrate else {}), xcp_elf=xcp_elf)
    if gate is not None:
        results.acceptance = gate.judge(results)
    found = list(dict.fromkeys((extra_problems or []) + problems(results)))
    if report_dir is not None:
        report_path = write_report(Path(report_dir), results, found, record, refs, dataset, run_info or {})
        results.report = str(report_path)
    return results, found


def _m4_rows(m: RunResults) -> list[str]:
    """The measured Cortex-M4F cycles (firmware engine) and the flash/RAM rows: measured beside the estimate."""
    est = f"{_fmt(m.memory.est_flash_bytes)} B / {_fmt(m.memory.est_ram_bytes)} B"
    if m.timing.engine != "firmware":
        return ["| measured Cortex-M4F cycles | – (the Python engine; `--engine firmware` measures them) |",
                f"| flash / RAM, C28x estimate | {est} |"]
    cycles, exec_us, memory = m.timing.m4_cycles, m.timing.m4_exec_time_us, m.memory
    return [f"| measured Cortex-M4F cycles p50 / max (emulated firmware) / time at {m.timing.m4_clock_mhz:g} MHz | "
            f"{_fmt(cycles and cycles.p50)} / {_fmt(cycles and cycles.max)} / {_fmt(exec_us and exec_us.p50, 1)} µs |",
            f"| flash / RAM, Cortex-M4F ELF (measured) | {_fmt(memory.flash_bytes)} B / {_fmt(memory.ram_bytes)} B |",
            f"| flash / RAM, C28x estimate | {est} |", *_response_rows(m)]


def _response_rows(m: RunResults) -> list[str]:
    """The model step's response time and the interrupt's CPU load (firmware with the current loop's interrupt)."""
    response = m.timing.response_time_us
    if response is None:
        return []
    return [f"| model step response time p50 / p99 / max, beside the current loop's interrupt | "
            f"{_fmt(response.p50, 1)} / {_fmt(response.p99, 1)} / {_fmt(response.max, 1)} µs |",
            f"| current loop interrupt CPU load (measured by the firmware) | {_fmt(m.timing.isr_load_percent, 2)} % |"]


def _complete(m: RunResults) -> str:
    if m.integrity.log_complete:
        return "yes"
    return "no: the .blf was never closed" if m.integrity.log_unclosed else "no: no Control STOP after the last START"


def _listed(counts) -> str:
    return counts_text(counts) if counts else "none"


def _unused(m: RunResults, message: str) -> str:
    """' (n <message> frames failed the host's checks and are not used)' when some did: the values shown come only
    from the frames that passed them."""
    n = m.integrity.rejected_target_frames.get(message)
    return f" (from the {message} frames that pass the host's checks; {n} failed them and are not used)" if n else ""


def _fmt(value, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


class _Written(dict):
    """The report's files; remembers which one is being written (for the sentence when that fails)."""

    current: str | None = None

    def items(self) -> Iterator[tuple[str, bytes]]:  # type: ignore[override]
        for name, payload in super().items():
            self.current = name
            yield name, payload
        self.current = None


def _png(draw, *args) -> bytes:
    out = io.BytesIO()
    with np.errstate(over="ignore", invalid="ignore"):    # a model that left every range: drawn, not warned about
        draw(out, *args)
    gc.collect()      # a closed figure is a web of cycles: free it before the next one is drawn
    return out.getvalue()


def write_report(report_dir: Path, metrics: RunResults, found: list[str], record: BusRecord, refs, dataset,
                 run_info: dict) -> Path:
    """The report directory (report.md, metrics.json, the figures), written at once; BenchError (one sentence naming
    the file) when it cannot be, and then nothing of it was written."""
    report_dir = Path(report_dir)
    check_report_dir(report_dir)
    model = metrics.model
    title = f"{model.kind} ({model.realization}, Δt = {model.dt_s:g} s), model {model.id}"
    files = _Written()
    files[FIGURES["temperatures"]] = _png(plots.temperatures, record, refs, title)
    files[FIGURES["float32_error"]] = _png(plots.float32_error, record, refs)
    files[FIGURES["step_time"]] = _png(plots.step_time_histogram, record.timing.get("measured_us", []),
                                       metrics.timing.est_exec_time_us,
                                       metrics.timing.m4_exec_time_us and metrics.timing.m4_exec_time_us.p50)
    files[FIGURES["bus_load"]] = _png(plots.bus_load, metrics.bus_load)
    body = metrics.to_json(windows=False)
    files["metrics.json"] = (json.dumps(body, indent=1, allow_nan=False, default=str) + "\n").encode("utf-8")
    files["report.md"] = render_markdown(metrics, found, dataset, run_info).encode("utf-8")
    try:
        write_directory_atomically(report_dir, files, replaceable=REPLACEABLE)
    except OSError as exc:
        reason = exc.strerror or str(exc) or exc.__class__.__name__
        if files.current is not None:
            where = f"while writing {report_dir / files.current}"
        else:
            where = f"while putting the directory in place ({exc.filename})" if exc.filename else \
                "while putting the directory in place"
        raise BenchError(f"cannot write the report {report_dir} ({reason} {where}); nothing of it was written and "
                         "an earlier report there is unchanged; free some space or choose another --report") from None
    return report_dir / "report.md"


def fault_section(faults: FaultResults) -> list[str]:
    """Injected versus detected per kind, the marked gaps, retransmissions."""
    lines = ["## Injected faults", "",
             "Every injected fault is marked in the log by a BenchEvent frame (id 0x1FF); detection comes from the "
             f"sidecar {('`' + Path(faults.sidecar).name + '`') if faults.sidecar else '(missing)'}.", "",
             "| kind | injected | detected | detected by |", "|---|---|---|---|"]
    detected = faults.detected or {}
    for kind, count in faults.injected.items():
        lines.append(f"| {kind} | {count} | {_fmt(detected.get(kind))} | {faults.detection[kind]} |")
    late = (f" ({faults.late_replies} of them only late: answered at every send, within the heartbeat timeout)"
            if faults.late_replies else "")
    lines += ["", f"Rows sent again after their reply deadline: {faults.retransmitted_rows}{late}; re-initializations "
              f"of a lost target: {faults.reinitializations}.", ""]
    if faults.mode == "realtime":
        lines += ["Real time: nothing is sent again, so a faulted row stays lost (and the row after it, whose frame "
                  "shows the alive-counter jump, too); the target leaves the lost rows out of its interval means. "
                  "The CAN values are checked against the target's twin (its own code fed the logged frames), and "
                  "their departure from the clean run is what the faults cost the estimate.", ""]
    if faults.gaps:
        lines += ["| marked gap: rows | target lost at row | re-initialized at row | lasted (s) |", "|---|---|---|---|"]
        for gap in faults.gaps:
            first, last = gap.rows
            lines.append(f"| {first}–{last} | {gap.lost_row} | {_fmt(gap.restart_row)} | "
                         f"{_fmt(gap.duration_s, 2)} |")
        lines += ["", "In a gap the target was lost (killed, frozen or restarted); the host restored it from its "
                  "last StateCheckpoint (the float32 state vector after the gap's first row minus one, echoed back "
                  "bit for bit in RestoreState) and replayed the gap's rows again, so every row has a reply and "
                  "the restarted target continues exactly as an uninterrupted one. The CAN − float32 check "
                  "compares every reply with the float32 reference restarted the same way.", ""]
    return lines


def observer_section(obs) -> list[str]:
    """Open loop and observer side by side per node, the measured node named, the target's 1-sigma and innovations."""
    lines = ["## Observer", "",
             f"The model runs a Kalman observer on its linear block, measuring the **{obs.measured_node}** node (the "
             f"Measurements frame's {obs.slot} slot): its error there is not an estimate's, the filter is pulled "
             f"towards that measurement. {obs.rows_measured} rows carried a valid measurement; "
             f"{obs.model_steps_updated} of {obs.model_steps} model steps used one (the others predicted only).", "",
             "| | " + " | ".join(TEMPERATURES) + " |", "|---|---|---|---|---|",
             _row("RMSE open loop, offline float32 (°C)", obs.open_loop_rmse_C, 3),
             _row("RMSE observer, offline float32 (°C)", obs.observer_rmse_C, 3),
             _row("1-σ after the last step, target (°C)", obs.sigma_final_C, 3),
             _row("largest 1-σ, target (°C)", obs.sigma_max_C, 3), "",
             f"RMS of the innovations the target reported: {_fmt(obs.innovation_rms_C)} °C. The RMSEs are against "
             "the measured temperatures (– where the data has none).", ""]
    gated = [(slot, m) for slot, m in obs.measurements.items()
             if m.readings_rejected or m.sensor_flagged or m.gate_steps_differing]
    for slot, m in gated:      # the innovation gate: the target's flags on the bus, checked against its code offline
        flag = " — **the sensor was flagged**: its readings stayed rejected" if m.sensor_flagged else ""
        source = ("as the target reported on the bus" if m.gate_source == "bus" else
                  "by the target's float32 code offline (its DBC carries no gate flags)")
        check = (f" The bus agrees with the target's float32 code offline at all {m.gate_steps_compared} model steps "
                 "compared." if m.gate_steps_compared and not m.gate_steps_differing else
                 f" **The bus differs from the target's float32 code offline at {m.gate_steps_differing} of "
                 f"{m.gate_steps_compared} model steps** (offline: {m.readings_rejected_float32} rejected)."
                 if m.gate_steps_differing else "")
        lines += [f"The innovation gate rejected {m.readings_rejected} readings of {m.sensor} ({slot}) as too far "
                  f"from the prediction, {source}: those steps predicted only{flag}.{check}", ""]
    if len(obs.measurements) > 1:     # several measurements per row: each one's share
        lines += ["| measurement (slot) | node it sees | rows with a valid reading | model steps that used it | "
                  "innovation RMS (°C) |", "|---|---|---|---|---|"]
        lines += [f"| {slot} | {m.measured_node} | {m.rows_measured} | {m.model_steps_updated} | "
                  f"{_fmt(m.innovation_rms_C)} |" for slot, m in obs.measurements.items()]
        lines.append("")
    return lines


def _row(label: str, values, digits: int) -> str:
    return f"| {label} | " + " | ".join(_fmt(values.get(t), digits) for t in TEMPERATURES) + " |"


def render_markdown(metrics: RunResults, found: list[str], dataset, run_info: dict) -> str:
    m = metrics
    model = m.model
    lines = [f"# Bench report: {model.kind} ({model.realization}), model {model.id}", ""]
    faults = m.faults
    if found:
        verdict = "NOT clean"
    elif faults and faults.injected_total:
        verdict = (f"faults injected and survived: every step answered, CAN = offline float32 (restarted as the "
                   f"target was) within ±0.005 °C, {faults.injected_total} injected fault(s)"
                   + (", all detected" if faults.undetected == 0 else ""))
    else:
        verdict = "clean: every step answered, CAN = offline float32 within ±0.005 °C"
    lines += [f"**Result: {verdict}.**", ""]
    for problem in found:
        lines.append(f"- {problem}")
    for note in m.notes:
        lines.append(f"- **Note:** {note}")
    if found or m.notes:
        lines.append("")
    if m.acceptance is not None:
        lines += acceptance_section(m.acceptance)
    lines += ["| | |", "|---|---|"]
    log, timing, agreement, accuracy = m.integrity, m.timing, m.agreement, m.accuracy
    info = [("log", f"`{log.log}` ({log.frames_in_log} frames)"),
            ("data", f"`{dataset.path}`" if dataset is not None else "– (no measured reference given)"),
            ("model step Δt", f"{model.dt_s:g} s"),
            ("loss model", _loss_model_words(model.loss_model)),
            ("mode", run_info.get("mode", "–")),
            ("bus", run_info.get("bus", "–")),
            ("target engine", run_info.get("engine") or ("firmware (emulated Cortex-M4F)" if timing.engine ==
                                                          "firmware" else "python (float32 model)"))]
    if run_info.get("node_cycles"):      # the firmware node's own statistics (the target's --stats)
        info.append(("firmware node Cortex-M4F cycles, model steps excluded (p50 / max)", run_info["node_cycles"]))
    lines += [f"| {k} | {v} |" for k, v in info]
    lines += ["", "## Metrics", "", "| metric | " + " | ".join(TEMPERATURES) + " |", "|---|---|---|---|---|"]
    reference = "target twin" if agreement.can_reference == "target twin" else "offline float32"
    lines.append(_row(f"max \\|CAN − {reference}\\| (°C)", agreement.max_abs_can_minus_float32_C, 4))
    if agreement.rows_lost_on_the_bus:  # faults in real time: what the lost rows cost the estimate
        lines.append(_row("max \\|CAN − clean run\\| (°C)", agreement.max_abs_can_minus_clean_C, 4))
    lines.append(_row("max \\|float32 − float64\\| (°C)", accuracy.max_abs_float32_minus_float64_C, 4))
    lines.append(_row("RMSE of the CAN values (°C)", accuracy.rmse_C, 3))
    lines.append(f"| ... over | {m.figure_rows.text('the RMSE and every figure')} | | | |")
    lines.append("| ... against | " + " | ".join(accuracy.rmse_reference.get(t) for t in TEMPERATURES) + " |")
    for label, values in accuracy.model_rmse_vs_measured_C.items():
        lines.append(f"| RMSE offline {label} vs measured (°C) | – | {_fmt(values.winding)} | – | "
                     f"{_fmt(values.magnet)} |")
    st, rtt, counts = timing.step_time_us, m.throughput.round_trip_us, m.counts
    load, heartbeat, throughput = m.bus_load, log.heartbeat, m.throughput
    lines += ["", "| | |", "|---|---|",
              f"| steps sent / answered / missing / gaps | {counts.steps_sent} / {counts.replies} / "
              f"{counts.missing} / {counts.sequence_gaps} |",
              f"| model steps | {counts.model_steps} (values outside the DBC range, clamped: "
              f"{agreement.saturated_values}) |",
              f"| measured step time p50 / p99 / max (µs, target process) | {_fmt(st.p50, 1)} / "
              f"{_fmt(st.p99, 1)} / {_fmt(st.max, 1)} |",
              f"| estimated C28x cycles / time at 90 MHz / CPU load | {_fmt(timing.est_cycles)} / "
              f"{_fmt(timing.est_exec_time_us, 1)} µs / {_fmt(timing.cpu_load_percent, 4)} % |",
              *_m4_rows(m),
              f"| overruns (step time > Δt) | {timing.overruns} |",
              f"| round trip p50 / p99 / max (µs) | {_fmt(rtt.p50, 0)} / {_fmt(rtt.p99, 0)} / "
              f"{_fmt(rtt.max, 0)} |",
              f"| throughput | {_fmt(throughput.throughput_steps_per_s, 0)} steps/s "
              f"({_fmt(throughput.throughput_model_steps_per_s, 0)} model steps/s) over "
              f"{_fmt(throughput.wall_time_s, 2)} s |",
              f"| bus load at {load.bitrate / 1000:g} kbit/s | {_fmt(load.data_rate_percent, 2)} % at the "
              f"data rate; this replay peaked at {_fmt(load.replay_peak_percent, 0)} % "
              f"(mean frame {_fmt(load.bits_per_frame_mean, 1)} bits incl. stuffing) |",
              f"| heartbeat | {heartbeat.frames} Status frames, longest gap "
              f"{_fmt(heartbeat.max_gap_s, 3)} s, {heartbeat.losses} losses |",
              f"| target receive errors | {log.target_rx_errors or '–'}{_unused(m, 'RxErrors')} |",
              f"| invalid frames in the log (rejected by the host's checks: id, length, CRC, range, alive counter) | "
              f"{_listed(log.invalid_frames_in_log)} |",
              f"| ... of them the target's, by message (none of their values is used) | "
              f"{_listed(log.rejected_target_frames)} |",
              f"| ... of them the host's measurement frames the target's checks refuse (their readings unused) | "
              f"{_listed(log.rejected_host_frames)} |",
              f"| restores not from a checkpoint the target sent (start row, why) | "
              f"{', '.join(f'{row} {why}' for row, why in log.restores_not_from_target) or 'none'} |",
              f"| frames that pass those checks but are not of this session (not used) | "
              f"{_listed(log.foreign_frames)} |",
              f"| rows with two different replies (not reported) | {log.contested_rows} |",
              f"| rows left out of every figure (a check flagged their answer) | "
              f"{_listed(m.figure_rows.excluded)} |",
              f"| target faults seen | {', '.join(log.target_faults_seen) or 'none'}{_unused(m, 'Status')} |",
              f"| log complete (the host's STOP, the file closed) | {_complete(m)} |",
              ""]
    if m.null_values:
        lines += ["Values shown as – because they are not finite numbers (JSON holds them as null):", ""]
        lines += [f"- `{where}`: {why}" for where, why in m.null_values.items()]
        lines.append("")
    if faults:
        lines += fault_section(faults)
    if m.observer is not None:
        lines += observer_section(m.observer)
    lines += ["## Figures", "",
              "Temperatures: CAN values (the target's float32 estimate as transmitted), the measured reference "
              "(winding and PM), and the offline float64 and float32 models on the same decoded inputs.", "",
              f"![temperatures]({FIGURES['temperatures']})", "",
              "float32 − float64: what single precision costs (a diverging realization shows here, like the "
              "paper's Fig. 6); CAN − float32: the transport (0.01 °C quantization, dotted ±0.005 °C).", "",
              f"![float32 error]({FIGURES['float32_error']})", "",
              f"![step time]({FIGURES['step_time']})", "",
              f"![bus load]({FIGURES['bus_load']})", ""]
    lines += ["## How the numbers are made", "",
              "Inputs of model step k are the float32 mean of the 5 Hz samples in [kΔt, (k+1)Δt); the step runs "
              "when the last sample of the interval arrives, and every data row is answered with the latest "
              "estimate. References are fed with the drive values as decoded from the frames the host sent. "
              "Estimated C28x cycles come from the per-operation cost table in `target_sim/costs.py`; measured "
              "Cortex-M4F cycles (firmware engine) are counted per executed basic block in the emulated core from "
              "the Cortex-M4 TRM timings (`target_sim/firmware/cycles.py`), and its flash and RAM are the ELF's.", ""]
    return "\n".join(lines)


def acceptance_section(acceptance: Acceptance) -> list[str]:
    """The acceptance criteria (--criteria, --baseline): each check's figure, limit and verdict."""
    head = "met" if acceptance.passed else f"{len(acceptance.failed)} of {len(acceptance.checks)} failed"
    source = f" (`{acceptance.criteria}`" + (f", baseline `{acceptance.baseline}`" if acceptance.baseline else "") + ")"
    lines = [f"## Acceptance criteria: {head}", "", f"Criteria{source if acceptance.criteria else ''}:"
             + ("" if acceptance.criteria else f" the default regression gate against `{acceptance.baseline}`"), "",
             "| criterion | figure | limit | verdict |", "|---|---|---|---|"]
    for c in acceptance.checks:
        figure = "–" if c.figure is None else f"{c.figure:.4g} {c.unit}".rstrip()
        note = f" ({c.source})" if c.source else ""
        lines.append(f"| {c.name}: {c.what}{note} | {figure} | {c.limit:g} {c.unit} | "
                     f"{'pass' if c.passed else '**FAIL**'} |")
    failed = [f"- {c.message}" for c in acceptance.failed]
    return lines + [""] + (failed + [""] if failed else [])


def _loss_model_words(name: str | None) -> str:
    """The run's loss model as its kind describes itself (`bench.motor.losskinds`)."""
    from bench.motor.losskinds import LAB_LOSS_KINDS

    return f"{name}: {LAB_LOSS_KINDS[name].summary}" if name in LAB_LOSS_KINDS else str(name)
