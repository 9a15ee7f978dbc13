"""A run's preparation, shared by `bench run` and `bench host`: every refusal its request and files can give,
before any work (the log's path and the names beside it, the report directory, the model and what the engine and
the frames can carry, the data and what the model needs of it, the acceptance gate's data identity), and what the
run then needs: the model, the dataset, the rows the host sends and the observer's measurements."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bench.errors import UsageError
from bench.fileio import check_writable
from bench.run.inputs import (
    data_options,
    drive_for,
    load_data,
    load_model,
    measurements_for,
    refuse_engine,
    refuse_over_can,
)
from bench.run.request import RUN
from dbc.files import NAME_MAX
from host.canlog import check_log_path

if TYPE_CHECKING:
    from bench.drive.dataset import Dataset
    from host.faults import FaultSpec
    from target_sim.artifact import ModelArtifact


@dataclass(frozen=True)
class PreparedRun:
    """What a run needs once its request is accepted."""

    log_path: Path
    artifact: ModelArtifact
    model_path: Path
    dataset: Dataset
    drive: np.ndarray
    measurements: np.ndarray | None


def check_log_names(log_path: Path, faults: FaultSpec | None, firmware: bool = False) -> None:
    """UsageError, before anything runs, when a file written beside the log would need a name longer than NAME_MAX
    (through its temporary name, `.<name>.XXXXXXXX`): with faults, the summary `<log>.faults.json`; on the firmware
    engine, the note of its ELF `<log>.elf.json` (`bench.run.elfnote`)."""
    from bench.run.elfnote import note_path
    from host.faults import sidecar_path

    beside = ([("the fault summary", sidecar_path(log_path).name)] if faults is not None and faults.active else []) \
        + ([("the note of its firmware ELF", note_path(log_path).name)] if firmware else [])
    for what, name in beside:
        length = len(os.fsencode(name)) + 10
        if length > NAME_MAX:
            raise UsageError(f"--log {log_path}: {what} beside it, {name}, would need a file name of {length} bytes "
                             f"(its temporary name), more than the {NAME_MAX} a name may have; shorten the log's "
                             f"name by {length - NAME_MAX} characters")


def refuse_isr_rate(request: Any) -> None:
    """--isr-rate needs the firmware engine and a current-loop rate (UsageError, one sentence)."""
    if not request.isr_rate:
        return
    if request.engine != "firmware":
        raise UsageError(f"--isr-rate runs the motor-control interrupt in the emulated core of the firmware engine, "
                         f"not the {request.engine} engine; add --engine firmware or drop --isr-rate")
    from target_sim.firmware.motor_control import isr_rate_problem

    problem = isr_rate_problem(request.isr_rate)
    if problem:
        raise UsageError(problem)


def check_outputs(request: Any, command: str, faults: FaultSpec | None) -> Path:
    """The log's path, once it and the report directory (`bench run` without --no-report) are known writable:
    a log or report that cannot be written must not cost a run."""
    log_path = check_log_path(request.log)
    check_writable(log_path, "--log")   # a directory there would fail the run only at its end
    check_log_names(log_path, faults, getattr(request, "engine", None) == "firmware")
    if command == RUN and not request.no_report:
        from bench.analysis.report import check_report_dir

        check_writable(Path(request.report), "--report", directory=True)
        check_report_dir(Path(request.report))   # a directory of other files would be refused only after the run
    return log_path


def load_run_data(request: Any, artifact: ModelArtifact, quiet: bool) -> tuple[Dataset, np.ndarray, np.ndarray | None]:
    """The run's dataset (--data through --mapping at --sample-period), the drive rows the host sends (4 values per
    row, 6 with the d/q currents for an electrical loss model) and, for a model with an observer, the measurements
    (`bench.run.inputs.measurements_for`; else None): BenchError, one sentence, when the data lacks what the model
    needs or its sample period is not the model's."""
    if request.data is None and request.mapping is not None:
        raise UsageError("--mapping says how to read your own data file: pass it with --data FILE")
    mapping, period = data_options(request)
    dataset = load_data(request.data, artifact, request.seed, quiet=quiet, mapping=mapping, sample_period_s=period)
    drive = drive_for(dataset, artifact)
    measurements = measurements_for(dataset, artifact)
    if request.rows is not None:
        drive = drive[: request.rows]
        measurements = None if measurements is None else measurements[: request.rows]
    return dataset, drive, measurements


def prepare_run(request: Any, command: str, faults: FaultSpec | None, check_data: Callable[[Any, str], None], *,
                quiet: bool) -> PreparedRun:
    """Every refusal of a run (`request`, a `bench.run.request.RunRequest`, for `command` run or host), in the order
    a user meets them, before any work; `check_data`: the acceptance gate's check of the data's identity."""
    from bench.analysis.results import DataIdentity

    if command == RUN:
        refuse_isr_rate(request)   # what the request alone refuses comes first
    log_path = check_outputs(request, command, faults)
    artifact, model_path = load_model(request.model)
    if command == RUN:
        refuse_engine(request.engine, artifact)   # a model this engine cannot run
    refuse_over_can(artifact)                      # an observer whose readings no frame carries
    dataset, drive, measurements = load_run_data(request, artifact, quiet)   # data it cannot run on
    check_data(DataIdentity(len(drive), dataset.rows_sha256(len(drive))), f"this run of {dataset.path}")
    return PreparedRun(log_path, artifact, model_path, dataset, drive, measurements)
