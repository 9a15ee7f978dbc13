"""No output of a command may name one of its inputs or another of its outputs (`bench.commands.args.check_files`):
the same path, a symlink to it, a hard link of it, or the same file through `..`. Each is one sentence naming both
options and the file, exit status 2, before any work: the input is left byte for byte, nothing is written.

Every subcommand declares its path options (`declare_files`); `test_every_path_option_is_declared` walks every
parser `bench` builds and fails on a path option that is neither an input nor an output, so a new command or option
cannot skip the check.
"""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

import pytest

from bench.cli import build_parser, main
from bench.commands.args import declare_files, declared_files

RUN = ("run", "--rows", "5", "--no-report", "--quiet", "-i", "udp_multicast")


@pytest.fixture
def data(tmp_path, small_dataset) -> Path:
    path = tmp_path / "data.csv"
    shutil.copyfile(small_dataset, path)
    return path


def refused(capsys, argv: list[str], *fragments: str) -> str:
    """`bench ARGV` exits 2 with one line on stderr holding every fragment; that line."""
    status = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2, err
    assert len(err) == 1 and err[0].startswith("bench: error: "), err
    for fragment in fragments:
        assert fragment in err[0], err[0]
    return err[0]


def test_a_log_naming_the_data_is_refused_and_the_data_kept(capsys, tmp_path, data):
    before = data.read_bytes()
    refused(capsys, [*RUN, "--data", data, "--log", data], f"--log {data}", f"--data {data}",
            "input", "choose another --log")
    assert data.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]   # no partial log, no firmware cache


def test_a_junit_xml_naming_the_data_is_refused(capsys, tmp_path, data):
    before = data.read_bytes()
    refused(capsys, [*RUN, "--data", data, "--log", tmp_path / "run.blf", "--junit-xml", data],
            f"--junit-xml {data}", f"--data {data}", "choose another --junit-xml")
    assert data.read_bytes() == before
    assert not (tmp_path / "run.blf").exists()


def test_a_junit_xml_naming_the_log_is_refused(capsys, tmp_path, data):
    log = tmp_path / "run.csv"
    refused(capsys, [*RUN, "--data", data, "--log", log, "--junit-xml", log],
            f"--junit-xml {log}", f"--log {log}", "another output")
    assert not log.exists()


@pytest.mark.parametrize("link", ["hard", "symlink", "dotdot"])
def test_another_name_of_the_data_is_refused(capsys, tmp_path, data, link):
    """A hard link (same st_dev/st_ino), a symlink and a path through `..` are the data file too."""
    other = tmp_path / "other.csv"
    if link == "hard":
        os.link(data, other)
    elif link == "symlink":
        other.symlink_to(data)
    else:
        (tmp_path / "sub").mkdir()
        other = tmp_path / "sub" / ".." / "data.csv"
    before = data.read_bytes()
    refused(capsys, [*RUN, "--data", data, "--log", other], f"--log {other}", f"--data {data}",
            "under another name")
    assert data.read_bytes() == before
    assert other.exists() and (link != "symlink" or other.is_symlink())


def test_a_symlinked_log_naming_the_data_through_junit_is_refused(capsys, tmp_path, data):
    """Two outputs that are one file under two names (a symlink): the second is refused."""
    log = tmp_path / "run.csv"
    alias = tmp_path / "alias.csv"
    alias.symlink_to(log)
    refused(capsys, [*RUN, "--data", data, "--log", log, "--junit-xml", alias], f"--junit-xml {alias}",
            f"--log {log}")


def test_replay_and_export_onto_their_own_log_are_refused(capsys, tmp_path):
    log = tmp_path / "bench.blf"
    log.write_bytes(b"not read: refused before")
    refused(capsys, ["replay", log, "--log", log], f"--log {log}", f"LOG {log}")
    refused(capsys, ["export", log, "--out", log], f"--out {log}", f"LOG {log}")
    refused(capsys, ["analyze", log, "--junit-xml", log], f"--junit-xml {log}", f"LOG {log}")
    assert log.read_bytes() == b"not read: refused before"


