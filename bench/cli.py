"""The `bench` command: one parser, one module per subcommand (each with `add_subparser`)."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from bench.errors import BenchError, UsageError
from dbc.database import DbcError

# Subcommand modules under bench.commands, in the order `bench --help` lists them.
SUBCOMMANDS = ("motor", "numerics", "data", "identify", "evaluate", "run", "replay", "analyze", "compare", "host",
               "firmware")


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad argument in one sentence (exit status 2) instead of a usage dump."""

    def error(self, message: str) -> None:  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: {message} (see '{self.prog} --help')")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="bench", description=__doc__)
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
    """An OSError nobody caught closer to its cause, as one sentence naming the file and what to do."""
    where = exc.filename if exc.filename is not None else "a file"
    reason = exc.strerror or exc.__class__.__name__
    return f"{where}: {reason}; check that the path exists, is of the right kind and is writable, or choose another"


def main(argv: list[str] | None = None) -> int:
    # python-can reports a bus that failed half-way through its constructor once more from __del__ ("... was not
    # properly shut down"), after the one-sentence error: its warnings are not for the bench's users.
    logging.getLogger("can").addHandler(logging.NullHandler())
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        return int(args.func(args) or 0)
    except BenchError as exc:
        print(f"bench: error: {one_line(str(exc))}", file=sys.stderr)
        return exc.exit_status
    except DbcError as exc:  # the CAN contract, read on first use by whichever command needs it
        print(f"bench: error: {one_line(str(exc))}", file=sys.stderr)
        return 1
    except OSError as exc:  # a file or directory the command could not use (last resort: name it, no traceback)
        if isinstance(exc, BrokenPipeError):
            sys.stderr.close()
            return 0
        print(f"bench: error: {_os_error_sentence(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
