"""The run request (`bench.run.request`): every `bench run` option is defined there once, reaches the campaign spec
and the pytest plugin, and `to_argv` / `from_toml` round-trip."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from bench.campaign.spec import OPTIONS as CAMPAIGN_OPTIONS
from bench.cli import build_parser
from bench.errors import UsageError
from bench.pytest_plugin import PROFILE_KEYS, ThermalBench
from bench.run.request import HOST, OPTION, RUN, RUN_OPTIONS, RunRequest, options_of

# what a run's command line has beside the request: how the result is printed, and the bus (python-can's options,
# `dbc.transport.add_bus_arguments`; a campaign and the plugin choose it for their runs)
NOT_THE_REQUEST = {"--json", "--quiet", "--interface", "--channel", "--bitrate", "--bus-kwargs", "--can-config",
                   "--help"}


def _subparser(command: str) -> argparse.ArgumentParser:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices[command]


def _flags(command: str) -> set[str]:
    return {a.option_strings[-1] for a in _subparser(command)._actions if a.option_strings}


@pytest.mark.parametrize("command", [RUN, HOST])
def test_every_option_of_the_command_is_in_the_request(command):
    assert _flags(command) - NOT_THE_REQUEST == {o.flag for o in options_of(command)}


def test_every_bench_run_option_reaches_the_campaign_spec_and_the_plugin():
    """A `bench run` option a user sets (not an output the adapter places) is a campaign key, a profile [run] key
    and a keyword of `thermal_bench.run`."""
    import inspect

    settable = {o.key for o in options_of(RUN) if o.settable}
    assert settable - set(CAMPAIGN_OPTIONS) == set()
    assert settable - set(PROFILE_KEYS["run"]) == set()
    run_keywords = set(inspect.signature(ThermalBench.argv).parameters)
    assert "options" in run_keywords or settable <= run_keywords


def test_every_unsettable_option_says_why():
    assert all(o.settable or o.placed.strip() for o in RUN_OPTIONS)
    assert {o.key for o in RUN_OPTIONS if not o.settable} == {"log", "report", "no_report", "junit_xml", "fault",
                                                            "target_events", "wait_for_listener"}


ARGVS = [
    [],
    ["--data", "d.csv", "--model", "m.json", "--rows", "300", "--mode", "realtime", "--speed", "2.5"],
    ["--engine", "firmware", "--isr-rate", "10000", "--reply-timeout", "0.2", "--tolerate-gaps", "--seed", "7"],
    ["--faults", "drop=0.01,corrupt=0.001", "--fault-seed", "3", "--tolerate-faults", "--criteria", "c.toml",
     "--baseline", "b.json", "--junit-xml", "j.xml", "--log", "x.blf", "--no-report"],
    ["--mapping", "map.toml", "--sample-period", "0.5", "--report", "rep", "--wait-for-listener", "3"],
]


@pytest.mark.parametrize("argv", ARGVS)
def test_a_command_line_round_trips_through_the_request(argv):
    request = RunRequest.from_args(_subparser(RUN).parse_args(argv))
    again = request.to_argv(RUN)
    assert RunRequest.from_args(_subparser(RUN).parse_args(again)) == request
    assert {a for a in again if a.startswith("--")} == {a for a in argv if a.startswith("--")}


def test_host_gets_only_its_options():
    request = RunRequest.from_mapping({"data": "d.csv", "engine": "firmware", "isr_rate": 1000,
                                       "connect_timeout": 60}, "test")
    assert request.to_argv(HOST) == ["--data", "d.csv", "--connect-timeout", "60.0"]
    assert "--connect-timeout" not in request.to_argv(RUN)


def test_toml_round_trips():
    text = ('data = "d.csv"\nmode = "realtime"\nspeed = 2.0\nrows = 600\nfaults = "drop=0.01"\nfault_seed = 4\n'
            "tolerate_faults = true\nisr_rate = 20000\nengine = \"firmware\"\n")
    request = RunRequest.from_toml(text)
    assert request.isr_rate == 20000 and request.rows == 600 and request.tolerate_faults is True
    assert RunRequest.from_toml(request.to_toml()) == request
    assert RunRequest.from_toml("faults = {drop = 0.01, kill = 1}").faults == "drop=0.01,kill=1"


@pytest.mark.parametrize(("text", "said"), [
    ("rows = 0", "the profile rows must be a positive whole number"),
    ('mode = "lokstep"', "mode must be one of lockstep, realtime"),
    ("isr_rate = -1", "isr_rate must be a whole number, 0 or more"),
    ("speed = true", "speed must be a number"),
    ("nosuch = 1", "has an unknown key 'nosuch'; it names no run option"),
    ('faults = "melt=1"', "faults unknown fault kind"),
])
def test_a_bad_value_is_one_sentence_naming_the_key(text, said):
    with pytest.raises(UsageError, match="^the profile ") as caught:
        RunRequest.from_toml(text, "the profile")
    assert said in str(caught.value) and "\n" not in str(caught.value)


def test_the_request_is_immutable_and_defaults_are_the_options():
    request = RunRequest()
    with pytest.raises(AttributeError):
        request.rows = 5
    assert request.reply_timeout == OPTION["reply_timeout"].default
    assert request.to_argv(RUN) == [] and request.to_toml() == ""


def test_campaign_isr_rate_reaches_the_run(tmp_path):
    from bench.campaign.spec import SpecError, parse_spec

    campaign = parse_spec('[fixed]\nengine = "firmware"\nisr_rate = 10000\nrows = 5\n', tmp_path / "s.toml")
    argv = campaign.runs[0].argv(tmp_path, tmp_path / "d.csv")
    assert argv[argv.index("--isr-rate") + 1] == "10000"
    with pytest.raises(SpecError, match="--isr-rate runs the motor-control interrupt .* not the python engine"):
        parse_spec("[fixed]\nisr_rate = 10000\n", tmp_path / "s.toml")
    with pytest.raises(SpecError, match="--isr-rate 900000 is not a current-loop rate"):
        parse_spec('[fixed]\nengine = "firmware"\nisr_rate = 900000\n', tmp_path / "s.toml")


def test_a_new_campaign_key_at_its_default_keeps_the_run_ids(tmp_path):
    """Run ids hash the options: a key the spec gained later (isr_rate) changes no earlier run's id (the ids are
    those the spec made before it had the key)."""
    from bench.campaign.spec import parse_spec

    text = "[fixed]\nrows = 300\n[axes]\nfault_seed = [1, 2]\n"
    ids = [r.run_id for r in parse_spec(text, tmp_path / "s.toml").runs]
    assert ids == ["fault-seed1-70d3d391e2", "fault-seed2-fbadf8d2f5"]   # as before the request
    with_isr = parse_spec(text.replace("rows = 300", 'rows = 300\nengine = "firmware"\nisr_rate = 1000'),
                          tmp_path / "s.toml")
    assert [r.run_id for r in with_isr.runs] != ids


def test_the_plugin_builds_its_command_line_from_the_request(tmp_path):
    from bench.pytest_plugin import BenchConfig

    bench = ThermalBench(BenchConfig(engine="firmware", defaults={"rows": 50, "isr_rate": 10000}), tmp_path)
    argv = bench.argv(run_dir=tmp_path, faults={"drop": 0.01})
    assert argv[argv.index("--isr-rate") + 1] == "10000" and argv[argv.index("--rows") + 1] == "50"
    assert argv[argv.index("--faults") + 1] == "drop=0.01" and argv[argv.index("--engine") + 1] == "firmware"
    assert Path(argv[argv.index("--log") + 1]) == tmp_path / "bench.blf" and "--no-report" in argv


def test_every_settable_option_goes_through_the_plugin_and_the_campaign(tmp_path):
    """Each settable option of the command lines above, set in a profile's [run] or a campaign's [fixed], comes
    back out of the command line the adapter builds."""
    from bench.campaign.spec import parse_spec
    from bench.pytest_plugin import BenchConfig

    given = RunRequest.from_args(_subparser(RUN).parse_args([a for argv in ARGVS for a in argv]))
    settable = {o.key: getattr(given, o.key) for o in options_of(RUN) if o.settable}
    assert settable.keys() == set(CAMPAIGN_OPTIONS) - {"report"}
    plain = {k: str(v) if isinstance(v, Path) else v for k, v in settable.items()}
    bench = ThermalBench(BenchConfig(engine=plain["engine"], defaults=plain), tmp_path)
    through_plugin = RunRequest.from_args(_subparser(RUN).parse_args(bench.argv(run_dir=tmp_path)[4:]))
    files = ("data", "model", "mapping", "criteria", "baseline")   # the campaign checks them (tests/bench/campaign)
    fixed = "\n".join(f"{k} = {v!r}".replace("True", "true") for k, v in plain.items()
                      if v is not None and k not in files)
    run = parse_spec("[fixed]\n" + fixed + "\n", tmp_path / "s.toml").runs[0]
    through_campaign = RunRequest.from_args(_subparser(RUN).parse_args(run.argv(tmp_path, tmp_path / "d.csv")))
    for key, value in settable.items():
        assert getattr(through_plugin, key) == value, key
        if key not in files:
            assert getattr(through_campaign, key) == value, key


@pytest.mark.parametrize("command", [RUN, HOST])
def test_both_commands_refuse_in_one_place_before_any_work(tmp_path, command):
    """`bench run` and `bench host` share their preparation (`bench.run.prepare`): a log that names a directory,
    a report directory of other files (run only), a model that does not load, each before the data is read."""
    from bench.errors import BenchError
    from bench.run.prepare import prepare_run

    def never(*_):
        raise AssertionError("the data was checked after a refusal")

    (tmp_path / "d.blf").mkdir()
    with pytest.raises(BenchError, match="--log"):
        prepare_run(RunRequest.from_mapping({"log": str(tmp_path / "d.blf")}, "test"), command, None, never,
                    quiet=True)
    (tmp_path / "rep").mkdir()
    (tmp_path / "rep" / "mine.txt").write_text("x")
    request = RunRequest.from_mapping({"log": str(tmp_path / "x.blf"), "report": str(tmp_path / "rep"),
                                       "model": str(tmp_path / "none.json")}, "test")
    from target_sim.artifact import ArtifactError

    with pytest.raises((BenchError, ArtifactError)) as caught:   # the report first (run), else the model (host)
        prepare_run(request, command, None, never, quiet=True)
    assert ("--report" in str(caught.value)) == (command == RUN), caught.value
    assert ("none.json" in str(caught.value)) == (command == HOST), caught.value
