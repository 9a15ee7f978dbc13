"""The JUnit XML of a bench command (`--junit-xml FILE`), the format GitLab, GitHub and Jenkins render.

One <testsuite> per command, one <testcase> for "clean" (the command's own verdict) and one per acceptance
criterion. A criterion's figure, limit, unit and kind are <properties> of its testcase and are in its <failure
message>; the log and the report are <properties> of the suite and `[[ATTACHMENT|path]]` lines in each testcase's
<system-out> (Jenkins' attachments, GitLab's test report). The file is written whole (a temporary file renamed).
"""

from __future__ import annotations

import socket
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from bench.analysis.results import Acceptance, CheckResult
from bench.fileio import write_bytes_atomically

CRITERION_FAILURE = "AcceptanceCriterion"
NOT_CLEAN = "NotClean"


@dataclass(frozen=True)
class CleanCase:
    """The command's own verdict: passed, the sentence, and the problems behind it."""

    passed: bool
    sentence: str
    problems: tuple[str, ...] = ()


def _properties(parent: ET.Element, values: dict[str, object]) -> None:
    props = ET.SubElement(parent, "properties")
    for name, value in values.items():
        if value is not None:
            ET.SubElement(props, "property", name=name, value=str(value))


def _system_out(case: ET.Element, attachments: list[str], text: str = "") -> None:
    lines = ([text] if text else []) + [f"[[ATTACHMENT|{Path(p).resolve()}]]" for p in attachments]
    if lines:
        ET.SubElement(case, "system-out").text = "\n".join(lines)


def _figure(value: float | None) -> str:
    return "none" if value is None else f"{value:.6g}"


def _criterion_case(suite: ET.Element, classname: str, check: CheckResult, attachments: list[str]) -> ET.Element:
    case = ET.SubElement(suite, "testcase", classname=f"{classname}.criteria", name=check.name, time="0")
    _properties(case, {"kind": check.kind, "what": check.what, "figure": _figure(check.figure),
                       "limit": f"{check.limit:g}", "unit": check.unit or None, "verdict": check.verdict,
                       "source": check.source})
    if not check.passed:
        failure = ET.SubElement(case, "failure", message=check.message, type=CRITERION_FAILURE)
        failure.text = (f"{check.what}: figure {_figure(check.figure)} {check.unit}, limit {check.limit:g} "
                        f"{check.unit}".rstrip())
    _system_out(case, attachments, check.message)
    return case


def _suite(command: str, tests: int, failures: int, errors: int, elapsed_s: float) -> tuple[ET.Element, ET.Element]:
    """The document's root <testsuites> and its one <testsuite> named `command`, both with the counts."""
    counts = {"tests": str(tests), "failures": str(failures), "errors": str(errors), "skipped": "0",
              "time": f"{elapsed_s:.3f}"}
    root = ET.Element("testsuites", name="bench", **counts)
    suite = ET.SubElement(root, "testsuite", name=command, **counts,
                          timestamp=datetime.now(UTC).replace(microsecond=0).isoformat(),
                          hostname=socket.gethostname())
    return root, suite


def junit_document(command: str, clean: CleanCase, acceptance: Acceptance | None, *, elapsed_s: float,
                   properties: dict[str, object], attachments: list[str]) -> bytes:
    """The JUnit XML (UTF-8 bytes) of one command: `command` names the suite ("bench run")."""
    checks = acceptance.checks if acceptance is not None else []
    failures = (0 if clean.passed else 1) + sum(1 for c in checks if not c.passed)
    tests = 1 + len(checks)
    root, suite = _suite(command, tests, failures, 0, elapsed_s)
    _properties(suite, {**properties, **({"criteria": acceptance.criteria, "baseline": acceptance.baseline}
                                          if acceptance is not None else {})})
    classname = command.replace(" ", ".")
    case = ET.SubElement(suite, "testcase", classname=classname, name="clean", time=f"{elapsed_s:.3f}")
    _properties(case, {"verdict": "pass" if clean.passed else "fail", "problems": len(clean.problems)})
    if not clean.passed:
        failure = ET.SubElement(case, "failure", message=clean.sentence, type=NOT_CLEAN)
        failure.text = "\n".join(clean.problems) or clean.sentence
    _system_out(case, attachments, clean.sentence)
    for check in checks:
        _criterion_case(suite, classname, check, attachments)
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def write_junit(path: Path, command: str, clean: CleanCase, acceptance: Acceptance | None, *, elapsed_s: float,
                properties: dict[str, object], attachments: list[str]) -> None:
    """`path` holds the whole JUnit XML, or is as it was (a temporary file renamed into place)."""
    payload = junit_document(command, clean, acceptance, elapsed_s=elapsed_s, properties=properties,
                             attachments=[a for a in attachments if a])
    write_bytes_atomically(Path(path), payload, "the JUnit XML")


def write_junit_error(path: Path, command: str, sentence: str, criteria: list[str], *, elapsed_s: float) -> None:
    """The JUnit XML of a command that ended before its verdict (the target died, the log could not be written):
    "clean" and each criterion an <error> with the command's sentence, so the CI page still says what happened."""
    root, suite = _suite(command, 1 + len(criteria), 0, 1 + len(criteria), elapsed_s)
    classname = command.replace(" ", ".")
    for name, cls, message in [("clean", classname, sentence),
                               *((c, f"{classname}.criteria", f"not judged: {sentence}") for c in criteria)]:
        case = ET.SubElement(suite, "testcase", classname=cls, name=name, time="0")
        ET.SubElement(case, "error", message=message, type="CommandError").text = message
    ET.indent(root)
    write_bytes_atomically(Path(path), ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n",
                           "the JUnit XML")
