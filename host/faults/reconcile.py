"""Injected versus detected: match every injected fault with the receiver's record of it.

"Detected" means, per kind, that the side receiving the fault recorded exactly that fault:

| kind | detected by | evidence |
|---|---|---|
| corrupt | target | a `crc` rejection of the very bytes that went out |
| wrong_length | target | a `wrong_length` rejection of the very (short) frame |
| unknown_id | target | an `unknown_id` rejection of the frame on its foreign id |
| out_of_range | target | an `out_of_range` rejection of the very frame |
| stale_counter | target | a `counter` rejection of the very frame (repeated counter) |
| duplicate | target | a `counter` rejection of the second copy (repeated counter) |
| drop | target | a `counter` rejection of the witness: the next frame of the same id, whose counter jumps |
| reorder | target | a `sequence` error on the DriveTemps that came before its DriveInputs |
| delay | host | the row's reply deadline passed (deadline miss) |
| kill, freeze | host | after the fault the target was declared lost (no Status for longer than the heartbeat |
| | | timeout, or a Status not RUNNING) and re-initialized |
| reply_* | host | the host validator's rejection of the very frame the target sent (as for the target's kinds: |
| | | crc, wrong_length, unknown_id, out_of_range, counter; a dropped reply by its witness's counter jump) |

The target's records come from its detection journal (`python -m target_sim --events FILE`, one JSON line per
rejected frame or sequence error, written as it happens, so a killed target's records survive and a restarted
one appends). Each record can confirm one injected fault. Records that confirm none are the faults'
consequences (a lost frame also leaves its row without a partner: sequence errors; a retransmission after a lost
frame jumps the counter), counted but not problems. The RxErrors counters the target broadcasts are the same
events counted per target process in 8 bits; after the run the host reads a last RxErrors (after STOP) and it
must equal the journal's counts of the last target process.

The target also journals the reply faults it injects ("inject" and "witness" records); the host keeps its own
validator's rejections (`HostSession.rejections`), which confirm them.

A deadline miss on a row without an injected fault, or a heartbeat loss beyond the number of kills and freezes,
is unexplained: a problem of the run, as is any fault that went undetected. A fault explains only a miss of its own
pass of the row (rows replayed after a re-initialization miss again in a new pass; the abandoned pass's misses are
judged before its replies are cleared). Except, in lockstep, a *late reply*: a
missed row that the target answered once for every time the host sent it (the first send and each retransmitted
copy), so its first send reached the target and nothing was lost, whose first reply came within the stall limit
(the heartbeat timeout). On a loaded machine the host and the target are both kept off the CPU now and then, for
50-220 ms at a load of 7-12 on two cores; such rows are counted (`late_replies`, `late_reply_max_ms`), not
problems. A frame lost without an injected fault (fewer replies than sends) and a stall (a first reply later than
the heartbeat timeout) stay unexplained.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from dbc.contract import RX_ERROR_KINDS, step_of
from dbc.files import write_atomically
from dbc.mutations import FRAME_FAULT_KINDS, REPLY_PREFIX
from host.errors import HostError, write_failure

from .bus import Injection
from .lockstep import FaultRun, RowPass
from .spec import KINDS, PROCESS_KINDS, REPLY_KINDS, TARGET_DETECTED

TARGET_EVIDENCE = {"drop": "counter", "duplicate": "counter", "stale_counter": "counter", "corrupt": "crc",
                   "wrong_length": "wrong_length", "unknown_id": "unknown_id", "out_of_range": "out_of_range",
                   "reorder": "sequence"}
DETECTION = {
    "drop": "target: alive-counter jump on the next frame of the same id",
    "delay": "host: the row's reply deadline passed",
    "duplicate": "target: repeated alive counter on the second copy",
    "reorder": "target: sequence error on the DriveTemps sent before its DriveInputs",
    "corrupt": "target: E2E CRC error on the corrupted frame",
    "stale_counter": "target: repeated alive counter on the stale frame",
    "wrong_length": "target: wrong-length rejection of the short frame",
    "unknown_id": "target: unknown-id rejection of the frame on a foreign id",
    "out_of_range": "target: out-of-range rejection of the frame",
    "kill": "host: heartbeat lost, target restarted and re-initialized",
    "freeze": "host: heartbeat lost, target re-initialized after it resumed",
    "reply_drop": "host: alive-counter jump on the next reply of the same id",
    "reply_duplicate": "host: repeated alive counter on the second copy",
    "reply_corrupt": "host: E2E CRC error on the corrupted reply",
    "reply_stale_counter": "host: repeated alive counter on the stale reply",
    "reply_wrong_length": "host: wrong-length rejection of the short reply",
    "reply_unknown_id": "host: unknown-id rejection of the reply on a foreign id",
    "reply_out_of_range": "host: out-of-range rejection of the reply",
}
assert set(DETECTION) == set(KINDS)
CATEGORIES = RX_ERROR_KINDS
SIDECAR_SUFFIX = ".faults.json"
# kinds after which the next frame of the same id carries an alive-counter jump (a copy repeats, it does not jump)
CHAINED = frozenset(prefix + k for k in FRAME_FAULT_KINDS if k != "duplicate" for prefix in ("", REPLY_PREFIX))
LISTED = 20


@dataclass
class Journal:
    """The target's detection records of one run, over every target process that served it."""

    entries: list[dict] = field(default_factory=list)
    instances: int = 0
    last_instance: Counter = field(default_factory=Counter)
    injections: list[Injection] = field(default_factory=list)   # the target's own (reply) injections


