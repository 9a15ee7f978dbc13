"""The acceptance options of `bench run`, `bench host`, `bench analyze` and `bench replay`: --criteria FILE,
--baseline FILE and --junit-xml FILE, read and checked before any work (`prepare`), and the end of such a
command (`finish`; `finish_run` for a run's summary): the JUnit XML written, the failed criteria named in one
sentence, the exit status. `add_acceptance_arguments` is all the commands need to build their parsers: the criteria,
the JUnit writer and the results are imported when a command is prepared and finished."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from bench.fileio import check_writable
from bench.run.request import RUN, add_options

if TYPE_CHECKING:
    from bench.acceptance.criteria import Gate
    from bench.acceptance.junit import CleanCase
    from bench.analysis.results import Acceptance, RunSummary


def add_acceptance_arguments(parser: argparse.ArgumentParser) -> None:
    """--criteria, --baseline, --junit-xml, as `bench run` has them (`bench.run.request`)."""
    add_options(parser, RUN, ("criteria", "baseline", "junit_xml"))


@dataclass(frozen=True)
class Acceptor:
    """What --criteria, --baseline and --junit-xml asked for, checked before any work."""

    gate: Gate | None
    junit_xml: Path | None

    def judge(self, results, why_none: str = "the run has no figures") -> Acceptance | None:
        return self.gate.judge(results, why_none) if self.gate is not None else None

    def check_data(self, identity, subject: str) -> None:
        """A baseline of other data than `subject` replays: refused before any work (`Gate.check_data`)."""
        if self.gate is not None:
            self.gate.check_data(identity, subject)


def prepare(args: argparse.Namespace) -> Acceptor:
    """The criteria and baseline read, the JUnit path checked: a bad one is one sentence, before any work."""
    from bench.acceptance.criteria import load_gate

    junit = getattr(args, "junit_xml", None)
    if junit is not None:
        check_writable(junit, "--junit-xml")
    return Acceptor(load_gate(getattr(args, "criteria", None), getattr(args, "baseline", None)), junit)


def finish(acceptor: Acceptor, acceptance: Acceptance | None, *, command: str, subject: str, status: int,
           clean: CleanCase, elapsed_s: float, properties: dict[str, object], attachments: list[str],
           quiet: bool = False) -> int:
    """The command's exit status once the criteria are judged (1 when any fails: the sentence names each failed
    one on stderr, with --json too), after the JUnit XML is written when asked for."""
    if acceptor.junit_xml is not None:
        from bench.acceptance.junit import write_junit

        write_junit(acceptor.junit_xml, command, clean, acceptance, elapsed_s=elapsed_s, properties=properties,
                    attachments=attachments)
    if acceptance is None:
        return status
    if not acceptance.passed:
        print(f"bench: error: {acceptance.sentence(subject)}", file=sys.stderr)
        return max(status, 1)
    if not quiet:
        print(f"bench: {acceptance.sentence(subject)}", file=sys.stderr)
    return status


def finish_run(acceptor: Acceptor, summary: RunSummary, *, command: str, subject: str, status: int, bus: str,
               model_id: str, quiet: bool) -> int:
    """`finish` for a run (`bench run`, `bench host`): its summary's criteria, verdict, log and report; `status`:
    the verdict's exit status, `bus`: the bus as the run describes it."""
    from bench.acceptance.junit import CleanCase

    metrics = summary.metrics
    log = metrics.integrity.log if metrics is not None else summary.log_path
    report = metrics.report if metrics is not None else None
    return finish(acceptor, summary.acceptance, command=command, subject=subject, status=status,
                  clean=CleanCase(status == 0, summary.verdict, tuple(summary.problems)),
                  elapsed_s=summary.elapsed_s, quiet=quiet,
                  properties={"model": model_id, "engine": summary.engine, "bus": bus, "log": log, "report": report},
                  attachments=[log, report])


def junit_after_error(args: argparse.Namespace | None, sentence: str, elapsed_s: float) -> None:
    """After a command with --junit-xml ended on an error (exit status 1, not a bad argument): the JUnit XML with
    that sentence as the error of each testcase. Nothing when it cannot be written (the error is said already)."""
    path = getattr(args, "junit_xml", None)
    if path is None:
        return
    from bench.acceptance.criteria import CriteriaError, load_gate
    from bench.acceptance.junit import write_junit_error
    from bench.errors import BenchError

    try:
        gate = load_gate(getattr(args, "criteria", None), getattr(args, "baseline", None))
    except CriteriaError:
        gate = None
    names = [c.name for c in gate.criteria.criteria] if gate is not None else []
    try:
        check_writable(path, "--junit-xml")
        write_junit_error(path, f"bench {args.command}", sentence, names, elapsed_s=elapsed_s)
    except (BenchError, OSError):
        pass
