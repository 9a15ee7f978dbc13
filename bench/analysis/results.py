"""A run's results as typed objects, and their JSON.

`RunResults` is what `canmetrics.compute` makes of a bus log (the report's metric table, `metrics.json`);
`RunSummary` is what `bench run --json` prints (and the campaign stores): the run's verdict, bus, host figures and
its RunResults; `LogSummary` is `bench analyze --json`; `ReplayResults` is `bench replay --json`.

`bench run --json` and `bench analyze --json` carry, beside `clean` (true or false), `verdict`: "clean", or
"not clean: " and the reasons (the problems, "; "-separated, or the faults injected; `verdict_text`), and beside
each node's `rmse_C` the `rmse_reference` it is taken against ("measured": the dataset's temperature, "float64
model": the offline float64 model where the data has no measurement of that node), and `figure_rows`: the rows every
figure is over (`kept` of `rows`, `without_reply`) and those left out because a check flagged them as not the
target's own answer, counted by reason (`excluded`: contested, replayed, off_reference; `bench.analysis.rowfilter`).

The JSON keeps the flat shape the bench always printed: a group marked `flat` (e.g. `Agreement`) puts its keys at
its parent's level, so grouping the fields in Python changed no key. Every top-level JSON carries
`schema_version`; `from_json` refuses another version in one sentence (`ResultsError`).
"""

from __future__ import annotations

import types
import typing
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from typing import Any, TypeVar

import numpy as np

from bench.errors import BenchError

SCHEMA_VERSION = 2                # 2: figure_rows, the float64 range of the model (issue 23)
SCHEMA_KEY = "schema_version"

FLAT = {"flat": True}             # a group: its keys sit at its parent's level of the JSON
REST = {"rest": True}             # a dict of the keys no other field declares (another package's open record)
OMIT_NONE = {"omit_none": True}   # a key the JSON had only when there was a value

T = TypeVar("T")


class ResultsError(BenchError, ValueError):
    """Results JSON this bench cannot read (another schema version, a missing key)."""