def read_journal(path: str | Path, since: float | None = None) -> Journal:
    """The records in a target's --events file (those stamped at or after `since`); a torn last line is skipped."""
    journal = Journal()
    waiting: dict = {}  # seq -> a drop whose witness record is still to come
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        return journal
    for line in text.splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if not isinstance(record, dict) or (since is not None and record.get("t", 0) < since):
            continue
        event = record.get("event")
        if event == "start":
            journal.instances += 1
            journal.last_instance = Counter()
            waiting = {}  # a restarted target numbers its injections anew
        elif event == "inject" and record.get("kind") in REPLY_KINDS:
            injection = Injection(record["kind"], int(record.get("step", -1)), 0, record.get("id"),
                                  record.get("sent_id"), record.get("counter"), record.get("data"),
                                  float(record.get("t", 0.0)))
            journal.injections.append(injection)
            waiting[record.get("seq")] = injection
        elif event == "witness" and record.get("seq") in waiting:
            waiting.pop(record["seq"]).witness = record.get("data")
        elif record.get("kind") in CATEGORIES:
            journal.entries.append(record)
            journal.last_instance[record["kind"]] += 1
    return journal


def chained_rows(injections: Iterable[Injection]) -> list[int]:
    """In real time, the row each fault costs besides its own: the one whose frame of the faulted id next carries
    the counter jump, which the receiver refuses. For a drive frame that is the next row; for a reply, the next row
    the target answered: rows whose drive frames a fault kept from the target get no reply, so the jump waits for
    the first row after them."""
    injections = list(injections)
    drive = [i for i in injections if i.kind in CHAINED and i.kind not in REPLY_KINDS]
    unanswered = {i.row for i in drive} | {i.row + 1 for i in drive}
    rows = []
    for injection in injections:
        if injection.kind not in CHAINED:
            continue
        row = injection.row + 1
        while injection.kind in REPLY_KINDS and row in unanswered:
            row += 1
        rows.append(row)
    return rows


def reply_passes(injections: Iterable[Injection], run: FaultRun) -> None:
    """Set the pass of each of the target's reply injections, which know their Step and time, not the pass: the
    newest pass of a row of that Step that the host had begun by then (`run.replayed_at`; none: the first).
    A target kept from running (freeze) answers the lost row's first send only when it resumes, possibly after the
    host began the new pass, but before that pass reaches the lost row (the target answers in order; unless the new
    pass begins at the lost row, when its fault may count for the new pass: that miss is the recovery's anyway)."""
    begun: dict[int, list[tuple[float, int]]] = {}
    for replay, t in run.replayed_at.items():
        begun.setdefault(step_of(replay.row), []).append((t, replay.pass_))
    for injection in injections:
        injection.pass_ = max(((t, p) for t, p in begun.get(injection.row, ()) if t <= injection.t),
                              default=(0.0, 0))[1]


def _key(kind: str, frame_id, data) -> tuple:
    return kind, int(frame_id) if frame_id is not None else None, data


def _confirm(injection: Injection, records: Counter, side: str) -> str | None:
    """Use up the receiver's record of this frame fault (from `records`); its category, or None if there is none."""
    kind = injection.kind.removeprefix(REPLY_PREFIX)
    category = TARGET_EVIDENCE[kind]
    data = injection.witness if kind == "drop" else injection.data
    key = _key(category, injection.frame_id if kind == "drop" else injection.sent_id, data)
    if data is None or records[key] <= 0:
        return None
    records[key] -= 1
    injection.detected, injection.detected_by = True, f"{side} {category}"
    return category