def test_a_glob_of_training_files_holding_the_output_is_refused(capsys, tmp_path, data):
    """--train takes globs: the file a glob matches is an input like one named."""
    refused(capsys, ["identify", "--train", str(tmp_path / "*.csv"), "--out", data, "--quiet"],
            f"--out {data}", f"--train {data}")


def test_distinct_files_pass_the_check(tmp_path):
    from bench.commands.args import check_files

    args = build_parser().parse_args(["run", "--data", str(tmp_path / "a.csv"), "--log", str(tmp_path / "b.blf"),
                                      "--junit-xml", str(tmp_path / "j.xml")])
    check_files(args)   # no error
    assert declared_files(args) is not None


# ---------------------------------------------------------------- every path option is declared

PATH_METAVARS = ("FILE", "DIR", "ELF", "SPEC", "LOG")


def is_path_option(action: argparse.Action) -> bool:
    """A path option: typed as a Path, or showing a file or directory metavar (argparse's public Action fields)."""
    metavar = str(action.metavar or "")
    return action.type is Path or any(word in metavar for word in PATH_METAVARS)


def recorded_parsers(monkeypatch, build=build_parser) -> dict[argparse.ArgumentParser, list[argparse.Action]]:
    """Every parser `build()` makes and the actions added to it (also through argument groups), recorded by
    wrapping argparse's public add_argument / add_argument_group / add_mutually_exclusive_group."""
    seen: dict[argparse.ArgumentParser, list[argparse.Action]] = {}
    add_argument = argparse.ArgumentParser.add_argument
    add_group = argparse.ArgumentParser.add_argument_group
    add_exclusive = argparse.ArgumentParser.add_mutually_exclusive_group

    def wrap(container, parser):
        original_add, original_exclusive = container.add_argument, container.add_mutually_exclusive_group

        def recording_add(*args, **kwargs):
            action = original_add(*args, **kwargs)
            seen.setdefault(parser, []).append(action)
            return action

        def recording_exclusive(*args, **kwargs):
            return wrap(original_exclusive(*args, **kwargs), parser)

        container.add_argument = recording_add
        container.add_mutually_exclusive_group = recording_exclusive
        return container

    def parser_add(self, *args, **kwargs):
        action = add_argument(self, *args, **kwargs)
        seen.setdefault(self, []).append(action)
        return action

    monkeypatch.setattr(argparse.ArgumentParser, "add_argument", parser_add)
    monkeypatch.setattr(argparse.ArgumentParser, "add_argument_group",
                        lambda self, *a, **k: wrap(add_group(self, *a, **k), self))
    monkeypatch.setattr(argparse.ArgumentParser, "add_mutually_exclusive_group",
                        lambda self, *a, **k: wrap(add_exclusive(self, *a, **k), self))
    build()
    return seen


def undeclared(parsers: dict[argparse.ArgumentParser, list[argparse.Action]]) -> list[str]:
    """'PROG --option' for each path option no declaration names, and each declared name no option has."""
    problems = []
    for parser, actions in parsers.items():
        roles = declared_files(parser)
        declared = roles.dests if roles is not None else set()
        dests = {a.dest for a in actions}
        problems += [f"{parser.prog} {'/'.join(a.option_strings) or a.dest}: not declared" for a in actions
                     if is_path_option(a) and a.dest not in declared]
        if roles is not None:   # a declaration of an option the command lacks (the shared ones need not be there)
            own = {o.dest for o in (*roles.inputs, *roles.outputs)} - {"mapping", "criteria", "baseline",
                                                                       "can_config", "junit_xml"}
            problems += [f"{parser.prog} {dest}: declared, no such option" for dest in sorted(own - dests)]
    return problems


def test_every_path_option_is_declared(monkeypatch):
    parsers = recorded_parsers(monkeypatch)
    progs = {p.prog for p in parsers}
    assert {"bench run", "bench replay", "bench campaign run", "bench firmware timing"} <= progs   # it walked them
    assert undeclared(parsers) == []


