"""What a run needs before anything starts: the model artifact, the drive data checked against it (sample period,
d/q currents, the observer's measurement column), the rows (and measurements) the host sends, and the firmware image
for the firmware engine.

`matching_dataset` finds the dataset in out/data a log was recorded from (its measured reference, for `bench
analyze` and the figures of `bench replay`). The default dataset (the 40 °C validation run) is generated in out/data
when missing; the firmware image of an artifact that ships none is built once into a cache directory.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bench.errors import BenchError, UsageError
from target_sim.artifact import ModelArtifact, load_artifact
from target_sim.losses import reads_currents

if TYPE_CHECKING:
    from bench.drive.dataset import ColumnMapping, Dataset


def load_model(path: str | Path | None) -> tuple[ModelArtifact, Path]:
    """The artifact at `path` (default: the packaged one) and its path (ArtifactError, one sentence, if unusable)."""
    from bench.model.default import default_artifact_path

    model_path = Path(path) if path else default_artifact_path()
    return load_artifact(model_path), model_path


def refuse_engine(engine: str, artifact: ModelArtifact) -> None:
    """BenchError (one sentence) when `engine` cannot run `artifact` (the firmware engine: a loss model or an observer
    its generated C lacks); a command calls it before any work."""
    if engine != "firmware":
        return
    from target_sim.firmware.node_protocol import firmware_refusal

    refuse_over_can(artifact)      # an observer no frame carries (the flux linkage): exit 2, as on the python engine

    refusal = firmware_refusal(artifact)
    if refusal is not None:
        raise BenchError(refusal)


def firmware_for_engine(engine: str, artifact: ModelArtifact, cache_dir: Path, *, quiet: bool = True,
                        isr: bool = False) -> Path | None:
    """The ELF the target runs with `engine` "firmware" (None for "python"): the packaged one of a packaged
    artifact, else built once into `cache_dir` (BenchError, one sentence, without the compiler, or for a model the
    firmware cannot run); with `isr` the timing image with the motor-control interrupt (always built, cached)."""
    if engine != "firmware":
        return None
    refuse_engine(engine, artifact)
    from bench.firmware.images import firmware_for

    return firmware_for(artifact, cache_dir, quiet=quiet, isr=isr)


def load_data(path: str | Path | None, artifact: ModelArtifact | None = None, seed: int | None = None,
              quiet: bool = True, *, mapping: ColumnMapping | None = None,
              sample_period_s: float | None = None) -> Dataset:
    """The dataset (default: the generated 40 °C validation run, made in out/data if missing).

    A user's own file is read through `mapping` (a `bench.drive.dataset.ColumnMapping`, from --mapping) at
    `sample_period_s` (--sample-period; None: the mapping's, else the artifact's). The data's sample period must be
    the one the artifact's model runs on (BenchError, one sentence, if not)."""
    from bench.drive.dataset import load_dataset
    from bench.drive.generate import ensure_default_datasets

    if path is None:
        if not quiet and not Path("out/data/cycle_coolant40.csv").is_file():
            print("bench: generating the default datasets in out/data (once)", file=sys.stderr)
        path = ensure_default_datasets(Path("out/data"), seed)[40]
    given = sample_period_s if sample_period_s is not None else getattr(mapping, "sample_period_s", None)
    period = given if given is not None else (artifact.data_sample_period if artifact is not None else None)
    dataset = load_dataset(Path(path), mapping, sample_period_s=period)
    if artifact is not None and not math.isclose(dataset.sample_period_s, artifact.data_sample_period,
                                                  rel_tol=1e-6):
        where = f" ({artifact.path})" if artifact.path is not None else ""
        raise BenchError(f"{dataset.path} is sampled every {dataset.sample_period_s:g} s, but model "
                         f"{artifact.model_id:08x}{where} runs on data sampled every {artifact.data_sample_period:g} "
                         f"s; resample the data or use a model identified on data at {dataset.sample_period_s:g} s")
    return dataset


def check_drive_data(dataset: Dataset, artifact: ModelArtifact) -> None:
    """BenchError (one sentence) when the model needs the d/q currents (an electrical loss model) and the data has
    none: refused before anything starts (the target would otherwise never see a complete row)."""
    if reads_currents(artifact.drive_signals) and not dataset.has_currents:
        where = f" ({artifact.path})" if artifact.path is not None else ""
        raise BenchError(f"model {artifact.model_id:08x}{where} has an {artifact.loss_model} loss model, which needs "
                         f"the d/q currents, and {dataset.path} has none (columns i_d_A, i_q_A); map them with "
                         "--mapping or use a model with loss maps")


def check_measurement_data(dataset: Dataset, artifact: ModelArtifact) -> None:
    """BenchError (one sentence) when the model's observer measures a column the data does not have: refused before
    anything starts (the filter would otherwise run open loop without saying so)."""
    for column in measured_columns(artifact).values():
        if not dataset.has(column):
            where = f" ({artifact.path})" if artifact.path is not None else ""
            raise BenchError(f"model {artifact.model_id:08x}{where} has an observer that measures column {column}, "
                             f"and {dataset.path} has none; map it with --mapping or use a model without an observer")


