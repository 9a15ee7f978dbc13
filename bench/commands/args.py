"""Argument types and bus options the subcommands share (as python-can's command-line tools share one module).

argparse types raise `UsageError` (one sentence, exit status 2); `bus_from_args` turns the bus options
(`dbc.transport.add_bus_arguments`) into the bus of a run. Every subcommand declares which of its path options it
reads and which it writes (`declare_files`); `check_files` refuses, before any work, an output that names an input
or another output (`bench.cli` calls it for every command, and a test holds every path option to a declaration).
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from bench.errors import UsageError
from bench.run.request import RUN, add_options
from bench.run.values import non_negative_int, positive_float, positive_int  # noqa: F401 - the commands import them from here
from dbc.database import contract
from dbc.files import same_file
from dbc.transport import BusConfig, config_from_args, logger_command, resolve


def bus_from_args(args: argparse.Namespace) -> BusConfig:
    """The bus the command-line options describe, `auto` resolved: udp_multicast on the bench's own group gets a
    run-unique port, on a channel the user chose python-can's default port unless one is given (`resolve`); the
    CAN contract is read first: a broken DBC is one sentence before anything starts."""
    contract()
    config = resolve(config_from_args(args), session_unique=True)
    if config.interface == "virtual":  # python-can's virtual bus lives inside one process; the target is another
        raise UsageError("the 'virtual' interface does not cross processes; use udp_multicast, socketcan or auto")
    return config


def add_listener_argument(parser: argparse.ArgumentParser) -> None:
    """--wait-for-listener SECONDS: the logger line first, then a pause before anything is sent on the bus."""
    add_options(parser, RUN, ("wait_for_listener",))


def announce_logger(bus: BusConfig, quiet: bool, prefix: str = "bench: ", wait_s: float | None = None) -> None:
    """On stderr (unless `quiet`), the line that records this bus with python-can's logger, ready to paste; with
    `wait_s` (--wait-for-listener) always, then the wait: nothing is on the bus yet, a listener started now misses
    nothing."""
    if not quiet or wait_s:
        print(f"{prefix}to record this bus with python-can: {logger_command(bus)}", file=sys.stderr, flush=True)
    if wait_s:
        print(f"{prefix}waiting {wait_s:g} s for a listener (e.g. the logger line above) before anything is sent "
              "on the bus", file=sys.stderr, flush=True)
        time.sleep(wait_s)


def warn_listener_drops(dropped: int | None, quiet: bool, prefix: str = "bench: ") -> None:
    """On stderr (unless `quiet`; the JSON's "bus" has it anyway), how many frames other listeners on the run's
    udp bus lost at their full receive buffers (`dbc.udp_listeners`): a logger's copy of the run is incomplete."""
    if dropped and not quiet:
        print(f"{prefix}warning: listeners on this bus (e.g. python-can's logger) dropped {dropped} frames of the run "
              "at their full receive buffers, so their copies are incomplete (the run's own log is not); on a busy "
              "machine record with --log, or give the listener the CPU it needs", file=sys.stderr, flush=True)


# ---------------------------------------------------------------- inputs and outputs of a command

FILES_DEFAULT = "_bench_files"   # the parser default (namespace attribute) holding a command's FileRoles

# Options that shared helpers add with one role in every command that has them: --mapping
# (`common.add_data_arguments`), --criteria, --baseline and --junit-xml (`bench.acceptance.cli`), --can-config
# (`dbc.transport.add_bus_arguments`).
SHARED_INPUTS = ("--mapping", "--criteria", "--baseline", "--can-config")
SHARED_OUTPUTS = ("--junit-xml",)


@dataclass(frozen=True)
class FileOption:
    """A path option as the user writes it (`--log`, or `LOG` for a positional) and where argparse keeps it."""

    name: str
    dest: str

    @classmethod
    def of(cls, spec: str | tuple[str, str]) -> FileOption:
        """'--junit-xml' -> dest junit_xml, 'LOG' -> log, ('--log', 'new_log') as given."""
        if isinstance(spec, tuple):
            return cls(*spec)
        return cls(spec, spec.lstrip("-").replace("-", "_").lower())


@dataclass(frozen=True)
class FileRoles:
    """The path options of one command: those it reads and those it writes (files or directories)."""

    inputs: tuple[FileOption, ...] = ()
    outputs: tuple[FileOption, ...] = ()
    replaced: tuple[FileOption, ...] = ()   # outputs that are directories written whole (a report)
    off_with: tuple[tuple[str, str], ...] = ()   # (dest of an output, dest of the flag with which it is not written)

    @property
    def dests(self) -> set[str]:
        return {o.dest for o in (*self.inputs, *self.outputs)}


def declare_files(parser: argparse.ArgumentParser, *, inputs: Iterable[str | tuple[str, str]] = (),
                  outputs: Iterable[str | tuple[str, str]] = (), replaced: Iterable[str] = (),
                  off_with: dict[str, str] | None = None) -> None:
    """Declare which path options of `parser`'s command it reads (`inputs`) and writes (`outputs`): each as the user
    writes it ('--data', 'LOG' for a positional), or (name, dest) when argparse keeps it under another name;
    `replaced`: those of the outputs that are directories the command writes whole (`bench.fileio.
    write_directory_atomically`), so no other file of the command may be inside; `off_with`: an output the command
    does not write when a flag is given ({'--report': '--no-report'}). The shared options (--mapping,
    --criteria, --baseline, --can-config in, --junit-xml out) are declared with them."""
    outputs = tuple(FileOption.of(s) for s in (*outputs, *SHARED_OUTPUTS))
    parser.set_defaults(**{FILES_DEFAULT: FileRoles(
        tuple(FileOption.of(s) for s in (*inputs, *SHARED_INPUTS)), outputs,
        tuple(o for o in outputs if o.name in tuple(replaced)),
        tuple((FileOption.of(out).dest, FileOption.of(flag).dest) for out, flag in (off_with or {}).items()))})


def declared_files(args_or_parser) -> FileRoles | None:
    """The FileRoles a parser (or the namespace it made) declares; None for a command that declares none."""
    if isinstance(args_or_parser, argparse.ArgumentParser):
        return args_or_parser.get_default(FILES_DEFAULT)
    return getattr(args_or_parser, FILES_DEFAULT, None)


def _paths(value) -> Iterator[str]:
    """The paths an option's value names: a path, a list of them (nargs, append), a glob's matches (an existing
    file is itself even if its name has glob characters, as `bench.drive.files.expand_data_paths` takes it)."""
    if value is None or isinstance(value, bool):
        return
    if isinstance(value, list | tuple):
        for item in value:
            yield from _paths(item)
        return
    text = str(value)
    if not text:
        return
    globbed = any(c in text for c in "*?[") and not os.path.lexists(text)
    matches = glob.glob(text, recursive=True) if globbed else []
    yield from (matches or [text])


def check_files(args: argparse.Namespace) -> None:
    """UsageError (one sentence, exit status 2) when an output of the command names one of its inputs or another
    of its outputs (the same path, a symlink to it or a hard link of it), or when a file of the command is inside a
    directory it writes whole (`replaced`). `bench.cli` calls it for every command, before any work."""
    roles = declared_files(args)
    if roles is None:
        return
    seen: list[tuple[FileOption, str, bool]] = []   # (option, path, is an output), in the order checked
    off = {dest for dest, flag in roles.off_with if getattr(args, flag, False)}
    for is_output, options in ((False, roles.inputs), (True, roles.outputs)):
        for option in options:
            for path in _paths(None if option.dest in off else getattr(args, option.dest, None)):
                for other, other_path, other_output in seen:
                    if (is_output or other_output) and other.dest != option.dest:
                        refuse_same(option.name, path, other.name, other_path, other_is_output=other_output)
                seen.append((option, path, is_output))
    for directory in roles.replaced:
        for path in _paths(None if directory.dest in off else getattr(args, directory.dest, None)):
            for option, inner, _ in seen:
                if option.dest != directory.dest and _inside(inner, path):
                    raise UsageError(f"{option.name} {inner} is inside {directory.name} {path}, a directory this "
                                     f"command writes whole (nothing else may be there); choose another "
                                     f"{directory.name}")


def _inside(path: str, directory: str) -> bool:
    """`path` is below `directory`, symlinks resolved."""
    return Path(os.path.realpath(directory)) in Path(os.path.realpath(path)).parents


def refuse_same(output: str, path: str | Path, other: str, other_path: str | Path, *,
                other_is_output: bool = False) -> None:
    """UsageError when the output `output` (its option as the user writes it) at `path` is the file `other` names
    (`dbc.files.same_file`). `check_files` asks it of every pair of a command's options; a command that derives an
    output's path (a default beside an input) asks it itself."""
    if not same_file(path, other_path):
        return
    what = ("another output of this command" if other_is_output else
            "an input of this command, which it would overwrite")
    how = "" if str(path) == str(other_path) else " under another name (a symlink, a hard link or a relative path)"
    raise UsageError(f"{output} {path} is the same file as {other} {other_path}{how} ({what}); choose another "
                     f"{output}")
