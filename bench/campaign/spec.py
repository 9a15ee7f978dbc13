"""A campaign spec (TOML): the axes to sweep and the options every run shares, expanded into runs.

    [campaign]
    name = "smoke"                  # optional: a title for the report (default: the file's stem)
    description = "..."             # optional
    timeout = 600                   # optional: seconds a run may take before it is stopped (default 1800)

    [fixed]                         # options of every run
    rows = 300
    tolerate_faults = true

    [axes]                          # every combination of these values is one run (cartesian product)
    model = ["hammerstein", "lti-lptn", "pv-lptn"]
    fault_seed = [1, 2]
    faults = ["drop=0.01,corrupt=0.001"]

Options: every `bench run` option a user sets (`bench.run.request.RUN_OPTIONS`, the same name with `_` for
`-`, the same checks): `model` (a packaged kind, hammerstein, lti-lptn or pv-lptn, or an artifact path), `engine`
(python, firmware), `isr_rate` (Hz, with the firmware engine), `data` (20, 40 or 60: the generated dataset of that
coolant set point; or a CSV path), `mapping` (path), `sample_period` (seconds or "auto"), `seed` (of the generated
datasets), `mode` (lockstep, realtime), `speed`, `rows` (a number or "all"), `reply_timeout`, `faults` (as
`--faults`: "drop=0.01,kill=1", or a table {drop = 0.01, kill = 1}; "" for none), `fault_seed`, `tolerate_faults`,
`tolerate_gaps`, `criteria` (a criteria TOML file, `bench run --criteria`: each run judged by it, its JUnit XML
beside its log as junit.xml) and `baseline` (a stored summary, `--baseline`); and the campaign's own `report`
(false: no per-run report). Each run's log, report and JUnit XML go into its own directory. Paths are relative to
the spec file.

Every problem is one sentence naming the file and the key (`SpecError`, exit status 2), found before anything is
written.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import re
import tomllib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from bench.errors import UsageError
from bench.run.request import OPTION, RUN, SETTABLE, RunRequest
from bench.tomlspec import Check, TableSpec, flag, number, read_spec, spec_tables, string
from target_sim.kinds import MODEL_KINDS as model_kind_table

MODEL_KINDS = model_kind_table.names()
COOLANT_SETPOINTS = (20, 40, 60)
DEFAULT_TIMEOUT_S = 1800.0
SECTIONS = ("campaign", "fixed", "axes")


class SpecError(UsageError):
    """A campaign spec that cannot be used: one sentence naming the file and the key."""


# ---------------------------------------------------------------- option values


def _model(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"must be a model kind ({', '.join(MODEL_KINDS)}) or the path of a model artifact")
    if value in MODEL_KINDS or "/" in value or value.endswith(".json"):
        return value
    raise ValueError(f"unknown model kind {value!r}; use {', '.join(MODEL_KINDS)} or the path of a model "
                     "artifact (a .json file)")


def _data(value: Any) -> int | str:
    if isinstance(value, int) and not isinstance(value, bool):
        if value not in COOLANT_SETPOINTS:
            raise ValueError(f"{value} is not a coolant set point of the generated datasets "
                             f"({', '.join(map(str, COOLANT_SETPOINTS))}); give one of them or a CSV path")
        return value
    if isinstance(value, str) and value.strip():
        return value
    raise ValueError("must be a coolant set point of the generated datasets (20, 40, 60) or a CSV path")


@dataclass(frozen=True)
class Option:
    check: Callable[[Any], Any]
    default: Any
    new: bool = False   # a key added after run ids existed: left out of the id at its default (`run_id`)


# The campaign's own spelling of two run options (a packaged model kind, a generated dataset's set point), and its
# own `report` (false: no per-run report; where it goes is the campaign's, as the log's).
CAMPAIGN_FORMS: dict[str, Option] = {
    "model": Option(_model, "hammerstein"),
    "data": Option(_data, 40),
    "report": Option(flag, True),
}
# the keys run ids were made of before the options came from the run request (`bench.run.request`)
ID_KEYS = ("model", "engine", "data", "mapping", "sample_period", "seed", "mode", "speed", "rows", "reply_timeout",
           "faults", "fault_seed", "tolerate_faults", "tolerate_gaps", "report", "criteria", "baseline")


def _options() -> dict[str, Option]:
    """Every run option a campaign's user sets (`bench.run.request.SETTABLE`, the same names and checks), the
    campaign's own forms of model and data, and `report`."""
    out = {key: CAMPAIGN_FORMS.get(key) or Option(OPTION[key].check, OPTION[key].default, key not in ID_KEYS)
           for key in SETTABLE if RUN in OPTION[key].commands}
    out["report"] = CAMPAIGN_FORMS["report"]
    return out


OPTIONS: dict[str, Option] = _options()


def option_name(key: str) -> str:
    return key.strip().replace("-", "_")


# ---------------------------------------------------------------- runs and campaigns


