"""What a host run reports: counts, round trips, jitter, the target's view, and whether anything went wrong."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from dbc.contract import FaultBit
from host.replay import ReplayStats
from host.session import HostSession


def percentiles(values, scale: float = 1.0) -> dict[str, float | None]:
    """{p50, p99, max} of `values` times `scale`; None entries for an empty set."""
    arr = np.asarray(values, dtype=float) * scale
    arr = arr[np.isfinite(arr)]
    if arr.size == 0:
        return {"p50": None, "p99": None, "max": None}
    return {"p50": float(np.percentile(arr, 50)), "p99": float(np.percentile(arr, 99)), "max": float(arr.max())}


def gap_count(answered: np.ndarray) -> int:
    """Runs of consecutive unanswered rows (each run is one gap in the reply sequence)."""
    missing = ~np.asarray(answered, dtype=bool)
    if missing.size == 0:
        return 0
    starts = missing & ~np.concatenate([[False], missing[:-1]])
    return int(np.count_nonzero(starts))


def clamped_problem(faults_seen: list[str]) -> str | None:
    """The sentence for a target that clamped temperatures it could not carry (Status fault bits SATURATED,
    NONFINITE), or None; a run that did is not clean (`bench analyze` says the same of its log)."""
    bits = [bit for bit in ("SATURATED", "NONFINITE") if bit in faults_seen]
    if not bits:
        return None
    what = "left the DBC range -50..600 °C" + (" or was not finite" if "NONFINITE" in bits else "")
    return (f"the target clamped temperatures ({' and '.join(bits)}): the model's estimate {what}, so the CAN "
            "values there are not the model's")


@dataclass
class HostResult:
    mode: str
    speed: float | None
    rows: int
    rows_sent: int
    replies: int
    missing: int
    late_replies: int
    sequence_gaps: int
    heartbeat_losses: int
    max_heartbeat_gap_s: float
    invalid_frames: dict[str, int]
    target_rx_errors: dict[str, int]
    target_faults_seen: list[str]
    target_state: str | None
    target_info: dict[str, object]
    model_id: str | None
    wall_time_s: float
    rows_per_s: float
    round_trip_us: dict[str, float | None]
    send_jitter_us: dict[str, float | None] | None
    step_time_us: dict[str, float | None]
    est_cycles: int | None
    est_exec_us: float | None
    cpu_load_percent: float | None
    # the Cortex-M4F cycles the firmware engine counted per model step (Timing4), p50/p99/max; None without them
    m4_cycles: dict[str, float | None] | None = None
    engine: str | None = None       # "firmware" when the target sent Timing4, else "python"
    log_path: str | None = None
    aborted: str | None = None
    log_frames: int | None = None
    faults: dict | None = None      # the fault summary (host.faults.reconcile) of a run with injected faults
    arrays: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def problems(self) -> list[str]:
        """Every reason this run is not clean, one sentence each (empty: clean).

        With injected faults, what the faults explain is not a problem (the target's rejections, the heartbeat
        losses of kills and freezes, rows answered after a retransmission or a re-initialization); what they do
        not explain is, and so is every fault that went undetected. That faults were injected at all is
        `host.faults.fault_note`, which the command lines add unless --tolerate-faults.
        """
        out = []
        if self.aborted:
            out.append(f"the run was aborted: {self.aborted}")
        if self.rows_sent < self.rows:
            out.append(f"only {self.rows_sent} of {self.rows} rows were sent")
        clamped = clamped_problem(self.target_faults_seen)
        if clamped:
            out.append(clamped)
        realtime_faults = self.faults is not None and self.faults.get("mode") == "realtime"
        if self.missing and not realtime_faults:  # in real time a faulted row stays unanswered: see fault_problems
            out.append(f"{self.missing} of {self.rows_sent} rows got no reply ({self.sequence_gaps} gaps in the "
                       "reply sequence)")
        if self.faults is not None:
            from host.faults import fault_problems

            return out + fault_problems(self.faults)  # it judges the host's rejections against the reply faults
        if self.heartbeat_losses:
            out.append(f"the target's heartbeat was lost {self.heartbeat_losses} time(s) (longest silence "
                       f"{self.max_heartbeat_gap_s:.2f} s)")
        bad = {k: v for k, v in self.invalid_frames.items() if v}
        if bad:
            out.append(f"the host rejected frames from the target: {bad}")
        target_bad = {k: v for k, v in self.target_rx_errors.items() if v}
        if target_bad:
            out.append(f"the target rejected or could not sequence frames: {target_bad}")
        return out

    def to_dict(self) -> dict:
        data = asdict(self)
        data.pop("arrays")
        return data


def build_result(session: HostSession, stats: ReplayStats, *, rows: int, speed: float | None,
                 log_path: str | None, log_frames: int | None = None, faults: dict | None = None) -> HostResult:
    book = session.book
    assert book is not None
    sent = stats.rows_sent
    answered = book.answered()[:sent]
    rtt = (book.replied_ns[:sent] - book.sent_ns[:sent])[answered]
    mon = session.monitor
    timing = session.timing
    measured = timing["measured_us"].values()
    cycles = timing["cycles"].values()
    exec_us = timing["exec_us"].values()
    load = timing["cpu_load"].values()
    m4_cycles = timing["m4_cycles"].values()
    return HostResult(
        mode=stats.mode, speed=speed, rows=rows, rows_sent=sent, replies=int(np.count_nonzero(answered)),
        missing=int(sent - np.count_nonzero(answered)), late_replies=session.late_replies,
        sequence_gaps=gap_count(answered), heartbeat_losses=mon.heartbeat_losses,
        max_heartbeat_gap_s=round(mon.max_gap_s, 4), invalid_frames=dict(session.invalid),
        target_rx_errors=dict(mon.rx_errors),
        target_faults_seen=[bit.name for bit in FaultBit if bit & mon.faults_seen],
        target_state=mon.state.name if mon.state is not None else None, target_info=dict(mon.target_info),
        model_id=f"{mon.model_id:08x}" if mon.model_id is not None else None,
        wall_time_s=round(stats.wall_time_s, 4), rows_per_s=round(sent / stats.wall_time_s, 1)
        if stats.wall_time_s > 0 else 0.0,
        round_trip_us=percentiles(rtt, 1e-3),
        send_jitter_us=percentiles(stats.send_jitter_s, 1e6) if stats.send_jitter_s is not None else None,
        step_time_us=percentiles(measured), est_cycles=int(cycles.max()) if cycles.size else None,
        est_exec_us=float(exec_us.max()) if exec_us.size else None,
        cpu_load_percent=float(load.max()) if load.size else None,
        m4_cycles=percentiles(m4_cycles) if m4_cycles.size else None, engine="firmware" if m4_cycles.size else "python",
        log_path=log_path, aborted=stats.aborted, log_frames=log_frames, faults=faults,
        arrays={"temps": book.temps[:sent], "answered": answered, "round_trip_ns": book.replied_ns[:sent]
                - book.sent_ns[:sent], **({"send_jitter_s": stats.send_jitter_s}
                                          if stats.send_jitter_s is not None else {})})
