"""The `bench` command: one parser, one module per subcommand (each with `add_subparser`)."""

from __future__ import annotations

import argparse
import difflib
import functools
import importlib
import logging
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable

from bench import DISTRIBUTION, package_version, stop
from bench.commands.args import check_files
from bench.errors import BenchError, UsageError
from dbc.errors import CanLinkError
from host.errors import HostError, io_advice
from host.faults.spec import FaultSpecError
from target_sim.errors import TargetError

# Subcommand modules under bench.commands, in the order `bench --help` lists them.
SUBCOMMANDS = ("motor", "numerics", "data", "identify", "observer", "evaluate", "run", "replay", "analyze", "export",
               "compare", "campaign", "robustness", "host", "firmware")


# The errors of the layers below bench, caught here once: each is one sentence for the user (exit status 1). A bad
# fault option (--fault/--faults) is a bad command-line argument, as a UsageError: exit status 2.
LAYER_ERRORS = (CanLinkError, TargetError, HostError)
LAYER_USAGE_ERRORS = (FaultSpecError,)


DESCRIPTION = """\
A CAN hardware-in-the-loop bench for traction-motor (PMSM) temperature estimators: it identifies thermal models
from drive data, runs them in float32 on a simulated C2000 target (a Python node, or C firmware in an emulated
Cortex-M4F) on a real CAN bus, replays the FTP-75/WLTC3 drive cycles to it as CAN frames, logs every frame and
reports accuracy, agreement with the offline reference, timing and bus load.

The main job is `bench run`: start the target, replay a dataset over CAN, log, analyze, report (exit status 0
only when the run is clean). The other subcommands make its inputs (data, identify, firmware) or work on its
logs (analyze, replay, export)."""

EPILOG = """\
examples:
  bench run                                    the default run: generated data, packaged model, out/run/
  bench run --engine firmware --json           the same on the emulated Cortex-M4F, the summary as JSON
  bench analyze out/run/bench.blf --no-report  decode a run's log again and print its figures
  bench export out/run/bench.blf --out run.asc --host-only
                                               the host's frames as a Vector ASC log, for python -m can.player

'bench SUBCOMMAND --help' describes each subcommand."""

# argparse's "invalid choice" sentence, in the forms of Python 3.11 to 3.13 (choices quoted or not)
INVALID_CHOICE = re.compile(r"invalid choice: (?P<q>['\"]?)(?P<value>.*?)(?P=q) \(choose from (?P<choices>.*)\)$")
UNKNOWN_PARSER = "_bench_unknown_parser"   # namespace attribute: the (sub)command parser that left unknown
# arguments


