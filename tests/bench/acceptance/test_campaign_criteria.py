"""Acceptance criteria per run of a campaign: the spec's `criteria` and `baseline` reach each run's `bench run`
(with its JUnit XML beside its log), and a bad criteria file is refused with the spec, before any run."""

from pathlib import Path

import pytest

from bench.campaign.spec import SpecError, parse_spec

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "ci" / "criteria.toml"


def test_each_run_gets_the_criteria_and_a_junit_xml(tmp_path):
    (tmp_path / "criteria.toml").write_text(EXAMPLE.read_text())
    spec = tmp_path / "spec.toml"
    spec.write_text('[fixed]\nrows = 300\ncriteria = "criteria.toml"\n[axes]\nengine = ["python", "firmware"]\n')
    campaign = parse_spec(spec.read_text(), spec)
    for run in campaign.runs:
        argv = run.argv(tmp_path / run.run_id, tmp_path / "data.csv")
        assert argv[argv.index("--criteria") + 1] == str(tmp_path / "criteria.toml")
        assert argv[argv.index("--junit-xml") + 1] == str(tmp_path / run.run_id / "junit.xml")
        assert "--baseline" not in argv


def test_a_bad_criteria_file_is_refused_with_the_spec(tmp_path):
    (tmp_path / "criteria.toml").write_text("[criteria.pm]\nkind = 'rmse'\n")
    spec = tmp_path / "spec.toml"
    spec.write_text('[fixed]\nrows = 300\ncriteria = "criteria.toml"\n')
    with pytest.raises(SpecError, match=r"spec.toml: run \(the only run\): .*\[criteria.pm\] has no limit"):
        parse_spec(spec.read_text(), spec)