def reconcile(run: FaultRun, journal: Journal | None, *, heartbeat_losses: int = 0,
              final_rx_errors: dict | None = None, host_rejections: Iterable[dict] = ()) -> dict:
    """The fault summary of a run (JSON-ready); marks each injection's `detected`/`detected_by`.

    `run.injections` are the host's; the target's reply injections come from its journal and are confirmed by
    `host_rejections` (the host validator's records of the frames it refused)."""
    records = Counter(_key(e["kind"], e.get("id"), e.get("data")) for e in journal.entries) if journal else Counter()
    host_rejections = list(host_rejections)
    host_records = Counter(_key(r["kind"], r.get("id"), r.get("data")) for r in host_rejections)
    matched_categories: Counter = Counter()
    host_confirming: Counter = Counter()
    misses = Counter(run.deadline_misses)
    recoveries = sorted(run.recoveries, key=lambda r: r.lost_at)
    used_recoveries: set[int] = set()
    if journal is not None:
        reply_passes(journal.injections, run)
    injections = run.injections + (journal.injections if journal is not None else [])
    for injection in injections:
        injection.detected, injection.detected_by = False, None
        if injection.kind in TARGET_DETECTED:
            if journal is not None and (category := _confirm(injection, records, "target")) is not None:
                matched_categories[category] += 1
        elif injection.kind in REPLY_KINDS:
            if (category := _confirm(injection, host_records, "host")) is not None:
                host_confirming[category] += 1
        elif injection.kind == "delay":
            if misses[(here := RowPass(injection.row, injection.pass_))] > 0:
                misses[here] -= 1
                injection.detected, injection.detected_by = True, "host deadline miss"
        elif injection.kind in PROCESS_KINDS:
            for i, recovery in enumerate(recoveries):
                if i not in used_recoveries and recovery.lost_at >= injection.t and recovery.lost_row >= injection.row:
                    used_recoveries.add(i)
                    injection.detected, injection.detected_by = True, f"host: {recovery.reason}"
                    break
    injected = Counter(i.kind for i in injections)
    detected = Counter(i.kind for i in injections if i.detected)
    unknown = journal is None and any(k in TARGET_DETECTED for k in injected)
    # a reply injection knows its Step (not the row), so deadline misses are explained by Step and pass: a miss
    # of an abandoned pass is not explained by a fault of the pass that replayed its row; in real time (one pass)
    # a lost or refused frame also costs the row whose frame of its id carries the counter jump
    explained = (Counter((step_of(i.row), i.pass_) for i in injections)
                 + Counter((step_of(r.lost_row), r.lost_pass) for r in run.recoveries))
    if run.mode == "realtime":
        explained += Counter((step_of(row), 0) for row in chained_rows(injections))
    unexplained_misses, late = [], {}
    answered_late = run.late_replies()
    for miss in run.deadline_misses:
        if explained[(key := (step_of(miss.row), miss.pass_))] > 0:
            explained[key] -= 1
        elif answered_late.get(miss, math.inf) <= (run.stall_limit_s or 0.0):
            late[miss] = answered_late[miss]    # every send answered, within the stall limit: late, not lost
        else:
            unexplained_misses.append(miss.row)
    process = sum(injected[k] for k in PROCESS_KINDS)
    # the host refuses nothing the target sends unless a reply fault made it so: a refused reply that confirms no
    # injection is a problem, except the counter jumps that follow a lost or refused reply (its consequences)
    host_totals = Counter(r["kind"] for r in host_rejections)
    replies_faulted = any(injected[k] for k in REPLY_KINDS)
    unexplained_host = {k: n - host_confirming[k] for k, n in host_totals.items()
                        if n > host_confirming[k] and not (k == "counter" and replies_faulted)}
    totals = Counter(e["kind"] for e in journal.entries) if journal else None
    consistent = None
    if journal is not None and journal.instances and final_rx_errors:  # the journal covers the target's life
        final = dict(final_rx_errors)
        consistent = all(final.get(c, 0) == min(journal.last_instance[c], 255) for c in CATEGORIES)
    kinds = [k for k in KINDS if injected[k] or run.spec.rates.get(k, 0) or run.spec.counts.get(k, 0)]
    undetected = [i for i in injections if not i.detected]
    return {
        "spec": run.spec.describe(),
        "mode": run.mode,
        **run.spec.to_dict(),
        "injected": {k: injected[k] for k in kinds},
        "detected": {k: (None if unknown and k in TARGET_DETECTED else detected[k]) for k in kinds},
        "injected_total": sum(injected.values()),
        "detected_total": sum(detected.values()),
        "undetected": None if unknown else len(undetected),
        "undetected_faults": [] if unknown else [i.to_dict() for i in undetected[:LISTED]],
        "detection": {k: DETECTION[k] for k in kinds},
        "target_rejections": dict(totals) if totals is not None else None,
        "target_rejections_confirming_faults": dict(matched_categories),
        "host_rejections": dict(host_totals),
        "host_rejections_confirming_faults": dict(host_confirming),
        "unexplained_host_rejections": unexplained_host,
        "target_processes": journal.instances if journal is not None else None,
        "recoveries": [r.to_dict() for r in run.recoveries],
        "gaps": [{"rows": [r.restart_row, r.lost_row], "lost_row": r.lost_row, "restart_row": r.restart_row,
                  "reason": r.reason, "silent_s": r.silent_s, "duration_s": round(r.reinit_at - r.lost_at, 3)}
                 for r in run.recoveries],
        "retransmitted_rows": run.retransmitted_rows,
        "deadline_misses": len(run.deadline_misses),
        "late_replies": len(late),
        "late_reply_rows": [miss.row for miss in late][:LISTED],
        "late_reply_max_ms": round(1e3 * max(late.values()), 1) if late else None,
        "stall_limit_s": run.stall_limit_s,
        "unexplained_deadline_misses": len(unexplained_misses),
        "unexplained_deadline_miss_rows": unexplained_misses[:LISTED],
        "heartbeat_losses": heartbeat_losses,
        "unexplained_heartbeat_losses": max(0, heartbeat_losses - process),
        "final_rx_errors": dict(final_rx_errors or {}),
        "final_rx_errors_match_journal": consistent,
    }