def _suggestion(message: str) -> str:
    """"; did you mean 'run'?" for a mistyped choice (difflib), else ''."""
    match = INVALID_CHOICE.search(message)
    if not match:
        return ""
    choices = [c.strip().strip("'\"") for c in match["choices"].split(",")]
    close = difflib.get_close_matches(match["value"], choices, n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


def _is_option(token: str) -> bool:
    """A command-line token that names an option (`--name`, `--name=value`, `-x`), not a value (`-5`, `-`)."""
    if len(token) < 2 or not token.startswith("-"):
        return False
    try:
        float(token)
    except ValueError:
        return True
    return False


# a second option is suggested beside the closest when its similarity (difflib's ratio) is this close to it:
# `--seped` is as near `--seed` as `--speed`
SUGGESTION_TIE = 0.1


def close_options(name: str, known: list[str]) -> list[str]:
    """The options of `known` closest to the option `name` (difflib, as for choices), compared without the dashes
    every option shares (they would make `--bogus` close to `--out`): the closest, and any about as close."""
    bare = {option.lstrip("-"): option for option in known}
    word = name.lstrip("-")
    close = difflib.get_close_matches(word, list(bare), n=3)
    if not close:
        return []
    best = difflib.SequenceMatcher(None, word, close[0]).ratio()
    return [bare[c] for c in close if difflib.SequenceMatcher(None, word, c).ratio() >= best - SUGGESTION_TIE]


def misspelt_options(tokens: list[str], known: list[str]) -> list[tuple[str, list[str]]]:
    """(option, the options it is close to) for each token that names no option of `known` but is close to one.
    `--criteira=x` is compared by its name; an abbreviation argparse accepts is known."""
    pairs = []
    for token in tokens:
        name = token.split("=", 1)[0]
        if not _is_option(token) or name in known or any(k.startswith(name) for k in known if k.startswith("--")):
            continue
        close = close_options(name, known)
        if close:
            pairs.append((name, close))
    return pairs


def did_you_mean(pairs: list[tuple[str, list[str]]]) -> str:
    """"; did you mean '--criteria'?", for several "; did you mean '--criteria' (for --criteira), ...?"."""
    def meant(options: list[str]) -> str:
        return " or ".join(repr(option) for option in options)

    if not pairs:
        return ""
    if len(pairs) == 1:
        return f"; did you mean {meant(pairs[0][1])}?"
    return "; did you mean " + ", ".join(f"{meant(right)} (for {wrong})" for wrong, right in pairs) + "?"


class _RecordingGroup:
    """An argument group (or a mutually exclusive one) as argparse made it, recording the options added through it
    in its parser's `option_names`; everything else is the group's own."""

    def __init__(self, group, names: list[str]):
        self._group, self._names = group, names

    def add_argument(self, *args, **kwargs) -> argparse.Action:
        return _recorded(self._group.add_argument(*args, **kwargs), self._names)

    def add_mutually_exclusive_group(self, **kwargs) -> _RecordingGroup:
        return _RecordingGroup(self._group.add_mutually_exclusive_group(**kwargs), self._names)

    def __getattr__(self, name: str):
        return getattr(self._group, name)


def _recorded(action: argparse.Action, names: list[str]) -> argparse.Action:
    if action.help is not argparse.SUPPRESS:   # a hidden option is never suggested
        names.extend(action.option_strings)
    if callable(action.type) and action.option_strings:
        action.type = _naming_its_option(action.type, action.option_strings)
    return action


def _naming_its_option(parse, options: list[str]):
    """The argparse type `parse`, whose UsageError that does not name the option becomes argparse's own type error,
    whose sentence does ("argument --rows: '0' must be a positive whole number"), as argparse's own errors do."""
    @functools.wraps(parse)
    def typed(text: str):
        try:
            return parse(text)
        except UsageError as exc:
            if str(exc).startswith(tuple(f"{option} " for option in options)):
                raise     # its sentence names the option already
            raise argparse.ArgumentTypeError(str(exc)) from None
    return typed


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad argument in one sentence (exit status 2) instead of a usage dump, pointing to the
    help of the (sub)command the argument was given to, with the option, choice or subcommand it probably meant
    ("did you mean '--criteria'?"). The CLI prints the `bench: error:` prefix: the message carries no prog of its
    own. Its options are recorded as they are added (`option_names`), through the public argparse calls only."""

    def __init__(self, *args, **kwargs):
        self.option_names: list[str] = []
        self.given: list[str] = []
        self.subcommands: argparse.Action | None = None
        super().__init__(*args, **kwargs)

    def add_argument(self, *args, **kwargs) -> argparse.Action:
        return _recorded(super().add_argument(*args, **kwargs), self.option_names)

    def add_argument_group(self, *args, **kwargs) -> _RecordingGroup:
        return _RecordingGroup(super().add_argument_group(*args, **kwargs), self.option_names)

    def add_mutually_exclusive_group(self, **kwargs) -> _RecordingGroup:
        return _RecordingGroup(super().add_mutually_exclusive_group(**kwargs), self.option_names)

    def add_subparsers(self, **kwargs):
        self.subcommands = super().add_subparsers(**kwargs)   # its `choices`: name -> parser (the tests walk them)
        return self.subcommands

    def error(self, message: str) -> None:  # noqa: D401 - argparse API
        # a misspelt required option reads "the following arguments are required": the misspelling is the news
        misspelt = misspelt_options(self.given, self.option_names)
        if message.startswith("the following arguments are required") and misspelt:
            message += f"; unrecognized arguments: {' '.join(wrong for wrong, _ in misspelt)}{did_you_mean(misspelt)}"
            raise UsageError(f"{message} (see '{self.prog} --help')")
        raise UsageError(f"{message}{_suggestion(message)} (see '{self.prog} --help')")

    def parse_known_args(self, args=None, namespace=None):
        # argparse hands a subcommand's unknown arguments up to the top parser, which would name its own help and
        # options: the innermost parser that had some records itself, for parse_args to name
        self.given = list(sys.argv[1:] if args is None else args)
        namespace, extras = super().parse_known_args(args, namespace)
        if extras and not hasattr(namespace, UNKNOWN_PARSER):
            setattr(namespace, UNKNOWN_PARSER, self)
        return namespace, extras

    def parse_args(self, args=None, namespace=None):
        namespace, extras = self.parse_known_args(args, namespace)
        parser = vars(namespace).pop(UNKNOWN_PARSER, self)
        if extras:
            misspelt = misspelt_options(extras, parser.option_names)
            raise UsageError(f"unrecognized arguments: {' '.join(extras)}{did_you_mean(misspelt)} "
                             f"(see '{parser.prog} --help')")
        return namespace


def version_text() -> str:
    """'bench 0.1.0 (pmsm-thermal-bench; DBC thermal_bench.dbc 1.5.0, model artifact schema 2)'."""
    from dbc.database import contract
    from target_sim.artifact import SCHEMA_VERSION

    return (f"bench {package_version('(not installed)')} ({DISTRIBUTION}; DBC thermal_bench.dbc "
            f"{contract().version}, model artifact schema {SCHEMA_VERSION})")


class VersionAction(argparse.Action):
    """`--version`: computed when asked (the DBC is not parsed for every command)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):  # noqa: A002
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(version_text())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="bench", description=DESCRIPTION, epilog=EPILOG,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=VersionAction,
                        help="print the version, and the versions of the DBC and the model artifact schema it speaks")
    subparsers = parser.add_subparsers(title="subcommands", dest="command", parser_class=OneLineParser)
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"bench.commands.{name}")
        except ModuleNotFoundError as exc:
            if not exc.name or not exc.name.startswith("bench.commands"):
                raise
            continue  # a subcommand not built yet must not break the others
        module.add_subparser(subparsers)
    return parser