def measured_columns(artifact: ModelArtifact) -> dict[str, str]:
    """{host measurement channel: dataset column} the artifact's observer reads over CAN ({} without an observer)."""
    from target_sim.observer.node import measured_columns as columns

    refuse_over_can(artifact)
    return columns(artifact)


def refuse_over_can(artifact: ModelArtifact) -> None:
    """UsageError (one sentence, exit 2) for an observer the CAN frames cannot carry (two measurements in one slot,
    the flux linkage of a model whose rows carry no currents: `target_sim.observer.node.can_refusal`); a command
    calls it before any work."""
    from target_sim.observer.node import can_refusal

    refusal = can_refusal(artifact)
    if refusal is not None:
        raise UsageError(refusal)


def measurements_for(dataset: Dataset, artifact: ModelArtifact) -> np.ndarray | None:
    """What the host sends per row in its measurement frames: (rows, `target_sim.observer.node.measurement_width`
    columns of `dbc.contract.MEASUREMENT_CHANNELS`), each channel the observer reads from its dataset column and NaN
    (absent) elsewhere; None for a model without an observer (no measurement frames, the bus as before)."""
    from dbc.contract import CHANNEL_NAMES
    from target_sim.observer import has_observer
    from target_sim.observer.node import measurement_width

    columns = measured_columns(artifact)
    if not has_observer(artifact):
        return None
    check_measurement_data(dataset, artifact)
    out = np.full((len(dataset.time_s), measurement_width(artifact)), np.nan)
    for channel, column in columns.items():
        out[:, CHANNEL_NAMES.index(channel)] = dataset.column(column)
    return out


def drive_for(dataset: Dataset, artifact: ModelArtifact) -> np.ndarray:
    """What the host sends per row: (rows, 4) [torque, speed, coolant, ambient], and [i_d, i_q] after them (rows,
    6) when the model has an electrical loss model (after `check_drive_data`)."""
    from bench.model.runs import drive_matrix

    check_drive_data(dataset, artifact)
    return drive_matrix(dataset, artifact.drive_signals)


# half the resolution of each drive signal on the bus: torque 0.1 Nm, speed 0.5 rpm, temperatures 0.1 °C, and the
# d/q currents of DriveCurrents 0.1 A
DRIVE_HALF_RESOLUTION = np.array([0.05, 0.25, 0.05, 0.05, 0.05, 0.05]) + 1e-9


def matching_dataset(drive: np.ndarray, artifact):
    """A dataset in out/data whose first rows carry the log's drive values (within the CAN resolution)."""
    from bench.drive.dataset import DatasetError, default_dataset_dir

    directory = default_dataset_dir()
    for csv in sorted(directory.glob("*.csv")) if directory.is_dir() else []:
        try:
            dataset = load_data(csv, artifact)
        except DatasetError:
            continue
        if data_mismatch(dataset, drive) is None:
            return dataset
    return None


def data_mismatch(dataset, drive: np.ndarray) -> str | None:
    """Why `dataset` is not the one the log's drive frames came from (None if it is, within the CAN resolution;
    a log whose rows carry the d/q currents needs a dataset with them, and they must match too)."""
    from bench.model.runs import drive_matrix
    from target_sim.losses import reads_currents, row_of_width

    columns = row_of_width(drive.shape[1])
    if reads_currents(columns) and not dataset.has_currents:
        return "has no d/q current columns (i_d_A, i_q_A), the log's rows carry them"
    values = drive_matrix(dataset, columns)
    if len(values) < len(drive):
        return f"has {len(values)} rows, the log {len(drive)}"
    with np.errstate(invalid="ignore"):   # a row whose frames never came intact (NaN) differs from nothing
        off = np.any(np.abs(values[: len(drive)] - drive) > DRIVE_HALF_RESOLUTION[: drive.shape[1]], axis=1)
    if off.any():
        row = int(np.argmax(off))
        return f"differs from the log's drive values at data row {row + 1}"
    return None


def data_options(args) -> tuple[ColumnMapping | None, float | None]:
    """(ColumnMapping or None, sample period in s or None for auto) from the --mapping and --sample-period options
    (`bench.run.request`; any object with those attributes); a period given on the command line replaces the
    mapping's, with 'auto' the mapping's period (if any) is used."""
    from dataclasses import replace

    from bench.drive.mapping import load_mapping
    from bench.run.values import sample_period

    period = getattr(args, "sample_period", None)
    if isinstance(period, str):
        period = sample_period(period)
    path = getattr(args, "mapping", None)
    mapping = load_mapping(path) if path is not None else None
    if mapping is not None:
        if period is None:
            period = mapping.sample_period_s
        else:
            mapping = replace(mapping, sample_period_s=period)
    return mapping, period
