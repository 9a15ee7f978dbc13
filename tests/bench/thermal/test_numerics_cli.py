import json

import pytest

from bench.cli import main

from helpers import run_cli


def test_numerics_json_has_the_documented_shape(capsys):
    assert main(["numerics", "--json", "--dt", "0.5,4", "--disc", "zoh"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["params"] == "table1-refined"
    assert len(report["eigenvalues_continuous"]) == 4 and len(report["time_constants_s"]) == 4
    assert {(r["dt"], r["realization"]) for r in report["rows"]} == {
        (dt, name) for dt in (0.5, 4.0) for name in ("physical", "original", "balanced", "modal", "delta")}
    keys = {"discretization", "dt", "realization", "cond", "eig_f64", "eig_f32_abs", "stable_f32",
            "max_output_error_f32_C"}
    for row in report["rows"]:
        assert keys <= row.keys()
        assert row["stable_f32"] == (row["realization"] != "original" or row["dt"] != 0.5)


def test_numerics_table_mentions_every_realization(capsys):
    assert main(["numerics", "--params", "table1", "--dt", "1", "--disc", "tustin"]) == 0
    out = capsys.readouterr().out
    assert "parameter set: table1" in out
    for name in ("physical", "original", "balanced", "modal", "delta"):
        assert name in out


@pytest.mark.parametrize("args,fragment", [
    (["--params", "table9"], "unknown parameter set"),
    (["--dt", "0.5,abc"], "not a comma-separated list of numbers"),
    (["--dt", "-1"], "positive"),
    (["--disc", "zoh,rk4"], "comma-separated list of zoh, tustin, euler"),
    (["--bogus"], "unrecognized arguments"),
])
def test_bad_arguments_give_one_sentence_and_status_2(args, fragment):
    proc = run_cli("-m", "bench", "numerics", *args)
    assert proc.returncode == 2
    assert fragment in proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert proc.stdout == ""
