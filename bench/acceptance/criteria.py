"""Acceptance criteria: a TOML file of named checks, read and checked before any work, judged on a run's figures.

    baseline = "baseline.json"        # optional: the stored summary a regression criterion compares with

    [criteria.pm_rmse]                # the check's name (in the JSON, the report and the JUnit XML)
    kind = "rmse"                     # one of `bench.acceptance.kinds.KINDS`
    nodes = "magnet"
    against = "measured"
    max = 3.0                         # the limit: the figure must not exceed it (regression: max_worse_percent)

Every problem of the file (not TOML, an unknown kind or key, a missing or negative limit, a regression criterion
without a baseline, a baseline that is no summary of this bench) is one sentence naming the file and the key, exit
status 2, before anything runs (`CriteriaError`). `--baseline FILE` without a regression criterion adds the default
one: "no node's RMSE more than 5 % worse".
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.acceptance.kinds import KINDS, NODES, Criterion, Subject, number
from bench.analysis.results import Acceptance, CheckResult, DataIdentity, ResultsError, RunResults
from bench.errors import UsageError
from bench.tomlspec import TableSpec, read_spec, spec_tables, string

UNKNOWN_KEY = 'has an unknown key {key!r}; it holds [criteria.NAME] tables and an optional baseline = "FILE"'
DEFAULT_REGRESSION = Criterion("regression", "regression", 5.0, {"figure": "rmse", "nodes": NODES, "floor": 0.01})


class CriteriaError(UsageError):
    """A criteria or baseline file that cannot be used: one sentence naming the file and the key (exit status 2)."""


@dataclass(frozen=True)
class CriteriaSet:
    """The criteria of a file (path None: only the default regression of --baseline), and its baseline file."""

    path: Path | None
    criteria: tuple[Criterion, ...]
    baseline: Path | None = None


def parse_criterion(name: str, table: Any, where: str) -> Criterion:
    """One `[criteria.NAME]` table as a Criterion (CriteriaError naming `where` and the key)."""
    at = f"{where}: [criteria.{name}]"
    if not isinstance(table, dict):
        raise CriteriaError(f"{at} must be a table with a kind and a limit")
    kind_name = table.get("kind")
    if not isinstance(kind_name, str) or kind_name not in KINDS:
        raise CriteriaError(f"{at} kind {kind_name!r} is not a kind of criterion; use one of {', '.join(KINDS)}")
    kind = KINDS[kind_name]
    if kind.limit_key not in table:
        raise CriteriaError(f"{at} has no limit; give {kind.limit_key} = NUMBER ({kind.summary})")
    keys = {"kind": string, kind.limit_key: number, **kind.options}
    values = TableSpec(f"[criteria.{name}]", keys,
                       advice=f"a {kind_name} criterion takes {', '.join(list(keys)[1:])}").read(table, where,
                                                                                                   CriteriaError)
    limit = values.pop(kind.limit_key)
    params = {}
    for key, parse in kind.options.items():    # an option left out takes the kind's default, checked alike
        if key in values:
            params[key] = values[key]
            continue
        try:
            params[key] = parse(kind.defaults.get(key))
        except ValueError as exc:
            raise CriteriaError(f"{at} {key} {exc}") from None
    return Criterion(name, kind_name, limit, params)


def parse_criteria(text: str, path: Path) -> CriteriaSet:
    """The criteria of a file's text (`path` names it and anchors a relative baseline)."""
    where = str(path)
    # [criteria.NAME] tables and the baseline path, both checked below with sentences of their own
    doc = spec_tables(text, f"the criteria file {where}", (), CriteriaError, keys=("criteria", "baseline"),
                      fix="fix it", unknown=UNKNOWN_KEY)
    tables = doc.get("criteria")
    if not isinstance(tables, dict) or not tables:
        raise CriteriaError(f"the criteria file {where} has no criteria; add [criteria.NAME] tables with a kind "
                            f"({', '.join(KINDS)}) and a limit")
    baseline = doc.get("baseline")
    if baseline is not None and (not isinstance(baseline, str) or not baseline.strip()):
        raise CriteriaError(f"the criteria file {where}: baseline must be the path of a summary JSON file")
    criteria = tuple(parse_criterion(name, table, where) for name, table in tables.items())
    return CriteriaSet(path, criteria, (path.parent / baseline) if baseline else None)


