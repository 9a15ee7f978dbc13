"""The `bench` command: one parser, one module per subcommand (each with `add_subparser`)."""

from __future__ import annotations

import argparse
import importlib
import sys

from bench.errors import BenchError, UsageError

# Subcommand modules under bench.commands, in the order `bench --help` lists them.
SUBCOMMANDS = ("numerics", "data", "identify", "evaluate", "run", "replay", "analyze", "compare")


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


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        return int(args.func(args) or 0)
    except BenchError as exc:
        print(f"bench: error: {exc}", file=sys.stderr)
        return exc.exit_status
    except BrokenPipeError:  # `bench ... | head` closed the pipe: not an error of ours
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
