"""A run's last stage, shared by `bench run` and `bench host`: the log analyzed against the offline references (with
the report, where one is asked for), the acceptance criteria judged, the verdict, and the one `RunSummary` both
commands print and the campaign and the pytest plugin read back (`bench.acceptance.cli.finish_run` then writes the
JUnit XML and gives the exit status: the acceptance package knows the run's options, so the run does not import it)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.analysis.results import BusInfo, HostFaults, NodeCycles, RunSummary
from bench.analysis.verdict import Verdict, verdict
from bench.errors import BenchError
from bench.run.execute import RunOutcome
from bench.run.prepare import PreparedRun
from dbc.transport import UDP_INTERFACE, BusConfig
from host.canlog import LogError
from host.faults import fault_note

if TYPE_CHECKING:
    from bench.run.request import RunRequest


@dataclass(frozen=True)
class JudgedRun:
    """What a run came to: its summary (the JSON of `--json`) and its verdict (the problems, the exit status before
    the acceptance criteria)."""

    summary: RunSummary
    verdict: Verdict


def bus_summary(bus: BusConfig, listener_drops: int | None = None) -> BusInfo:
    """The bus a run used, `auto` resolved (a script needs it to reach the same bus, e.g. its udp port), and what
    other listeners on it lost during the run."""
    port = bus.kwargs.get("port") if bus.interface == UDP_INTERFACE else None
    return BusInfo(bus.interface, bus.channel, port, listener_drops)


def node_cycles(stats: dict | None) -> NodeCycles | None:
    """The firmware node's cycles per received frame and per reply frame (model steps excluded), from its stats."""
    if not stats or stats.get("engine") != "firmware":
        return None
    return NodeCycles(per_received_frame=stats.get("frame_cycles"), per_reply_frame=stats.get("reply_cycles"),
                      stack_used_bytes=stats.get("stack_used_bytes"), tx_dropped=stats.get("tx_dropped"))


def judge(prepared: PreparedRun, outcome: RunOutcome, request: RunRequest, gate: Any, bus: BusConfig, *,
          engine: str | None, firmware: Path | None, started: float, run_info: dict | None = None,
          need_figures: bool = True) -> JudgedRun:
    """The run's log against the offline references, its acceptance criteria (`gate`, a `bench.acceptance.criteria.
    Gate`, or None without --criteria and --baseline) and its verdict, as one summary.

    `engine`: the target's, as the command knows it (None: what the log shows); `started`: `time.perf_counter()`
    when the run began; `run_info`: the report's run lines, which a report (`request.report`, unless
    `request.no_report` or `run_info` is None) is written with. A log that cannot be analyzed is a BenchError with
    `need_figures` (a run the bench made itself: its log must be readable), else a problem of the summary (a target
    of one's own may have ended the run before its first row)."""
    from bench.analysis.report import analyze_log

    host = outcome.result
    log_path = prepared.log_path
    report_dir = None if request.no_report or run_info is None else request.report
    unjudged = None
    try:
        metrics, found = analyze_log(log_path, prepared.artifact, prepared.dataset, report_dir=report_dir,
                                     bitrate=bus.nominal_bitrate, run_info=run_info, extra_problems=host.problems(),
                                     gate=gate, xcp_elf=firmware)   # a calibration master's DOWNLOADs: its addresses
    except (LogError, ValueError) as exc:
        if need_figures:
            raise BenchError(f"the log {log_path} cannot be analyzed ({exc})") from None
        metrics, found = None, [f"the log {log_path} cannot be compared with the offline float32 reference ({exc})"]
        unjudged = gate.judge(None, why_none="; ".join(found)) if gate is not None else None
    judged = verdict(host.problems() + found, fault_note(host.faults), faulted=host.faults is not None,
                     tolerate_faults=request.tolerate_faults, tolerate_gaps=request.tolerate_gaps)
    injected = host.faults["injected_total"] if host.faults else 0
    summary = RunSummary(
        engine=engine or (metrics.timing.engine if metrics is not None else host.engine),
        firmware=str(firmware) if firmware is not None else None,
        bus=bus_summary(bus, outcome.listener_drops),
        problems=judged.problems,
        clean=not judged.problems and not injected,
        faults=HostFaults.of_run(host.faults, metrics.faults if metrics is not None else None),
        host={k: v for k, v in host.to_dict().items() if k not in ("log_path", "faults")},
        metrics=metrics,
        elapsed_s=time.perf_counter() - started,
        node_cycles=node_cycles(outcome.target_stats),
        log_path=host.log_path,
        unjudged=unjudged)
    return JudgedRun(summary, judged)