def load_criteria(path: Path) -> CriteriaSet:
    """The criteria file at `path` (CriteriaError, one sentence, if it is missing or bad)."""
    path = Path(path)
    text = read_spec(path, "the criteria file", "give the path of a TOML file of [criteria.NAME] tables, e.g. "
                     "examples/ci/criteria.toml", CriteriaError)
    return parse_criteria(text, path)


def load_baseline(path: Path, named_in: Path | None = None) -> RunResults:
    """The figures of a stored summary: the --json of bench run (its "metrics"), bench host or bench analyze, or a
    report's metrics.json (CriteriaError, one sentence, for anything else; `named_in`: the criteria file that
    names it, said in the sentence)."""
    path = Path(path)
    where = f"the baseline {path}" + (f" (named in the criteria file {named_in})" if named_in else "")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CriteriaError(f"{where} does not exist; store a run's summary first, e.g. "
                            "'bench run --json > baseline.json'") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise CriteriaError(f"{where} is not a readable JSON file ({exc}); store a run's summary, "
                            "e.g. 'bench run --json > baseline.json'") from None
    if isinstance(data, dict) and isinstance(data.get("metrics"), dict):
        data = data["metrics"]
    try:
        return RunResults.from_json(data)
    except (ResultsError, TypeError) as exc:
        raise CriteriaError(f"{where} is not a summary this bench can compare with ({exc})") from None


@dataclass(frozen=True)
class Gate:
    """Criteria ready to judge: read and checked, the baseline loaded."""

    criteria: CriteriaSet
    baseline: RunResults | None = None
    baseline_path: Path | None = None

    def check_data(self, identity: DataIdentity | None, subject: str) -> None:
        """CriteriaError (one sentence, before any work) when the baseline is a run on other data than `subject`
        replays: its figures are no baseline for this run. A baseline (or subject) without a data identity, from
        a bench before it was recorded or a log no dataset matched, is compared as it is."""
        stored = self.baseline.data if self.baseline is not None else None
        if stored is None or identity is None:
            return
        why = identity.differs_from(stored)
        if why:
            raise CriteriaError(f"the baseline {self.baseline_path} is a run on other data ({why}) than {subject}; "
                                "store a baseline of this data, e.g. 'bench run ... --json > baseline.json'")

    def _other_data(self, results: RunResults | None) -> str | None:
        """Why the baseline's figures are of other data than `results`' (None when they are not known to be)."""
        if results is None or results.data is None or self.baseline is None or self.baseline.data is None:
            return None
        why = results.data.differs_from(self.baseline.data)
        return f"the baseline {self.baseline_path} is a run on other data: {why}" if why else None

    def judge(self, results: RunResults | None, why_none: str = "the run has no figures") -> Acceptance:
        """Each criterion on `results`; with no results every criterion fails, saying `why_none`."""
        subject = Subject(results, self.baseline, str(self.baseline_path) if self.baseline_path else None)
        other = self._other_data(results)
        checks = [_unjudged(c, why_none) if results is None else
                  _unjudged(c, other) if other and c.kind == "regression" else KINDS[c.kind].judge(c, subject)
                  for c in self.criteria.criteria]
        return Acceptance(criteria=str(self.criteria.path) if self.criteria.path else None,
                          baseline=subject.baseline_path, checks=checks)


def _unjudged(criterion: Criterion, why: str) -> CheckResult:
    kind = KINDS[criterion.kind]
    return CheckResult(name=criterion.name, kind=criterion.kind, what=kind.summary, figure=None,
                       limit=criterion.limit, unit=kind.unit, passed=False,
                       message=f"{criterion.name}: cannot be judged ({why})")


def load_gate(criteria: Path | None, baseline: Path | None) -> Gate | None:
    """The gate of --criteria and --baseline (None when neither is given), checked before any work: a regression
    criterion needs a baseline; --baseline without one adds the default regression criterion."""
    if criteria is None and baseline is None:
        return None
    found = load_criteria(criteria) if criteria is not None else CriteriaSet(None, ())
    baseline = Path(baseline) if baseline is not None else found.baseline
    regressions = [c for c in found.criteria if c.kind == "regression"]
    if regressions and baseline is None:
        raise CriteriaError(f"the criteria file {found.path}: [criteria.{regressions[0].name}] is a regression "
                            "criterion and no baseline is given; pass --baseline FILE or set baseline = \"FILE\" "
                            "in the file")
    if baseline is not None and not regressions:
        found = CriteriaSet(found.path, (*found.criteria, DEFAULT_REGRESSION), found.baseline)
    named_in = found.path if baseline == found.baseline else None
    return Gate(found, load_baseline(baseline, named_in) if baseline is not None else None, baseline)
