"""Campaign specs: parsing, expansion into runs with stable ids, the `bench run` arguments of a run, and bad specs
(one sentence, a non-zero exit, nothing written)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.campaign.spec import MODEL_KINDS, SpecError, load_spec, parse_spec
from bench.cli import main
from bench.errors import UsageError

from helpers import ROOT

SPEC = """
[campaign]
name = "t"
timeout = 120

[fixed]
rows = 300
tolerate-faults = true

[axes]
model = ["hammerstein", "lti-lptn", "pv-lptn"]
fault_seed = [1, 2]
faults = ["drop=0.01,corrupt=0.001", {reply_drop = 0.02}]
"""


def test_every_combination_is_one_run(tmp_path):
    campaign = parse_spec(SPEC, tmp_path / "t.toml")
    assert (campaign.name, campaign.timeout_s) == ("t", 120.0)
    assert len(campaign.runs) == 3 * 2 * 2
    combos = {tuple(r.axes.values()) for r in campaign.runs}
    assert len(combos) == 12 and len({r.run_id for r in campaign.runs}) == 12
    first = campaign.runs[0]
    assert first.axes == {"model": "hammerstein", "fault_seed": 1, "faults": "drop=0.01,corrupt=0.001"}
    assert campaign.runs[1].axes["faults"] == "reply_drop=0.02"          # a TOML table becomes --faults' form
    assert first.options["rows"] == 300 and first.options["tolerate_faults"] is True
    assert first.options["engine"] == "python" and first.options["data"] == 40    # defaults filled in
    assert first.run_id.startswith("hammerstein_fault-seed1_drop-0.01-corrupt-0.001-")


def test_run_ids_are_stable_and_follow_every_option(tmp_path):
    ids = [r.run_id for r in parse_spec(SPEC, tmp_path / "t.toml").runs]
    assert ids == [r.run_id for r in parse_spec(SPEC, tmp_path / "other.toml").runs]
    # an explicit default is the same run; a changed fixed option is another one
    same = parse_spec(SPEC.replace("rows = 300", "rows = 300\nengine = 'python'"), tmp_path / "t.toml")
    assert [r.run_id for r in same.runs] == ids
    changed = parse_spec(SPEC, tmp_path / "t.toml", ["rows=301"])
    assert not set(ids) & {r.run_id for r in changed.runs}


def test_a_run_is_bench_run_with_its_own_directory_and_bus(tmp_path):
    campaign = parse_spec(SPEC, tmp_path / "t.toml")
    run = campaign.runs[0]
    argv = run.argv(tmp_path / "runs" / run.run_id, tmp_path / "d.csv")
    pairs = dict(zip(argv[::2], argv[1::2], strict=False))
    assert Path(argv[argv.index("--model") + 1]).name == "default_model.json"
    assert argv[argv.index("--data") + 1] == str(tmp_path / "d.csv")
    assert pairs["--rows"] == "300" and pairs["--fault-seed"] == "1"
    assert argv[argv.index("--faults") + 1] == "drop=0.01,corrupt=0.001"
    assert argv[argv.index("--log") + 1] == str(tmp_path / "runs" / run.run_id / "bench.blf")
    assert argv[argv.index("--report") + 1] == str(tmp_path / "runs" / run.run_id / "report")
    assert "--tolerate-faults" in argv and "--json" in argv and "--quiet" in argv
    # udp_multicast and no channel: `bench run` gives the run a port of its own
    assert argv[argv.index("-i") + 1] == "udp_multicast" and "-c" not in argv and "--channel" not in argv


def test_paths_are_relative_to_the_spec_and_overrides_replace_axes(tmp_path):
    (tmp_path / "d.csv").write_text("x\n")
    model = tmp_path / "m" / "model.json"
    model.parent.mkdir()
    model.write_bytes((ROOT / "bench" / "data" / "default_model-lti-lptn.json").read_bytes())
    spec = tmp_path / "s.toml"
    spec.write_text('[fixed]\ndata = "d.csv"\nreport = false\n[axes]\nmodel = ["m/model.json", "hammerstein"]\n')
    campaign = load_spec(spec)
    assert campaign.runs[0].model_path() == model.resolve()
    assert campaign.runs[0].path_of("data") == (tmp_path / "d.csv").resolve()
    assert "--no-report" in campaign.runs[0].argv(tmp_path, tmp_path / "d.csv")
    assert campaign.runs[0].run_id.startswith("model-")
    fixed = load_spec(spec, ["model=pv-lptn"])             # a single value fixes an axis
    assert fixed.axes == {} and [r.options["model"] for r in fixed.runs] == ["pv-lptn"]
    swept = load_spec(spec, ['rows=[100, 200]'])            # a list makes an axis
    assert len(swept.runs) == 4 and swept.axes["rows"] == [100, 200]


@pytest.mark.parametrize(("text", "expected"), [
    ("[axes\nmodel = 1", "is not valid TOML"),
    ("[axes]\nmodle = ['hammerstein']", "[axes] has an unknown key 'modle'"),
    ("[axes]\nmodel = ['foo']", "unknown model kind 'foo'"),
    ("[axes]\nmodel = ['missing/model.json']", "is not a file"),
    ("[axes]\ndata = ['nope.csv']", "data 'nope.csv' is not a file"),
    ("[axes]\ndata = [30]", "30 is not a coolant set point"),
    ("[fixed]\nfaults = 'drp=0.1'", "unknown fault kind 'drp'"),
    ("[fixed]\nfaults = 'drop=2'", "must be a probability"),
    ("[fixed]\nmode = 'realtime'\nfaults = 'kill=1'", "need lockstep"),
    ("[fixed]\nrows = 300\n[axes]\nrows = [1, 2]", "both in [fixed] and in [axes]"),
    ("[axes]\nmodel = []", "must be a non-empty list"),
    ("[axes]\nfault_seed = [1, 1]", "lists 1 twice"),
    ("rows = 3", "unknown section or key 'rows'"),
    ("[fixed]\nrows = -3", "[fixed] rows must be a positive whole number"),
    ("[fixed]\nspeed = true", "[fixed] speed must be a number"),
    ("[fixed]\nengine = 'fpga'", "[fixed] engine must be one of python, firmware"),
    ("[campaign]\nworkers = 3", "[campaign] has an unknown key 'workers'"),
])
def test_a_bad_spec_is_one_sentence_and_nothing_is_written(tmp_path, capsys, text, expected):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    with pytest.raises(SpecError, match="bad.toml"):
        load_spec(spec)
    out = tmp_path / "out"
    for action in (["run", str(spec), "--out", str(out)], ["plan", str(spec)]):
        assert main(["campaign", *action]) == 2
        err = capsys.readouterr().err
        assert expected in err and err.count("\n") == 1 and err.startswith("bench: error: ")
        assert "Traceback" not in err
    assert not out.exists()


def test_bad_arguments_are_one_sentence(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text("[axes]\nmodel = ['hammerstein']\n")
    cases = [
        (["run", str(tmp_path / "none.toml")], 2, "does not exist"),
        (["run", str(spec), "--workers", "0"], 2, "must be a positive whole number"),
        (["run", str(spec), "--cluster", "127.0.0.1:1", "--workers", "2"], 2, "--workers sizes the local cluster"),
        (["run", str(spec), "--cluster", "no-port"], 1, "is not a scheduler address"),
        (["run", str(spec), "--cluster", "tcp://127.0.0.1:1", "--out", str(tmp_path / "o")], 1,
         "cannot reach a Dask scheduler at tcp://127.0.0.1:1"),
        (["run", str(spec), "--set", "rows"], 2, "must be KEY=VALUE"),
        (["report", str(tmp_path)], 1, "campaign.sqlite does not exist"),
        ([], 2, "needs an action"),
    ]
    for argv, status, expected in cases:
        assert main(["campaign", *argv]) == status, argv
        err = capsys.readouterr().err
        assert expected in err and err.count("\n") == 1, (argv, err)
    assert not (tmp_path / "o").exists()


def test_an_occupied_out_is_refused(tmp_path, capsys):
    spec = tmp_path / "s.toml"
    spec.write_text("[axes]\nmodel = ['hammerstein']\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["campaign", "run", str(spec), "--out", str(out)]) == 2
    assert "is not empty and holds no campaign table" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_the_shipped_specs_parse():
    smoke = load_spec(ROOT / "examples" / "campaigns" / "smoke.toml")
    assert len(smoke.runs) == 6 and set(smoke.axes["model"]) == set(MODEL_KINDS)
    assert all(r.options["rows"] == 300 for r in smoke.runs)
    soak = load_spec(ROOT / "examples" / "campaigns" / "soak.toml")
    assert len(soak.runs) == 10 and {r.options["faults"] for r in soak.runs} == {"drop=0.01,corrupt=0.001,kill=1"}
    assert [r.options["fault_seed"] for r in soak.runs] == list(range(100, 110))
    assert all(r.options["rows"] is None and r.options["data"] == 40 for r in soak.runs)   # the full 40 °C run
    with pytest.raises(UsageError):
        load_spec(ROOT / "examples" / "campaigns" / "soak.toml", ["rows"])