def one_line(message: str) -> str:
    """An error message as one line: a library's multi-line reason (a config parser's, say) is folded in."""
    return " ".join(message.split())


def _os_error_sentence(exc: OSError) -> str:
    """An OSError nobody caught closer to its cause, as one sentence naming the file and what to do (the writers
    name their files themselves: `bench.fileio.OutputError`, `host.canlog.LogError`)."""
    where = exc.filename if exc.filename is not None else "a file the command used"
    reason = exc.strerror or exc.__class__.__name__
    return f"{where}: {reason}; {io_advice(exc.errno)}"


class Terminated(BaseException):
    """SIGTERM or SIGHUP, raised in the main thread as SIGINT raises KeyboardInterrupt: every `finally` and context
    manager on the way out runs (a target process started is stopped, temporary files are deleted)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


TERMINATING = (signal.SIGTERM, signal.SIGHUP)
STOP_NOTE = "no half-written file is left and any target process it started was stopped"


def _catch_termination() -> tuple[dict, Callable]:
    """Turn SIGTERM and SIGHUP into `Terminated` (once: a second signal does not cut the cleanup short); returns
    the handlers and the unraisable hook to put back. These and SIGINT also set `bench.stop`'s flag, which worker
    threads check (the identification's polish).

    A signal that the process inherited as ignored stays ignored (`nohup bench run` must survive the hangup). A
    signal arrives between any two bytecodes, also inside a finalizer or a weakref callback (matplotlib's, the
    garbage collector's), where Python prints "Exception ignored in ..." and goes on: such a swallowed
    `Terminated` (or `KeyboardInterrupt`) is delivered again, so the command still stops."""
    raised = []

    def terminate(signum, frame) -> None:
        stop.request(signum)   # worker threads see it too (bench.stop): the main thread's way out waits for them
        if not raised:
            if _inside_import(frame):
                _resend(signum)
                return
            raised.append(signum)
            raise Terminated(signum)

    def interrupt(signum, frame) -> None:
        stop.request(signum)
        if _inside_import(frame):
            _resend(signum)
            return
        signal.default_int_handler(signum, frame)   # KeyboardInterrupt, as without this handler

    previous = {}
    for signum in TERMINATING:
        try:
            if signal.getsignal(signum) == signal.SIG_IGN:
                continue
            previous[signum] = signal.signal(signum, terminate)
        except ValueError:   # not the main thread (a test calling main()): leave the signals alone
            break
    if previous and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, interrupt)
    hook = sys.unraisablehook

    def deliver_again(unraisable) -> None:
        exc = unraisable.exc_value
        if isinstance(exc, Terminated) and exc.signum in previous:
            raised.clear()
            _resend(exc.signum)
        elif isinstance(exc, KeyboardInterrupt):
            _resend(signal.SIGINT)
        else:
            hook(unraisable)

    sys.unraisablehook = deliver_again
    return previous, hook


RESEND_DELAY_S = 0.02   # the hook and the finalizer that called it return first


def _inside_import(frame) -> bool:
    """Whether the main thread is importing a module (a command's lazy import of the fit). A signal's exception
    raised there can reach a C extension's module init, which prints it with its traceback and raises an ImportError
    of its own (numba's dispatcher: "numba._devicearray failed to import"), so the stop would end in a traceback;
    such a signal is sent again (`_resend`) until the import is done: an import takes a second or two at most."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _resend(signum: int) -> None:
    """Send `signum` to this process from another thread: its handler then runs in the main thread at the next
    bytecode, outside the finalizer that swallowed it (raised here, it would be swallowed again)."""
    resend = threading.Timer(RESEND_DELAY_S, os.kill, (os.getpid(), signum))
    resend.daemon = True
    resend.start()


def main(argv: list[str] | None = None) -> int:
    previous, hook = _catch_termination()
    try:
        try:
            return _main(argv)
        except Terminated as exc:   # wherever it came, even while an error was being reported
            return _terminated(exc)
        except stop.StopRequested:
            # the signal's own exception was swallowed on the way (matplotlib's `except Exception` around an
            # import took the RuntimeError that wrapped it) and only the flag survived: an output about to be
            # committed, or a worker, saw it (bench.fileio)
            return _stopped_by(stop.signal_number())
        except Exception as exc:
            # A signal that lands inside a class body being created (a lazy import's dataclass) reaches us wrapped:
            # Python 3.11 re-raises what `__set_name__` raised as the cause of a RuntimeError.
            cause = _signal_behind(exc)
            if isinstance(cause, Terminated):
                return _terminated(cause)
            if isinstance(cause, KeyboardInterrupt):
                return _interrupted()
            raise
    finally:
        sys.unraisablehook = hook
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        stop.clear()


def _terminated(exc: Terminated) -> int:
    print(f"bench: terminated ({signal.Signals(exc.signum).name}); {STOP_NOTE}", file=sys.stderr)
    return 128 + exc.signum


def _stopped_by(signum: int | None) -> int:
    return _interrupted() if signum == signal.SIGINT else _terminated(Terminated(signum or signal.SIGTERM))


def _interrupted() -> int:
    print(f"bench: interrupted (SIGINT); {STOP_NOTE}", file=sys.stderr)
    return 128 + signal.SIGINT


def _signal_behind(exc: BaseException) -> BaseException | None:
    """The `Terminated` or `KeyboardInterrupt` an exception was raised from or while handling, if any."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (Terminated, KeyboardInterrupt)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _failed(args: argparse.Namespace | None, sentence: str, status: int, started: float) -> int:
    """The one sentence of an error on stderr, and its exit status; a command that ended on it (not a bad argument,
    status 2) still writes its --junit-xml, with the sentence as the error (`bench.acceptance.cli`)."""
    print(f"bench: error: {sentence}", file=sys.stderr)
    if status == 1 and getattr(args, "junit_xml", None) is not None:
        from bench.acceptance.cli import junit_after_error

        junit_after_error(args, sentence, time.perf_counter() - started)
    return status


def _main(argv: list[str] | None) -> int:
    # python-can reports a bus that failed half-way through its constructor once more from __del__ ("... was not
    # properly shut down"), after the one-sentence error: its warnings are not for the bench's users.
    logging.getLogger("can").addHandler(logging.NullHandler())
    args = None
    started = time.perf_counter()
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        check_files(args)   # an output naming an input or another output: one sentence, before any work
        return int(args.func(args) or 0)
    except BenchError as exc:
        return _failed(args, one_line(str(exc)), exc.exit_status, started)
    except LAYER_ERRORS as exc:  # e.g. the CAN contract, read on first use by whichever command needs it
        return _failed(args, one_line(str(exc)), 2 if isinstance(exc, LAYER_USAGE_ERRORS) else 1, started)
    except OSError as exc:  # a file or directory the command could not use (last resort: name it, no traceback)
        if isinstance(exc, BrokenPipeError):
            sys.stderr.close()
            return 0
        return _failed(args, _os_error_sentence(exc), 1, started)
    except KeyboardInterrupt:
        return _interrupted()


if __name__ == "__main__":
    sys.exit(main())