@dataclass(frozen=True)
class Run:
    """One combination: its id, the axis values that make it, and every option (defaults filled in)."""

    run_id: str
    index: int
    axes: dict[str, Any]
    options: dict[str, Any]
    base_dir: Path             # relative paths in the spec are relative to this

    def path_of(self, key: str) -> Path | None:
        value = self.options.get(key)
        if not isinstance(value, str):
            return None
        path = Path(value).expanduser()
        return (path if path.is_absolute() else self.base_dir / path).resolve()

    def model_path(self) -> Path:
        value = self.options["model"]
        if value in MODEL_KINDS:
            from bench.model.default import default_artifact_path

            return default_artifact_path(value).resolve()
        return self.path_of("model")

    def request(self, run_dir: Path, data: Path) -> RunRequest:
        """The run request of this run: absolute paths, its log, report and JUnit XML in `run_dir`."""
        o = self.options
        paths = {key: self.path_of(key) for key in ("mapping", "criteria", "baseline")}
        judged = o["criteria"] is not None or o["baseline"] is not None
        chosen = {k: v for k, v in o.items() if k in SETTABLE} | paths | {
            "model": self.model_path(), "data": data, "log": run_dir / "bench.blf", "report": run_dir / "report",
            "no_report": not o["report"], "junit_xml": run_dir / "junit.xml" if judged else None}
        return RunRequest(**chosen)

    def argv(self, run_dir: Path, data: Path) -> list[str]:
        """`bench run` arguments (after `run`): the request's, JSON on stdout, on udp_multicast with no channel, so
        the run gets a port of its own."""
        request = self.request(run_dir, data)
        args = request.to_argv(RUN)
        if request.no_report:   # its default report directory would be out/run/report, not the run's
            args = [a for a in args if a != "--report" and a != str(request.report)]
        return [*args, "--json", "--quiet", "-i", "udp_multicast"]

    def label(self) -> str:
        return ", ".join(f"{k}={v}" for k, v in self.axes.items()) or "(the only run)"


@dataclass(frozen=True)
class Campaign:
    path: Path
    text: str
    name: str
    description: str
    timeout_s: float
    axes: dict[str, list[Any]]
    fixed: dict[str, Any]
    runs: list[Run] = field(repr=False)


def run_id(axes: dict[str, Any], options: dict[str, Any]) -> str:
    """A slug of the axis values and a hash of every option: the same run has the same id in any spec, so
    `--resume` recognizes it; a changed option (fixed or not) makes another run."""
    hashed = {k: v for k, v in options.items() if not (OPTIONS[k].new and v == OPTIONS[k].default)}
    digest = hashlib.sha256(json.dumps(hashed, sort_keys=True).encode()).hexdigest()[:10]
    parts = []
    for name, value in axes.items():
        if isinstance(value, str):
            text = Path(value).stem if "/" in value or value.endswith(".json") else value
        else:   # a number or a flag means little without its axis' name
            text = f"{name}{value}"
        parts.append(re.sub(r"[^A-Za-z0-9.]+", "-", text).strip("-.") or "x")
    slug = "_".join(parts)[:48].strip("_-.")
    return f"{slug}-{digest}" if slug else digest


def _set(key: str, value: Any, table: TableSpec) -> Any:
    """The value of `--set KEY=VALUE`, checked as `table` ([fixed] or [axes]) checks its key."""
    if key not in table.keys:
        raise SpecError(f"--set names an unknown option {key!r}; use {', '.join(table.keys)}")
    try:
        return table.keys[key](value)
    except ValueError as exc:
        raise SpecError(f"--set {key} {exc}") from None


def _seconds(value: Any) -> float:
    try:
        return number(value)
    except ValueError as exc:
        raise ValueError(f"{exc} of seconds") from None


def _axis(check: Check) -> Check:
    """An axis of an option: a non-empty list of its values, each checked, none twice."""
    def values(value: Any) -> list[Any]:
        if not isinstance(value, list) or not value:
            raise ValueError("must be a non-empty list of values, e.g. [1, 2]")
        checked, seen = [check(v) for v in value], set()
        for one in checked:
            if json.dumps(one) in seen:
                raise ValueError(f"lists {one!r} twice; give each value once")
            seen.add(json.dumps(one))
        return checked
    return values


# the spec's tables: its head, the options every run shares, the axes swept
HEAD = TableSpec("[campaign]", {"name": string, "description": string, "timeout": _seconds},
                 advice="use name, description, timeout (run options go into [fixed] or [axes])")
FIXED = TableSpec("[fixed]", {key: option.check for key, option in OPTIONS.items()})
AXES = TableSpec("[axes]", {key: _axis(option.check) for key, option in OPTIONS.items()})


def _options_of(table: dict[str, Any]) -> dict[str, Any]:
    """A table's keys as option names (`tolerate-faults` is `tolerate_faults`)."""
    return {option_name(key): value for key, value in table.items()}