# ------------------------------------------------------------------------------------------------ JSON machinery
def _dump(value: Any) -> Any:
    if is_dataclass(value) and not isinstance(value, type) and hasattr(value, "json_value"):
        return value.json_value()    # a part with derived keys of its own (`Acceptance`)
    if is_dataclass(value) and not isinstance(value, type):
        out: dict[str, Any] = {}
        for f in fields(value):
            item = getattr(value, f.name)
            if f.metadata.get("flat") or f.metadata.get("rest"):
                out.update(_dump(item))
            elif not (item is None and f.metadata.get("omit_none")):
                out[f.name] = _dump(item)
        return out
    if isinstance(value, dict):
        return {str(k): _dump(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_dump(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def as_json(value: Any) -> Any:
    """A part of the results (a dataclass, or anything holding some) as its JSON value."""
    return _dump(value)


def _load(tp: Any, data: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        if data is None:
            return None
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        classes = [a for a in options if is_dataclass(a)]
        return _load(classes[0], data, where) if classes else data
    if is_dataclass(tp):
        if not isinstance(data, dict):
            raise ResultsError(f"the results' {where or 'top level'} is not a JSON object")
        return _load_fields(tp, data, where)[0]
    if origin is dict:
        value_type = typing.get_args(tp)[1]
        return {k: _load(value_type, v, f"{where}.{k}") for k, v in data.items()}
    if origin is list:
        item_type = typing.get_args(tp)[0]
        return [_load(item_type, v, f"{where}[{i}]") for i, v in enumerate(data)]
    return data


def _load_fields(cls: type[T], data: dict, where: str) -> tuple[T, set[str]]:
    """An instance of dataclass `cls` from `data`, and the keys of `data` it used."""
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    used: set[str] = set()
    rest = None
    for f in fields(cls):  # type: ignore[arg-type]
        if f.metadata.get("rest"):
            rest = f.name
        elif f.metadata.get("flat"):
            kwargs[f.name], keys = _load_fields(hints[f.name], data, where)
            used |= keys
        elif f.name in data:
            kwargs[f.name] = _load(hints[f.name], data[f.name], f"{where}.{f.name}" if where else f.name)
            used.add(f.name)
        elif f.default is MISSING and f.default_factory is MISSING:
            raise ResultsError(f"the results lack {f'{where}.' if where else ''}{f.name}, which this bench needs; "
                               "they were not written by `bench run` or `bench analyze`")
    if rest is not None:
        kwargs[rest] = {k: v for k, v in data.items() if k not in used}
    return cls(**kwargs), used


def finite_json(value: Any, nulls: dict[str, str], where: str = "") -> Any:
    """`value` (JSON) with every float that is not finite replaced by None, the reason recorded in `nulls` under its
    dotted path. JSON cannot hold inf or NaN, and a report must not print them."""
    if isinstance(value, float | np.floating) and not np.isfinite(value):
        nulls.setdefault(where, f"{float(value)!r}: not a finite number (the values overflowed)")
        return None
    if isinstance(value, dict):
        return {k: finite_json(v, nulls, f"{where}.{k}" if where else str(k)) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_json(v, nulls, f"{where}[{i}]") for i, v in enumerate(value)]
    return value


def check_schema(data: Any, what: str = "results") -> None:
    """ResultsError (one sentence) unless `data` is a JSON object of this bench's results schema."""
    if not isinstance(data, dict):
        raise ResultsError(f"the {what} are not a JSON object")
    version = data.get(SCHEMA_KEY)
    if version != SCHEMA_VERSION:
        found = "no schema_version" if version is None else f"schema_version {version!r}"
        raise ResultsError(f"the {what} have {found}, this bench reads schema_version {SCHEMA_VERSION}; "
                           "make them again with this bench")


class _Json:
    """to_json/from_json of a top-level result (with its schema version)."""

    def to_json(self) -> dict[str, Any]:
        return {SCHEMA_KEY: SCHEMA_VERSION, **_dump(self)}

    @classmethod
    def from_json(cls: type[T], data: Any) -> T:
        check_schema(data)
        return _load_fields(cls, data, "")[0]


# ------------------------------------------------------------------------------------------------ parts
@dataclass
class NodeValues:
    """One figure per temperature node (None: none, or not finite)."""

    yoke: float | None = None
    winding: float | None = None
    tooth: float | None = None
    magnet: float | None = None

    def values(self) -> list[float | None]:
        return [self.yoke, self.winding, self.tooth, self.magnet]

    def worst(self) -> float | None:
        """The largest of the figures there are."""
        return max((v for v in self.values() if v is not None), default=None)

    def get(self, node: str) -> float | None:
        return getattr(self, node)


@dataclass
class NodeLabels:
    """What each node's RMSE is taken against ("measured" or "float64 model")."""

    yoke: str
    winding: str
    tooth: str
    magnet: str

    def get(self, node: str) -> str:
        return getattr(self, node)


@dataclass
class Percentiles:
    p50: float | None
    p99: float | None
    max: float | None


@dataclass
class CycleFigures:
    """{p50, max} of per-step figures (Timing4)."""

    p50: int | float | None
    max: int | float | None


@dataclass
class ModelInfo:
    id: str
    kind: str
    realization: str
    dt_s: float
    loss_model: str
    log_model_id: str | None


@dataclass
class DataIdentity:
    """Which data a run replayed: its first `rows` rows, whose values hash to `sha256`
    (`bench.drive.dataset.Dataset.rows_sha256`); a baseline of other data cannot be compared with."""

    rows: int
    sha256: str

    def differs_from(self, other: DataIdentity) -> str | None:
        """Why `other` is other data (None when it is the same)."""
        if self.rows != other.rows:
            return f"{other.rows} rows, not {self.rows}"
        if self.sha256 != other.sha256:
            return f"rows of sha256 {other.sha256[:12]}…, not {self.sha256[:12]}…"
        return None


@dataclass
class Replies:
    steps_sent: int
    replies: int
    missing: int
    sequence_gaps: int
    model_steps: int


@dataclass
class Agreement:
    """CAN values against the float32 reference (restarted as the target was, or the target's twin)."""

    max_abs_can_minus_float32_C: NodeValues
    can_agrees_with_float32: bool
    replies_compared: int
    can_reference: str
    rows_lost_on_the_bus: int
    max_abs_can_minus_clean_C: NodeValues
    segments: int
    saturated_values: int
    # the log's XCP DOWNLOADs the twin answered otherwise than the target (its cells not where the target's were)
    xcp_downloads_unlike_target: int = 0


REASON_WORDS = {"contested": "contested", "replayed": "replayed",
                "restored_not_from_target": "restored from a checkpoint the target did not send",
                "off_reference": "off the float32 reference"}


@dataclass
class FigureRows:
    """The rows every figure is over (`bench.analysis.rowfilter.kept_rows`): `kept` of `rows`, the rows without a
    reply, and the rows a check flagged as not the target's own answer, by reason."""

    rows: int
    kept: int
    without_reply: int
    excluded: dict[str, int] = field(default_factory=dict)

    @property
    def excluded_total(self) -> int:
        return sum(self.excluded.values())

    def text(self, what: str = "figures") -> str:
        """'figures over 1990 of 2000 rows; 10 rows excluded: replayed'."""
        head = f"{what} over {self.kept} of {self.rows} rows"
        if self.without_reply:
            head += f" ({self.without_reply} without a reply)"
        total = self.excluded_total
        if not total:
            return head
        words = [REASON_WORDS.get(k, k) + ("" if len(self.excluded) == 1 else f" {n}")
                 for k, n in self.excluded.items()]
        return f"{head}; {total} row{'' if total == 1 else 's'} excluded: {', '.join(words)}"


@dataclass
class NonFinite:
    float32: int
    float64: int


@dataclass
class MeasuredRmse:
    winding: float | None
    magnet: float | None


@dataclass
class Accuracy:
    """The model: float32 against float64, RMSE of the CAN values per node."""

    max_abs_float32_minus_float64_C: NodeValues
    non_finite_values: NonFinite
    rmse_C: NodeValues
    rmse_reference: NodeLabels
    model_rmse_vs_measured_C: dict[str, MeasuredRmse]
    # the float64 model's own range: values outside the DBC's, and the largest |float32 − float64| / max(1, |float64|)
    float64_outside_dbc_range: int = 0
    max_rel_float32_minus_float64: float | None = None
    # max |CAN − reference| per node against what its RMSE is against (`rmse_reference`), and both figures against
    # the float64 model for every node (the acceptance criteria's "against"; None in results of an older bench)
    max_abs_error_C: NodeValues | None = None
    rmse_vs_float64_C: NodeValues | None = None
    max_abs_error_vs_float64_C: NodeValues | None = None


@dataclass
class Timing:
    step_time_us: Percentiles
    overruns: int
    est_cycles: int | None
    est_exec_time_us: float | None
    cpu_load_percent: float | None
    engine: str
    m4_cycles: CycleFigures | None
    m4_exec_time_us: CycleFigures | None
    m4_clock_mhz: float
    # the firmware with the motor-control interrupt (Timing5): each model step's response time (reception ->
    # result, at m4_clock_mhz) and the interrupt's CPU load (the mean of the per-step figures); absent without it
    response_time_us: Percentiles | None = field(default=None, metadata=OMIT_NONE)
    isr_load_percent: float | None = field(default=None, metadata=OMIT_NONE)


@dataclass
class Memory:
    flash_bytes: int | None
    ram_bytes: int | None
    memory_source: str
    est_flash_bytes: int
    est_ram_bytes: int


@dataclass
class Throughput:
    round_trip_us: Percentiles
    wall_time_s: float | None
    throughput_steps_per_s: float | None
    throughput_model_steps_per_s: float | None


@dataclass
class Heartbeat:
    frames: int
    max_gap_s: float | None
    losses: int


@dataclass
class Integrity:
    """The bus and the log: heartbeat, rejected and foreign frames, completeness."""

    heartbeat: Heartbeat
    target_rx_errors: dict[str, int]
    invalid_frames_in_log: dict[str, int]
    rejected_target_frames: dict[str, int]
    foreign_frames: dict[str, int]
    contested_rows: int
    target_faults_seen: list[str]
    frames_in_log: int
    log_complete: bool
    log_stopped: bool
    log_unclosed: bool
    last_row: int
    log: str
    # the host's measurement frames the target's checks refuse, by message (a replayed or lost frame: the counter)
    rejected_host_frames: dict[str, int] = field(default_factory=dict)
    # segments restored from a state the target never sent or from a contested checkpoint: [start row, why]
    restores_not_from_target: list[list] = field(default_factory=list)


@dataclass
class FaultGap:
    """A gap marked in the log: the target lost and re-initialized."""

    rows: list[int]
    lost_row: int | None
    restart_row: int | None
    duration_s: float | None
    start_s: float | None


@dataclass
class FaultResults:
    """The faults marked in a log (BenchEvent) and their detection from the `<log>.faults.json` sidecar."""

    injected: dict[str, int]
    injected_total: int
    detected: dict[str, int | None] | None
    undetected: int | None
    detection: dict[str, str]
    sidecar_injected_total: int | None
    retransmitted_rows: int
    gaps: list[FaultGap]
    reinitializations: int
    unexplained_deadline_misses: int | None
    unexplained_deadline_miss_rows: list[int]
    seed: int | None
    mode: str | None
    sidecar_problems: list[str] | None
    sidecar: str | None
    late_replies: int | None = None      # lockstep rows answered at every send, but after the deadline

    def as_note_input(self) -> dict[str, Any]:
        """The dict `host.faults.fault_note` reads (host knows no bench types)."""
        return _dump(self)


@dataclass
class BusLoad:
    bitrate: int
    bits_per_frame_mean: float | None
    data_rate_percent: float | None
    window_s: float | None = None
    window_start_s: list[float] = field(default_factory=list)
    window_percent: list[float] = field(default_factory=list)
    replay_peak_percent: float | None = field(default=None, metadata=OMIT_NONE)


def _without_windows(data: dict[str, Any]) -> dict[str, Any]:
    """The bus load without its per-window series (the JSON summaries leave them to the figure)."""
    return {k: v for k, v in data.items() if not k.startswith("window_")}


@dataclass
class CheckResult:
    """One acceptance criterion judged (`bench.acceptance`): its figure against its limit (the figure must not
    exceed it), and the verdict. `figure` None: the figure could not be had (no measurement, no baseline node), which
    fails the check; `source` says where a figure came from when that matters (cycles: counted or estimated)."""

    name: str
    kind: str
    what: str
    figure: float | None
    limit: float
    unit: str
    passed: bool
    message: str
    source: str | None = field(default=None, metadata=OMIT_NONE)

    @property
    def verdict(self) -> str:
        return "pass" if self.passed else "fail"


@dataclass
class Acceptance:
    """The acceptance criteria of a run or a log (`--criteria FILE`, `--baseline FILE`) and how each fared."""

    criteria: str | None
    baseline: str | None
    checks: list[CheckResult]

    @property
    def failed(self) -> list[CheckResult]:
        return [c for c in self.checks if not c.passed]

    @property
    def passed(self) -> bool:
        return not self.failed

    def sentence(self, subject: str = "the run") -> str:
        """'the run meets its 7 acceptance criteria', or which failed and by what figure."""
        failed, n = self.failed, len(self.checks)
        if not failed:
            return f"{subject} meets its {n} acceptance criteri{'on' if n == 1 else 'a'}"
        return (f"{subject} fails {len(failed)} of its {n} acceptance criteria: "
                + "; ".join(c.message for c in failed))

    def json_value(self) -> dict[str, Any]:
        """Its JSON (`_dump` uses it): with the verdicts, the names that failed and the sentence."""
        return {"criteria": self.criteria, "baseline": self.baseline, "passed": self.passed,
                "failed": [c.name for c in self.failed], "verdict": self.sentence(),
                "checks": [{**_dump(c), "verdict": c.verdict} for c in self.checks]}


@dataclass
class SlotFigures:
    """One measurement of an observer over CAN, by its Innovations slot."""

    measured_node: str              # the node its reading sees (the flux linkage: the magnet)
    rows_measured: int              # rows whose measurement frames carried its channels VALID
    model_steps_updated: int        # model steps whose update used it (its Used flag)
    innovation_rms_C: float | None
    # the innovation gate (the section's `gate`) as the target reported it on the bus (DBC 1.8.0: each step's
    # Rejected flag in Innovations, the Flagged flag in Uncertainty1): readings rejected (ν² > sigma² S: predicted
    # only), whether its sensor was flagged (flag_after rejections in a row), and the sensor's name; a log of an
    # older target (DBC < 1.8) carries neither: then they are the offline float32 code's (`gate_source`)
    readings_rejected: int = 0
    sensor_flagged: bool = False
    sensor: str = ""
    gate_source: str = "bus"                # "bus", or "offline float32" for a target of DBC < 1.8
    # the same from the target's own float32 code offline, and the cross-check: the model steps compared (where
    # CAN = that code, in the run's first segment) and those whose Rejected or Flagged flag differs (a finding)
    readings_rejected_float32: int = 0
    sensor_flagged_float32: bool = False
    gate_steps_compared: int = 0
    gate_steps_differing: int = 0


@dataclass
class ObserverResults:
    """The observer of a model with one (`target_sim.observer`): the node its measurement sees (its error there is
    not an estimate's: the filter is pulled towards that measurement), how often a model step used a measurement, the
    target's 1-sigma per node and its innovations (Uncertainty1/2, Innovations), and per node the open loop's and the
    observer's RMSE, both offline float32, against the same reference (`rmse_reference`)."""

    measured_node: str
    slot: str                       # the Measurements slot it reads (sensor, flux)
    rows_measured: int              # rows whose Measurements carried a VALID value in that slot
    model_steps: int                # model steps the target reported (Innovations frames)
    model_steps_updated: int        # of which its update used a measurement
    sigma_final_C: NodeValues       # each node's 1-sigma after the last reported step
    sigma_max_C: NodeValues
    innovation_rms_C: float | None
    open_loop_rmse_C: NodeValues
    observer_rmse_C: NodeValues
    # per measurement (DBC 1.7.0: several per row), by slot; the fields above are the first one's (rows_measured
    # and model_steps_updated: any measurement's)
    measurements: dict[str, SlotFigures] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------ results
@dataclass
class RunResults(_Json):
    """What the bench measured on a bus log (`canmetrics.compute`): the metric table of the report."""

    model: ModelInfo
    counts: Replies = field(metadata=FLAT)
    agreement: Agreement = field(metadata=FLAT)
    accuracy: Accuracy = field(metadata=FLAT)
    timing: Timing = field(metadata=FLAT)
    memory: Memory = field(metadata=FLAT)
    throughput: Throughput = field(metadata=FLAT)
    integrity: Integrity = field(metadata=FLAT)
    faults: FaultResults | None
    bus_load: BusLoad
    figure_rows: FigureRows
    observer: ObserverResults | None = field(default=None, metadata=OMIT_NONE)   # a model with an observer
    data: DataIdentity | None = field(default=None, metadata=OMIT_NONE)   # None: no dataset matched the log
    notes: list[str] = field(default_factory=list)
    null_values: dict[str, str] = field(default_factory=dict)
    report: str | None = field(default=None, metadata=OMIT_NONE)   # report.md, once written
    acceptance: Acceptance | None = field(default=None, metadata=OMIT_NONE)   # with --criteria/--baseline

    def to_json(self, *, windows: bool = True) -> dict[str, Any]:
        """The JSON object; without `windows` the bus load leaves out its per-window series."""
        data = super().to_json()
        if not windows:
            data["bus_load"] = _without_windows(data["bus_load"])
        return data


def finite_results(results: RunResults, nulls: dict[str, str]) -> RunResults:
    """`results` with every value that is not finite null, and `null_values` saying why (`nulls`, which holds the
    reasons found while computing, by the JSON path of the value)."""
    data = results.to_json()
    data.pop("null_values", None)
    data = finite_json(data, nulls)
    data["null_values"] = dict(nulls)
    return RunResults.from_json(data)


@dataclass
class BusInfo:
    """The bus a run used, `auto` resolved (a script needs it to reach the same bus, e.g. its udp port)."""

    interface: str
    channel: Any
    port: int | None = field(default=None, metadata=OMIT_NONE)
    # frames other listeners lost at full receive buffers during the run (`dbc.udp_listeners`; udp_multicast)
    listener_drops: int | None = field(default=None, metadata=OMIT_NONE)


@dataclass
class NodeCycles:
    """The firmware node's cycles per received and per reply frame (model steps excluded), from its stats."""

    per_received_frame: dict[str, Any] | None
    per_reply_frame: dict[str, Any] | None
    stack_used_bytes: int | None
    tx_dropped: int | None

    def text(self) -> str:
        frame, reply = self.per_received_frame or {}, self.per_reply_frame or {}
        return (f"{frame.get('p50')} / {frame.get('max')} per received frame, {reply.get('p50')} / "
                f"{reply.get('max')} per reply frame; stack used {self.stack_used_bytes} B")


@dataclass
class HostGap:
    """A gap the host recovered from (`host.faults` reconciliation)."""

    rows: list[int]
    lost_row: int | None = None
    restart_row: int | None = None
    reason: str | None = None
    silent_s: float | None = None
    duration_s: float | None = None


@dataclass
class HostFaults:
    """The run's fault figures: the host's reconciliation (`host.faults.reconcile`, whose other keys are kept in
    `other` as the host wrote them), plus what the log's marks show."""

    injected: dict[str, int]
    detected: dict[str, int | None]
    injected_total: int
    detected_total: int
    undetected: int | None
    retransmitted_rows: int
    gaps: list[HostGap]
    other: dict[str, Any] = field(default_factory=dict, metadata=REST)
    undetected_faults: list[dict[str, Any]] = field(default_factory=list)
    marked_in_log: dict[str, int] | None = field(default=None, metadata=OMIT_NONE)
    gaps_in_log: list[FaultGap] | None = field(default=None, metadata=OMIT_NONE)

    @classmethod
    def of_run(cls, host_faults: dict | None, log_faults: FaultResults | None) -> HostFaults | None:
        """The host's reconciliation (None: no faults), with the log's marks when the log has some."""
        if host_faults is None:
            return None
        out = _load_fields(cls, {**host_faults, "undetected_faults": host_faults.get("undetected_faults", [])},
                           "faults")[0]
        if log_faults is not None:
            out.marked_in_log, out.gaps_in_log = dict(log_faults.injected), list(log_faults.gaps)
        return out


def verdict_text(clean: bool, problems: list[str], injected: int = 0, undetected: int | None = 0) -> str:
    """The one-line verdict of the JSON: "clean", else "not clean: " and why (the problems, or with none the
    injected faults, which keep a run from being clean even when each was detected and tolerated)."""
    if clean:
        return "clean"
    reasons = list(problems)
    if not reasons and injected:
        detected = "all detected" if undetected == 0 else "detection not verified"
        reasons = [f"{injected} fault{'' if injected == 1 else 's'} injected, {detected}, nothing else went wrong"]
    return "not clean: " + ("; ".join(reasons) or "no reason recorded")


@dataclass
class RunSummary(_Json):
    """What a run prints with `--json`, `bench run`'s and `bench host`'s alike: the brief's numbers first (copies of
    `metrics`' own, kept at the top for a script), then the verdict, the bus, the host's figures (under "host", and
    each at the top too, where `bench host` always had them) and the metrics. A run whose log holds no figures (it
    ended before its first row) has no metrics, and none of the keys made of them."""

    engine: str | None
    firmware: str | None
    bus: BusInfo
    problems: list[str]
    clean: bool
    faults: HostFaults | None
    host: dict[str, Any]          # `host.results.HostResult.to_dict()` (the host package's record), less the above
    metrics: RunResults | None
    elapsed_s: float
    node_cycles: NodeCycles | None = None
    log_path: str | None = None   # the host's log (the metrics' own once the log is analyzed)
    # the criteria judged on no figures (each fails, saying why); with metrics, they are the metrics' own
    unjudged: Acceptance | None = field(default=None, metadata=OMIT_NONE)

    @property
    def acceptance(self) -> Acceptance | None:
        return self.metrics.acceptance if self.metrics is not None else self.unjudged

    def to_json(self) -> dict[str, Any]:
        m = self.metrics
        figures = {} if m is None else {
            "steps_sent": m.counts.steps_sent, "replies": m.counts.replies, "missing": m.counts.missing,
            "max_abs_can_minus_float32_C": m.agreement.max_abs_can_minus_float32_C, "rmse_C": m.accuracy.rmse_C,
            "rmse_reference": m.accuracy.rmse_reference,   # what each node's RMSE is against
            "figure_rows": m.figure_rows,                  # the rows it is over, those a check left out
            "step_time_us": m.timing.step_time_us, "est_cycles": m.timing.est_cycles,
            "m4_cycles": m.timing.m4_cycles, "flash_bytes": m.memory.flash_bytes, "ram_bytes": m.memory.ram_bytes,
            "memory_source": m.memory.memory_source, "throughput_steps_per_s": m.throughput.throughput_steps_per_s,
            "log": m.integrity.log, "report": m.report}
        head = {
            "engine": self.engine, "firmware": self.firmware, **figures, "bus": self.bus, "problems": self.problems,
            **({"notes": m.notes} if m is not None else {}), "clean": self.clean, "verdict": self.verdict,
            **({"acceptance": self.acceptance} if self.acceptance is not None else {}),
            "faults": self.faults, "host": self.host}
        out = {SCHEMA_KEY: SCHEMA_VERSION, **_dump(head)}
        if m is not None:
            out["metrics"] = m.to_json(windows=False)
        out |= {"elapsed_s": round(self.elapsed_s, 2), "node_cycles": _dump(self.node_cycles)}
        # the host's record at the top as well, each key where `bench host --json` always had it
        flat = {**self.host, "log_path": self.log_path if self.log_path is not None else
                (m.integrity.log if m is not None else None)}
        return out | {k: _dump(v) for k, v in flat.items() if k not in out}

    @property
    def verdict(self) -> str:
        faults = self.faults
        return verdict_text(self.clean, self.problems, faults.injected_total if faults else 0,
                            faults.undetected if faults else 0)

    @classmethod
    def from_json(cls, data: Any) -> RunSummary:
        check_schema(data, "run summary")
        check_schema(data.get("metrics"), "run summary's metrics")
        return _load_fields(cls, data, "")[0]


@dataclass
class LogSummary(_Json):
    """What `bench analyze --json` prints: the log's metrics with the verdict."""

    metrics: RunResults = field(metadata=FLAT)
    problems: list[str] = field(default_factory=list)
    clean: bool = False

    def to_json(self) -> dict[str, Any]:
        faults = self.metrics.faults
        verdict = verdict_text(self.clean, self.problems, faults.injected_total if faults else 0,
                               faults.undetected if faults else 0)
        return {**self.metrics.to_json(windows=False), "problems": self.problems, "clean": self.clean,
                "verdict": verdict}


@dataclass
class ReplyComparison:
    """A replay's final reply per data row against the recorded one."""

    rows_recorded: int
    rows_replayed: int
    recorded_answered: int
    replayed_answered: int
    compared: int
    identical: int
    different: int
    missing_in_replay: int
    max_abs_difference_C: float
    # rows a check flagged as not the target's own answer (`bench.analysis.rowfilter`), left out of the comparison
    recorded_excluded: dict[str, int] = field(default_factory=dict)
    replayed_excluded: dict[str, int] = field(default_factory=dict)


@dataclass
class Rejections:
    recorded: dict[str, int]
    replayed: dict[str, int]


@dataclass
class ReplayResults(_Json):
    """What `bench replay --json` prints."""

    log: str
    replay_log: str | None
    reproduced: bool
    comparison: ReplyComparison = field(metadata=FLAT)
    engine: str | None
    m4_cycles: dict[str, float | None] | None
    faults_in_log: dict[str, int] | None
    rejections_compared: bool
    target_rejections: Rejections
    mode: str
    speed: float | None
    wall_time_s: float
    rows_per_s: float
    round_trip_us: Percentiles
    problems: list[str]
    acceptance: Acceptance | None = field(default=None, metadata=OMIT_NONE)   # of the replay's log (--criteria)
