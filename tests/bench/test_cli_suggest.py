"""Did-you-mean for every unknown option of every subcommand, as for choices and subcommands: a misspelt option is
one sentence naming the option meant and the help of the (sub)command it was given to (exit status 2), also when
the misspelling leaves a required option missing."""

from __future__ import annotations

import re

import pytest

from bench.cli import OneLineParser, build_parser, main
from bench.errors import UsageError


def parsers(parser: OneLineParser, path: tuple[str, ...] = ()):
    """(the words that reach it, the parser) for the top parser and every subcommand, nested ones included."""
    yield path, parser
    if parser.subcommands is not None:
        for name, sub in parser.subcommands.choices.items():
            yield from parsers(sub, (*path, name))


def misspelt(option: str) -> str:
    """The option with two neighbouring letters of its name swapped (`--criteria` -> `--cirteria`)."""
    name = option.lstrip("-")
    i = max(0, len(name) // 2 - 1)
    while name[i] == name[i + 1]:
        i += 1
    return option[: len(option) - len(name)] + name[:i] + name[i + 1] + name[i] + name[i + 2:]


def long_options(parser: OneLineParser) -> list[str]:
    return [o for o in parser.option_names if o.startswith("--") and len(o) > 4]


ALL = [(path, option) for path, parser in parsers(build_parser()) for option in long_options(parser)]


def test_every_subcommand_is_walked():
    paths = {path for path, _ in parsers(build_parser())}
    assert {("run",), ("analyze",), ("observer",), ("robustness",), ("firmware", "build"), ("campaign", "run")} <= paths
    assert len(ALL) > 200   # every option of every subcommand


def test_every_misspelt_option_of_every_subcommand_gets_its_suggestion():
    wrong = []
    parser = build_parser()
    for path, option in ALL:
        typo = misspelt(option)
        prog = " ".join(("bench", *path))
        try:
            parser.parse_args([*path, typo])
        except UsageError as exc:
            message = str(exc)
            suggested = re.search(rf"did you mean ('[-\w]+' or )?{option!r}", message)
            if not suggested or f"(see '{prog} --help')" not in message:
                wrong.append(f"{prog} {typo}: {message}")
        else:
            wrong.append(f"{prog} {typo}: accepted")
    assert wrong == []


@pytest.mark.parametrize(("argv", "sentence"), [
    (["run", "--criteira", "c.toml"],
     "unrecognized arguments: --criteira c.toml; did you mean '--criteria'? (see 'bench run --help')"),
    (["run", "--junit-xlm=j.xml"],
     "unrecognized arguments: --junit-xlm=j.xml; did you mean '--junit-xml'? (see 'bench run --help')"),
    (["analyze", "--no-reprot"],
     "the following arguments are required: log; unrecognized arguments: --no-reprot; did you mean '--no-report'? "
     "(see 'bench analyze --help')"),
    (["export", "x.blf", "--ot", "y.asc"],
     "the following arguments are required: --out; unrecognized arguments: --ot; did you mean '--out'? "
     "(see 'bench export --help')"),
    (["run", "--criteira", "c", "--junit-xlm", "j"],
     "unrecognized arguments: --criteira c --junit-xlm j; did you mean '--criteria' (for --criteira), "
     "'--junit-xml' (for --junit-xlm)? (see 'bench run --help')"),
    (["run", "--seped", "2"],
     "unrecognized arguments: --seped 2; did you mean '--seed' or '--speed'? (see 'bench run --help')"),
    (["run", "--nosuch"], "unrecognized arguments: --nosuch (see 'bench run --help')"),
])
def test_the_sentence_exit_status_2(capsys, argv, sentence):
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert err == f"bench: error: {sentence}\n" and out == ""
