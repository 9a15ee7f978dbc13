"""The JUnit XML of a bench command (`--junit-xml FILE`), the format GitLab, GitHub and Jenkins render, written with
junitparser (the library the CI world reads it with).

One <testsuite> per command, one <testcase> for "clean" (the command's own verdict) and one per acceptance
criterion. A criterion's figure, limit, unit and kind are <properties> of its testcase and are in its <failure
message>; the log and the report are <properties> of the suite and `[[ATTACHMENT|path]]` lines in each testcase's
<system-out> (Jenkins' attachments, GitLab's test report). An attachment's path is relative to the project
directory (`attachment_path`), as GitLab requires. The file is written whole (a temporary file renamed).
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from xml.dom.minidom import parseString

from junitparser import Error, Failure, JUnitXml, Properties, Property, TestCase, TestSuite

from bench.analysis.results import Acceptance, CheckResult
from bench.fileio import write_bytes_atomically

CRITERION_FAILURE = "AcceptanceCriterion"
NOT_CLEAN = "NotClean"
COMMAND_ERROR = "CommandError"
# GitLab resolves an attachment against the project directory, which a job names in this variable (and runs in);
# elsewhere (Jenkins runs a step in its workspace, a developer in the checkout) the command's directory is it
PROJECT_DIR_VARIABLE = "CI_PROJECT_DIR"


@dataclass(frozen=True)
class CleanCase:
    """The command's own verdict: passed, the sentence, and the problems behind it."""

    passed: bool
    sentence: str
    problems: tuple[str, ...] = ()


def project_dir() -> Path:
    """The directory attachments are relative to: $CI_PROJECT_DIR in a GitLab job, else the current directory."""
    return Path(os.environ.get(PROJECT_DIR_VARIABLE) or Path.cwd())


def attachment_path(path: str | Path, base: Path | None = None) -> str:
    """`path` as an attachment names it: relative to `base` (default `project_dir()`) with `/` separators, what
    GitLab and Jenkins resolve; a file outside it (which GitLab cannot serve) keeps its absolute path."""
    resolved = Path(path).resolve()
    root = (base if base is not None else project_dir()).resolve()
    return resolved.relative_to(root).as_posix() if resolved.is_relative_to(root) else str(resolved)


def _properties(parent: TestCase | TestSuite, values: dict[str, object]) -> None:
    props = Properties()
    for name, value in values.items():
        if value is not None:
            props.add_property(Property(name, str(value)))
    parent.append(props)


def _system_out(case: TestCase, attachments: list[str], text: str = "") -> None:
    lines = ([text] if text else []) + [f"[[ATTACHMENT|{attachment_path(p)}]]" for p in attachments]
    if lines:
        case.system_out = "\n".join(lines)


def _figure(value: float | None) -> str:
    return "none" if value is None else f"{value:.6g}"


def _result(kind: type[Failure] | type[Error], message: str, type_: str, text: str) -> Failure | Error:
    result = kind(message, type_)
    result.text = text
    return result


def _criterion_case(classname: str, check: CheckResult, attachments: list[str]) -> TestCase:
    case = TestCase(check.name, f"{classname}.criteria", 0.0)
    _properties(case, {"kind": check.kind, "what": check.what, "figure": _figure(check.figure),
                       "limit": f"{check.limit:g}", "unit": check.unit or None, "verdict": check.verdict,
                       "source": check.source})
    if not check.passed:
        case.append(_result(Failure, check.message, CRITERION_FAILURE,
                            f"{check.what}: figure {_figure(check.figure)} {check.unit}, limit {check.limit:g} "
                            f"{check.unit}".rstrip()))
    _system_out(case, attachments, check.message)
    return case


def _clean_case(classname: str, clean: CleanCase, elapsed_s: float, attachments: list[str]) -> TestCase:
    case = TestCase("clean", classname, round(elapsed_s, 3))
    _properties(case, {"verdict": "pass" if clean.passed else "fail", "problems": len(clean.problems)})
    if not clean.passed:
        case.append(_result(Failure, clean.sentence, NOT_CLEAN, "\n".join(clean.problems) or clean.sentence))
    _system_out(case, attachments, clean.sentence)
    return case


def _document(command: str, cases: list[TestCase], properties: dict[str, object]) -> bytes:
    """The <testsuites> of one <testsuite> named `command` holding `cases`, its counts and time from the cases
    (the "clean" case carries the command's time), as UTF-8 bytes."""
    suite = TestSuite(command)
    suite.timestamp = datetime.now(UTC).replace(microsecond=0).isoformat()
    suite.hostname = socket.gethostname()
    if properties:
        _properties(suite, properties)
    suite.add_testcases(cases)
    root = JUnitXml("bench")
    root.add_testsuite(suite)
    root.update_statistics()
    # indented as junitparser's own `write(pretty=True)` does it, into bytes (its `write` takes a file only since 4)
    return parseString(root.tostring()).toprettyxml(indent="  ", encoding="utf-8")


def junit_document(command: str, clean: CleanCase, acceptance: Acceptance | None, *, elapsed_s: float,
                   properties: dict[str, object], attachments: list[str]) -> bytes:
    """The JUnit XML (UTF-8 bytes) of one command: `command` names the suite ("bench run")."""
    checks = acceptance.checks if acceptance is not None else []
    classname = command.replace(" ", ".")
    cases = [_clean_case(classname, clean, elapsed_s, attachments),
             *(_criterion_case(classname, check, attachments) for check in checks)]
    judged = {"criteria": acceptance.criteria, "baseline": acceptance.baseline} if acceptance is not None else {}
    return _document(command, cases, {k: v for k, v in {**properties, **judged}.items() if v is not None})


def write_junit(path: Path, command: str, clean: CleanCase, acceptance: Acceptance | None, *, elapsed_s: float,
                properties: dict[str, object], attachments: list[str]) -> None:
    """`path` holds the whole JUnit XML, or is as it was (a temporary file renamed into place)."""
    payload = junit_document(command, clean, acceptance, elapsed_s=elapsed_s, properties=properties,
                             attachments=[a for a in attachments if a])
    write_bytes_atomically(Path(path), payload, "the JUnit XML")


def junit_error_document(command: str, sentence: str, criteria: list[str], *, elapsed_s: float) -> bytes:
    """The JUnit XML of a command that ended before its verdict: "clean" and each criterion an <error>."""
    classname = command.replace(" ", ".")
    cases = []
    for name, cls, message, seconds in [("clean", classname, sentence, round(elapsed_s, 3)),
                                        *((c, f"{classname}.criteria", f"not judged: {sentence}", 0.0)
                                          for c in criteria)]:
        case = TestCase(name, cls, seconds)
        case.append(_result(Error, message, COMMAND_ERROR, message))
        cases.append(case)
    return _document(command, cases, {})


def write_junit_error(path: Path, command: str, sentence: str, criteria: list[str], *, elapsed_s: float) -> None:
    """The JUnit XML of a command that ended before its verdict (the target died, the log could not be written):
    "clean" and each criterion an <error> with the command's sentence, so the CI page still says what happened."""
    write_bytes_atomically(Path(path), junit_error_document(command, sentence, criteria, elapsed_s=elapsed_s),
                           "the JUnit XML")
