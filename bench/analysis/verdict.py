"""The pass/fail rules of a run or a log: its problems (one sentence each), the notes about the model a report must
not hide, and the `Verdict` (problems and exit status) that `bench run`, `bench analyze` and `bench host` share."""

from __future__ import annotations

import sys
from dataclasses import dataclass

from bench.analysis.results import RunResults
from dbc.database import temperature_range

QUANTIZATION_C = 0.005          # half the 0.01 °C resolution of the temperature signals
DIVERGENCE_NOTE_C = 1.0


def counts_text(counts: dict[str, int]) -> str:
    """'kind n, kind n' of a dict of counts."""
    return ", ".join(f"{k} {v}" for k, v in counts.items())


def fault_note(results: RunResults) -> str | None:
    """'N faults are marked in the log ...': what makes a faulted log non-zero without --tolerate-faults."""
    from host.faults import fault_note as note

    faults = results.faults.as_note_input() if results.faults is not None else None
    return note(faults, what="injected fault(s) are marked in the log")


def notes(results: RunResults) -> list[str]:
    """Facts about the model (not faults of the run) the report must not hide. Single precision is blamed only when
    float64 stays finite and inside the DBC range where float32 does not; a model whose float64 values overflow or
    leave the range as well is said to do so, with what float32 did beside it."""
    accuracy = results.accuracy
    worst = accuracy.max_abs_float32_minus_float64_C.worst() or 0.0
    realization = results.model.realization
    non_finite, outside = accuracy.non_finite_values, accuracy.float64_outside_dbc_range
    if non_finite.float64:
        return [f"the model overflows in float64 as well as in float32 ({non_finite.float64} float64 and "
                f"{non_finite.float32} float32 values are not finite): its estimate leaves every range whatever the "
                "precision, so single precision is not the cause"]
    if outside and (non_finite.float32 or worst > DIVERGENCE_NOTE_C):
        low, high = temperature_range()
        relative = accuracy.max_rel_float32_minus_float64
        float32 = (f"float32 overflows at {non_finite.float32} values, where float64 passes float32's range"
                   if non_finite.float32 else
                   f"float32 departs from it by up to {worst:.4g} °C, a relative {relative:.1g} of such values")
        return [f"the model's estimate leaves the DBC range ({low:g}..{high:g} °C) in float64 as well ({outside} "
                f"float64 values): {float32}, so single precision is not the cause"]
    if non_finite.float32:
        return [f"the float32 model overflows ({non_finite.float32} values are not finite) where float64 stays finite "
                f"and in range: the {realization} realization does not survive single precision"]
    if worst > DIVERGENCE_NOTE_C:
        return [f"the float32 model departs from float64 by up to {worst:.4g} °C: the "
                f"{realization} realization does not survive single precision"]
    return []


def problems(results: RunResults) -> list[str]:
    """Reasons the run is not clean, one sentence each.

    Of a log with injected faults (BenchEvent marks), what the faults explain is not listed: the target's
    rejections, and as many heartbeat losses as kills and freezes; an undetected fault is (see `fault_note` for
    the sentence that faults were injected at all)."""
    out = []
    faults = results.faults
    injected = faults.injected_total if faults else 0
    process = sum(faults.injected.get(k, 0) for k in ("kill", "freeze")) if faults else 0
    # in real time a faulted row stays unanswered: the sidecar judges those (unexplained deadline misses)
    explained = faults is not None and faults.mode == "realtime" and faults.unexplained_deadline_misses == 0
    counts, heartbeat = results.counts, results.integrity.heartbeat
    if counts.missing and not explained:
        out.append(f"{counts.missing} of {counts.steps_sent} steps got no reply ({counts.sequence_gaps} gaps)")
    if heartbeat.losses > process:
        extra = " more than the injected kills and freezes explain" if process else ""
        out.append(f"the target's heartbeat was lost {heartbeat.losses - process} time(s){extra}")
    if faults and faults.sidecar_problems:  # the same sentences the run gave (`host.faults.fault_problems`)
        out += faults.sidecar_problems
    agreement = results.agreement
    if not agreement.can_agrees_with_float32:
        worst = agreement.max_abs_can_minus_float32_C.worst()
        off = results.figure_rows.excluded.get("off_reference", 0)
        left_out = f" at {off} rows, which are left out of every figure" if off else ""
        out.append(f"CAN temperatures differ from the offline float32 reference by up to {worst:.4f} °C "
                   f"(more than the {QUANTIZATION_C} °C quantization){left_out}")
    if agreement.xcp_downloads_unlike_target:
        out.append(f"the target's twin answered {agreement.xcp_downloads_unlike_target} of the log's XCP DOWNLOADs "
                   "otherwise than the target (accepted a calibration it refused, or refused one it accepted): the "
                   "twin's cells are not at the target's addresses (give bench analyze the target's ELF, --xcp-elf) "
                   "or the target's XCP slave is not its reference's")
    bad = {k: v for k, v in results.integrity.target_rx_errors.items() if v}
    if bad and not injected:
        out.append(f"the target rejected or could not sequence frames: {bad}")
    return out + gate_problems(results) + integrity_problems(results, injected=bool(injected))