def parse_override(text: str) -> tuple[str, Any]:
    """'KEY=VALUE' of --set: VALUE read as a TOML value (300, true, ["a", "b"]), else as a string."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise UsageError(f"--set {text!r} must be KEY=VALUE, e.g. --set rows=2000")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()
    return option_name(key), parsed


def parse_spec(text: str, path: Path, overrides: Iterable[str] = ()) -> Campaign:
    """The campaign of a spec's text (`path` names it in messages and anchors relative paths); `overrides`
    ('KEY=VALUE', --set) replace fixed options, or an axis (a list) or fix it (a single value)."""
    path = Path(path)
    doc = spec_tables(text, str(path), SECTIONS, SpecError)
    head = HEAD.read(doc.get("campaign", {}), str(path), SpecError)
    name, description = head.get("name", path.stem), head.get("description", "")
    timeout_s = head.get("timeout", DEFAULT_TIMEOUT_S)
    fixed = FIXED.read(_options_of(doc.get("fixed", {})), str(path), SpecError)
    axes: dict[str, list[Any]] = AXES.read(_options_of(doc.get("axes", {})), str(path), SpecError)
    for key, value in (parse_override(o) for o in overrides):
        if isinstance(value, list):
            fixed.pop(key, None)
            axes[key] = _set(key, value, AXES)
        else:
            axes.pop(key, None)
            fixed[key] = _set(key, value, FIXED)
    both = sorted(set(fixed) & set(axes))
    if both:
        raise SpecError(f"{path}: {both[0]} is both in [fixed] and in [axes]; keep it in one of them")
    campaign = Campaign(path, text, name, description, timeout_s, axes, fixed, _expand(axes, fixed, path.parent))
    _check_runs(campaign)
    return campaign


def _expand(axes: dict[str, list[Any]], fixed: dict[str, Any], base_dir: Path) -> list[Run]:
    runs = []
    for index, values in enumerate(itertools.product(*axes.values())):
        chosen = dict(zip(axes, values, strict=True))
        options = {k: opt.default for k, opt in OPTIONS.items()} | fixed | chosen
        runs.append(Run(run_id(chosen, options), index, chosen, options, base_dir.resolve()))
    return runs


def _check_runs(campaign: Campaign) -> None:
    """What only a whole combination, or the files it names, can show: missing files, artifacts that do not load,
    kill/freeze in real time, the firmware engine on a model it cannot run."""
    where = campaign.path
    checked: dict[Path, str | None] = {}
    gates: set[tuple[Path | None, Path | None]] = set()
    for run in campaign.runs:
        o = run.options
        gate = (run.path_of("criteria"), run.path_of("baseline"))
        if gate != (None, None) and gate not in gates:   # a bad criteria file: refused before any run
            from bench.acceptance.criteria import CriteriaError, load_gate

            try:
                load_gate(*gate)
            except CriteriaError as exc:
                raise SpecError(f"{where}: run {run.label()}: {exc}") from None
            gates.add(gate)
        for key in ("data", "mapping"):
            p = run.path_of(key)
            if p is not None and not p.is_file():
                raise SpecError(f"{where}: {key} {o[key]!r} is not a file ({p}); fix the path (relative paths are "
                                "relative to the spec)")
        model = run.model_path()
        if model not in checked:
            checked[model] = _model_problem(model, o["model"])
        if checked[model] is not None:
            raise SpecError(f"{where}: model {o['model']!r}: {checked[model]}")
        if o["engine"] == "firmware":
            from target_sim.artifact import load_artifact
            from target_sim.firmware.node_protocol import firmware_refusal

            refusal = firmware_refusal(load_artifact(model))
            if refusal is not None:
                raise SpecError(f"{where}: run {run.label()}: {refusal}")
        if o["isr_rate"]:   # the same refusal as `bench run`'s, before any run
            from bench.run.prepare import refuse_isr_rate

            try:
                refuse_isr_rate(SimpleNamespace(isr_rate=o["isr_rate"], engine=o["engine"]))
            except UsageError as exc:
                raise SpecError(f"{where}: run {run.label()}: {exc}") from None
        if o["faults"] and o["mode"] != "lockstep" and re.search(r"(^|,)\s*(kill|freeze)", o["faults"]):
            raise SpecError(f"{where}: run {run.label()} has kill or freeze faults in {o['mode']} mode; they need "
                            "lockstep (a lost target's rows cannot be sent again on a real-time clock)")


def _model_problem(path: Path, value: str) -> str | None:
    if not path.is_file():
        return f"{path} is not a file; give a model kind ({', '.join(MODEL_KINDS)}) or an artifact's path"
    from target_sim.artifact import ArtifactError, load_artifact

    try:
        load_artifact(path)
    except ArtifactError as exc:
        return str(exc)
    return None


def load_spec(path: Path, overrides: Iterable[str] = ()) -> Campaign:
    """The campaign of the spec file `path` (SpecError, one sentence, for a missing or bad one)."""
    path = Path(path)
    text = read_spec(path, "the campaign spec", "give the path of a TOML spec, e.g. examples/campaigns/smoke.toml",
                     SpecError)
    return parse_spec(text, path, overrides)