def fault_problems(summary: dict) -> list[str]:
    """What the faults do not explain, one sentence each (empty: every fault detected, nothing unexplained)."""
    out = []
    if summary["undetected"] is None:
        out.append("the target's detection journal is not available, so detection of target-side faults cannot be "
                   "checked; start the target with --events FILE and pass the same file to the host with "
                   "--target-events")
    elif summary["undetected"]:
        kinds = Counter(f["kind"] for f in summary["undetected_faults"])
        out.append(f"{summary['undetected']} injected fault(s) went undetected "
                   f"({', '.join(f'{k} {n}' for k, n in kinds.items())})")
    if summary["unexplained_deadline_misses"]:
        out.append(late_sentence(summary["unexplained_deadline_misses"], summary["unexplained_deadline_miss_rows"]))
    if summary.get("unexplained_host_rejections"):
        out.append(f"the host rejected frames from the target that no reply fault explains: "
                   f"{summary['unexplained_host_rejections']}")
    if summary["unexplained_heartbeat_losses"]:
        out.append(f"the heartbeat was lost {summary['unexplained_heartbeat_losses']} time(s) more than the injected "
                   "kills and freezes explain")
    if summary["final_rx_errors_match_journal"] is False:
        out.append(f"the target's last RxErrors {summary['final_rx_errors']} differ from its detection journal")
    return out


def late_sentence(count: int, rows: list[int]) -> str:
    return f"{count} row(s) missed their reply deadline without an injected fault (rows {list(rows)[:5]})"


def fault_note(summary: dict | None, *, what: str = "fault(s) were injected") -> str | None:
    """'N faults were injected (...)', the sentence that makes a faulted run non-zero without --tolerate-faults
    (`summary`: a run's fault summary, or the fault metrics of a log)."""
    if not summary or not summary["injected_total"]:
        return None
    kinds = ", ".join(f"{k} {n}" for k, n in summary["injected"].items() if n)
    detected = ("detection unchecked" if summary["undetected"] is None else
                "all detected" if not summary["undetected"] else f"{summary['undetected']} undetected")
    return (f"{summary['injected_total']} {what} ({kinds}), {detected}; pass --tolerate-faults to accept a run with "
            "injected faults")


def sidecar_path(log_path: str | Path) -> Path:
    log_path = Path(log_path)
    return log_path.with_name(log_path.name + SIDECAR_SUFFIX)


def write_sidecar(log_path: str | Path, summary: dict, injections: Iterable) -> Path:
    """`<log>.faults.json`: the summary and every injection, written atomically next to the log."""
    path = sidecar_path(log_path)
    body = {"log": Path(log_path).name, **summary, "injections": [i.to_dict() for i in injections]}
    text = json.dumps(body, indent=1, allow_nan=False) + "\n"
    try:
        write_atomically(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    except OSError as exc:
        raise HostError(write_failure(path, "the fault summary", exc)) from None
    return path


def read_sidecar(log_path: str | Path) -> dict | None:
    path = sidecar_path(log_path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
