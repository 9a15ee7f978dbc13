import json
import subprocess
import sys

import pytest

from bench.cli import main
from target_sim.artifact import load_artifact


@pytest.mark.slow
def test_identify_writes_loadable_artifacts_of_all_kinds(default_data_dir, tmp_path, capsys):
    out = tmp_path / "m.json"
    assert main(["identify", "--data", str(default_data_dir), "--swarm", "12", "--iterations", "3",
                 "--lm-iterations", "4", "--all-kinds", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary["artifacts"]) == {"hammerstein", "lti-lptn", "pv-lptn"}
    assert len(summary["pso_history"]) == 3
    assert all(b <= a for a, b in zip(summary["pso_history"], summary["pso_history"][1:], strict=False))
    kinds = {load_artifact(p).kind for p in summary["artifacts"].values()}
    assert kinds == {"hammerstein", "lti-lptn", "pv-lptn"}
    assert load_artifact(out).realization == "delta"
    assert summary["validation"]["hammerstein"]["max_abs_f32_minus_f64_C"] < 0.005
    assert set(summary["validation"]["lti-lptn"]) == {"float64", "float32", "max_abs_f32_minus_f64_C"}


@pytest.mark.slow
def test_identify_can_deploy_the_original_realization_through_the_polynomial_path(default_data_dir, tmp_path,
                                                                                  capsys):
    out = tmp_path / "orig.json"
    assert main(["identify", "--data", str(default_data_dir), "--swarm", "6", "--iterations", "2",
                 "--lm-iterations", "3", "--fit-path", "polynomial", "--realization", "original", "--out", str(out),
                 "--json"]) == 0
    art = load_artifact(out)
    assert art.realization == "original" and art.content["provenance"]["lm"]["coordinates"] == "original"
    assert art.content["linear_block"]["condition_number"] > 30


@pytest.mark.slow
def test_evaluate_json_at_the_artifact_step(default_data_dir, capsys):
    assert main(["evaluate", "--data", str(default_data_dir), "--dt", "0.5", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    by_model = {r["model"]: r for r in report["rows"]}
    ham, lti = by_model["hammerstein"], by_model["lti-lptn"]
    assert ham["float32"]["winding"]["rmse"] < 0.5 * lti["float32"]["winding"]["rmse"]
    for row in report["rows"]:
        m = row["float64"]["winding"]
        assert abs(m["rmse"] ** 2 - m["mse"]) < 1e-9


@pytest.mark.slow
def test_identify_with_a_missing_dataset_says_how_to_make_it(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "bench", "identify", "--data", str(tmp_path)],
                          capture_output=True, text=True)
    assert proc.returncode == 1
    assert "is missing; run 'bench data --out" in proc.stderr and "Traceback" not in proc.stderr
