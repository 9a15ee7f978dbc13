"""`<log>.elf.json`: which firmware ELF the target of a run ran (or laid out its XCP cells by), beside the run's log.

A bus log holds CAN frames only; a firmware target's XCP cells sit at its ELF's addresses, so a DOWNLOAD in the log
names its cell by an address that only that ELF explains. `bench run --engine firmware` and `bench replay` (a target
of their own on the firmware engine, or on the Python engine laid out by an ELF, `--xcp-elf`) write the note: the
ELF's absolute path and its sha256. `bench analyze` lays out the twin that replays the log's calibrations by the ELF
the note names, and `bench replay` its target's cells, after checking it is still there and still the same file
(one sentence if not). A run on the Python engine's own pages, or of a target the bench did not start (`bench
host`), removes a note an earlier run left beside the same log name, so a note never describes another run.

    {"log": "run.blf", "elf": "/abs/path/model.elf", "sha256": "<64 hex digits>"}
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from bench.errors import BenchError
from bench.fileio import write_text_atomically
from dbc.files import NAME_MAX

ELF_NOTE_SUFFIX = ".elf.json"


@dataclass(frozen=True)
class ElfNote:
    """The ELF a log's target ran: its absolute path and the sha256 of its bytes."""

    elf: Path
    sha256: str


def note_path(log_path: str | os.PathLike) -> Path:
    log_path = Path(log_path)
    return log_path.with_name(log_path.name + ELF_NOTE_SUFFIX)


def can_exist(note: Path) -> bool:
    """Whether a note of this name can be on disk: a log with a name of the longest legal length has a note name
    too long to write (a firmware run refuses such a log name before it starts, `check_log_names`), so it has none."""
    return len(os.fsencode(note.name)) <= NAME_MAX


def file_sha256(path: str | os.PathLike) -> str:
    with open(path, "rb") as file:
        return hashlib.file_digest(file, "sha256").hexdigest()


def note_target(log_path: str | os.PathLike, elf: str | os.PathLike | None) -> Path | None:
    """After a run that wrote `log_path`: the note naming `elf` beside it (None: the Python engine or a target not
    started here, so an earlier run's note there goes). Nothing without the log (a run that wrote none)."""
    path = note_path(log_path)
    if elf is None:
        if can_exist(path):
            path.unlink(missing_ok=True)
        return None
    if not Path(log_path).is_file():
        return None
    body = {"log": Path(log_path).name, "elf": str(Path(elf).resolve()), "sha256": file_sha256(elf)}
    write_text_atomically(path, json.dumps(body, indent=1) + "\n", "the note of the run's firmware ELF")
    return path


def read_note(log_path: str | os.PathLike) -> ElfNote | None:
    """The note beside `log_path`, None without one; BenchError (one sentence) for a note that cannot be read."""
    path = note_path(log_path)
    if not can_exist(path):
        return None
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise BenchError(f"{path}, the note of the firmware ELF log {log_path} ran, cannot be read ({exc}); "
                         "remove it and pass the ELF with --xcp-elf") from None
    if not (isinstance(body, dict) and isinstance(body.get("elf"), str) and isinstance(body.get("sha256"), str)):
        raise BenchError(f"{path}, the note of the firmware ELF log {log_path} ran, does not name an ELF and its "
                         "sha256; remove it and pass the ELF with --xcp-elf")
    return ElfNote(Path(body["elf"]), body["sha256"])


def check_ran(note: ElfNote, elf: str | os.PathLike, log_path: str | os.PathLike) -> None:
    """BenchError (one sentence) unless `elf` is the file the note names by its sha256."""
    found = file_sha256(elf)
    if found != note.sha256:
        raise BenchError(f"{elf} is not the firmware ELF the run of log {log_path} ran on (its sha256 is "
                         f"{found[:12]}..., the run's was {note.sha256[:12]}..., {note_path(log_path).name}): its XCP "
                         "addresses may differ; pass the ELF that ran with --xcp-elf")


def noted_elf(log_path: str | os.PathLike) -> Path | None:
    """The ELF the note beside `log_path` names, checked present and unchanged (BenchError, one sentence, if not);
    None without a note."""
    note = read_note(log_path)
    if note is None:
        return None
    if not note.elf.is_file():
        raise BenchError(f"the run of log {log_path} ran on the firmware ELF {note.elf} "
                         f"({note_path(log_path).name}), which is not there any more; pass that ELF (its sha256 "
                         f"{note.sha256[:12]}...) with --xcp-elf")
    check_ran(note, note.elf, log_path)
    return note.elf


def check_model_elf(path: str | os.PathLike, artifact) -> None:
    """BenchError (one sentence) unless `path` is a firmware ELF of `artifact`'s model (`--xcp-elf`)."""
    from target_sim.firmware.elf import FirmwareError
    from target_sim.xcp.layout import elf_symbols

    try:
        elf_symbols(path, artifact.model_id)
    except FirmwareError as exc:
        raise BenchError(f"--xcp-elf: {exc}") from None


def check_given_elf(elf: str | os.PathLike, artifact, log_path: str | os.PathLike) -> None:
    """--xcp-elf `elf` for log `log_path`: BenchError (one sentence) for an ELF of another model, or one whose bytes
    are not those of the ELF the log's note names."""
    check_model_elf(elf, artifact)
    note = read_note(log_path)
    if note is not None:
        check_ran(note, elf, log_path)


def recorded_layout(log_path: str | os.PathLike, record, artifact) -> Path | None:
    """For a log with XCP DOWNLOADs (a `BusRecord`), the firmware ELF whose addresses its target's cells had, when
    no --xcp-elf says it: the ELF the log's note names (BenchError, one sentence, when it is gone or changed), else
    for a firmware target's log the packaged model's shipped ELF (BenchError for another model's firmware); None
    (the Python slave's pages) for a Python target's log and for a log without calibrations."""
    from bench.analysis.canmetrics import ran_firmware
    from bench.firmware.images import packaged_elf

    if not record.xcp_downloads:
        return None
    noted = noted_elf(log_path)
    if noted is not None:
        check_model_elf(noted, artifact)
        return noted
    if not ran_firmware(record):
        return None
    shipped = packaged_elf(artifact)
    if shipped is None:
        raise BenchError(f"log {log_path} is of a firmware target calibrated over XCP ({record.xcp_downloads} "
                         f"DOWNLOADs), whose cells sit at its ELF's addresses, and model {artifact.model_id:08x} "
                         "ships no ELF; pass the target's ELF with --xcp-elf")
    return shipped