def test_the_walk_finds_an_undeclared_path_option(monkeypatch):
    """The check above can fail: a command with an output it does not declare is named."""
    def build():
        parser = argparse.ArgumentParser(prog="bench new")
        parser.add_argument("--data", type=Path)
        parser.add_argument("--out", type=Path)
        group = parser.add_argument_group("more")
        group.add_argument("--table", metavar="FILE")
        declare_files(parser, inputs=("--data",))
        return parser

    assert undeclared(recorded_parsers(monkeypatch, build)) == ["bench new --out: not declared",
                                                                "bench new --table: not declared"]


def test_the_plugin_refuses_an_out_directory_that_is_its_profile(tmp_path):
    """--bench-out naming the --bench-profile file (here through a symlink): pytest's usage error, one sentence."""
    from types import SimpleNamespace

    from bench.pytest_plugin import config_of

    profile = tmp_path / "bench.toml"
    profile.write_text('[target]\nengine = "python"\n')
    (tmp_path / "out").symlink_to(profile)
    options = SimpleNamespace(bench_profile=str(profile), bench_out=str(tmp_path / "out"), bench_interface=None,
                              bench_engine=None, bench_channel=None, bench_bitrate=None, bench_bus_kwargs=[])
    with pytest.raises(pytest.UsageError, match=r"--bench-out .*out is the same file as --bench-profile .*bench\.toml"):
        config_of(options)
    assert profile.read_text() == '[target]\nengine = "python"\n'


@pytest.mark.parametrize("output", ["--stats", "--events"])
def test_the_target_refuses_counters_written_over_its_model(capsys, tmp_path, output):
    """`python -m target_sim --stats`/`--events` naming the model (a hard link of it): exit status 2, one sentence,
    before the bus is opened."""
    from target_sim.__main__ import main as target_main

    model = tmp_path / "model.json"
    model.write_text("{}")
    os.link(model, tmp_path / "link.json")
    with pytest.raises(SystemExit) as exited:
        target_main(["--model", str(model), output, str(tmp_path / "link.json")])
    assert exited.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{output} {tmp_path / 'link.json'} is the same file as --model {model}" in err
    assert model.read_text() == "{}"


def test_a_log_inside_the_report_directory_is_refused_unless_no_report(capsys, tmp_path, data):
    """The report directory is written whole: a --log (or the analyzed LOG) inside it is refused before the run;
    with --no-report there is no report, and the same paths run."""
    report = tmp_path / "R"
    refused(capsys, ["run", "--rows", "5", "--quiet", "-i", "udp_multicast", "--data", data, "--log",
                     report / "bench.blf", "--report", report],
            f"--log {report / 'bench.blf'} is inside --report {report}", "choose another --report")
    assert not report.exists()
    refused(capsys, ["analyze", report / "bench.blf", "--report", report], f"LOG {report / 'bench.blf'} is inside")
    assert main([str(a) for a in (*RUN, "--data", data, "--log", report / "bench.blf", "--report", report)]) == 0
    assert sorted(p.name for p in report.iterdir()) == ["bench.blf"]


def test_replays_default_log_that_is_the_replayed_log_is_refused(capsys, tmp_path, monkeypatch):
    """`bench replay x.blf` writes out/replay/x.replay.blf by default: a hard link of x.blf there is refused too
    (the default is no option `bench.cli` sees; the command asks the same check, `refuse_same`)."""
    monkeypatch.chdir(tmp_path)
    log = tmp_path / "x.blf"
    log.write_bytes(b"not read: refused before")
    (tmp_path / "out" / "replay").mkdir(parents=True)
    os.link(log, tmp_path / "out" / "replay" / "x.replay.blf")
    refused(capsys, ["replay", "x.blf"], "--log out/replay/x.replay.blf is the same file as LOG x.blf")
    assert log.read_bytes() == b"not read: refused before"