def gate_problems(results: RunResults) -> list[str]:
    """A sensor the observer's innovation gate flagged (its readings rejected many times in a row): one sentence
    naming it, with its rejected readings; and a gate on the bus that is not the target's float32 code's."""
    observer = results.observer
    if observer is None:
        return []
    flagged = [f"the observer's innovation gate flagged the sensor {m.sensor} ({slot}): {m.readings_rejected} of "
               f"its readings were rejected as too far from the model's prediction, so its estimate ran open loop "
               "there (a sensor that lies or fails, or a model that no longer fits)"
               for slot, m in observer.measurements.items() if m.sensor_flagged]
    differing = [f"the target's innovation gate for {m.sensor} ({slot}) on the bus differs from its float32 code "
                 f"offline at {m.gate_steps_differing} of {m.gate_steps_compared} model steps (bus: "
                 f"{m.readings_rejected} readings rejected{', flagged' if m.sensor_flagged else ''}; offline: "
                 f"{m.readings_rejected_float32}{', flagged' if m.sensor_flagged_float32 else ''})"
                 for slot, m in observer.measurements.items() if m.gate_steps_differing]
    return flagged + differing


def integrity_problems(results: RunResults, *, injected: bool = False) -> list[str]:
    """What makes a log's numbers untrustworthy whatever the faults: an incomplete log, values the target could not
    carry (clamped, not finite), frames that are not of this session, and (without injected faults, which explain
    them) frames of the target that the host's checks reject."""
    from host.results import clamped_problem

    log = results.integrity
    out = []
    if not log.log_complete:
        why = ("its .blf was never closed by its writer" if log.log_unclosed else
               "it ends without the host's Control STOP")
        out.append(f"the log is incomplete ({why}: a run that was killed, or a partial file); its last row is "
                   f"{log.last_row} and what came after it is missing")
    saturated, non_finite = results.agreement.saturated_values, results.accuracy.non_finite_values
    if saturated:
        out.append(f"{saturated} float32 values of the model lay outside the DBC range (-50..600 °C) or were not "
                   "finite, so the target clamped them (SATURATED): the CAN temperatures there are not the model's")
    if non_finite.float32 or non_finite.float64:
        out.append(f"the model's estimate is not finite at {non_finite.float32} float32 and "
                   f"{non_finite.float64} float64 values (it overflowed): those figures are null")
    clamped = clamped_problem(log.target_faults_seen)
    if clamped:
        out.append(clamped)
    if log.foreign_frames:
        out.append(f"{sum(log.foreign_frames.values())} frames in the log pass the host's checks but are not of "
                   f"this session ({counts_text(log.foreign_frames)}); none of them is used")
    if log.contested_rows:
        out.append(f"{log.contested_rows} rows got a second reply with other temperatures (a replayed or "
                   "forged frame): their temperatures are not reported")
    replayed = results.figure_rows.excluded.get("replayed", 0)
    if replayed:
        out.append(f"{replayed} rows got, in a frame the host's counter check rejected, other temperatures than the "
                   "answer used (a replayed frame): they are left out of every figure")
    for start, why in log.restores_not_from_target:
        restored = results.figure_rows.excluded.get("restored_not_from_target", 0)
        what = ("a state the target never sent (a forged StateCheckpoint or ObserverCheckpoint)" if why == "forged"
                else "a checkpoint one of whose frames was contested (a forged or replayed frame)")
        out.append(f"the target was restored at row {start} from {what}: its estimate from there is not the "
                   f"target's own, and its {restored} answered rows are left out of every figure")
    if log.rejected_host_frames and not injected:
        out.append(f"the target's checks refuse {sum(log.rejected_host_frames.values())} of the host's measurement "
                   f"frames in the log ({counts_text(log.rejected_host_frames)}: a replayed, repeated or lost "
                   "frame breaks their alive counter): their readings were not used, by the target nor here")
    if log.rejected_target_frames and not injected:
        out.append(f"the host's checks reject {sum(log.rejected_target_frames.values())} frames of the target in the "
                   f"log ({counts_text(log.invalid_frames_in_log)}; {counts_text(log.rejected_target_frames)}): "
                   "none of their values is used")
    return out


@dataclass(frozen=True)
class Verdict:
    """Whether a run, or the log of one, passes: the problems to report and the exit status."""

    problems: list[str]
    status: int

    def exit_status(self, subject: str, as_json: bool) -> int:
        """The status, after one sentence on stderr when it fails (with --json the problems are in the JSON)."""
        if self.status and not as_json:
            print(f"bench: error: {subject} is not clean: " + "; ".join(self.problems), file=sys.stderr)
        return self.status


def verdict(problems: list[str], fault_note: str | None, *, faulted: bool, tolerate_faults: bool,
            tolerate_gaps: bool = False) -> Verdict:
    """The rule of `bench run`, `bench analyze` and `bench host`: every problem fails (status 1); injected faults
    are one (`fault_note`, the sentence that says so) unless tolerated; --tolerate-gaps forgives only a run without
    faults, so an undetected fault, or anything the faults do not explain, always fails."""
    found = list(dict.fromkeys(problems))
    if fault_note and not tolerate_faults:
        found.append(fault_note)
    return Verdict(found, 1 if found and (faulted or not tolerate_gaps) else 0)
