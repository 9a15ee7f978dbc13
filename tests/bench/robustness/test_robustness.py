"""`bench robustness` on a small data slice: the target's float32 code on lanes equals its one-trajectory run bit
for bit, a bad spec is one sentence with nothing written, a perturbation that makes a model diverge is reported as
diverged (no number), an interrupted study resumed gives the same table, and a study on the local Dask cluster gives
the same table as a serial loop."""

from __future__ import annotations

import json
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bench.model.default import default_artifact_path
from bench.robustness.lanes import nominal_steps, run_lanes
from target_sim.artifact import load_artifact
from target_sim.model import run_offline

from helpers import ROOT, run_cli, subprocess_env

SPEC = """
[study]
name = "small"
seeds = 3
kinds = ["noise", "bias", "parameter", "initial", "jitter", "dropout"]
[perturbations.noise]
subjects = ["torque"]
[perturbations.bias]
subjects = ["coolant"]
[perturbations.dropout]
subjects = ["speed"]
[perturbations.parameter]
subjects = ["C_w", "P_dc"]
[perturbations.initial]
subjects = ["magnet"]
[filters]
kinds = ["lowpass", "moving-mean"]
time_constants = [1.0]
"""


ROWS = "400"


@pytest.fixture(scope="module")
def spec(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("spec") / "small.toml"
    path.write_text(SPEC)
    return path


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory, spec, small_dataset) -> tuple[Path, dict]:
    """The small study run straight through in a plain loop: the table the others must equal."""
    out = tmp_path_factory.mktemp("serial") / "out"
    return out, study(out, spec, small_dataset, "--serial")


def study(out: Path, spec: Path, data: Path, *extra: str, check: bool = True) -> dict:
    result = run_cli("-m", "bench", "robustness", "--data", str(data), "--spec", str(spec), "--out", str(out),
                     "--rows", ROWS, "--json", *extra)
    if check:
        assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def tables(out: Path) -> list[dict]:
    return json.loads((out / "report" / "robustness.json").read_text())["studies"]


@pytest.mark.parametrize("kind", ["hammerstein", "lti-lptn", "pv-lptn"])
def test_lanes_run_the_targets_code_bit_for_bit(kind, small_dataset):
    from bench.drive.dataset import load_dataset
    from bench.model.artifact_eval import artifact_drive
    from bench.model.runs import initial_temperatures

    artifact = load_artifact(default_artifact_path(kind))
    dataset = load_dataset(small_dataset)
    drive = artifact_drive(artifact, dataset)
    noisy = drive + np.random.default_rng(3).normal(0, 5, drive.shape)
    start = initial_temperatures(dataset)
    lanes = [nominal_steps(d, artifact.data_sample_period, artifact.dt) for d in (drive, noisy)]
    got = run_lanes(artifact, lanes, np.stack([start, start + 2], axis=1))
    for index, (d, y0) in enumerate([(drive, start), (noisy, start + 2)]):
        _, expected = run_offline(artifact, d, y0)
        assert np.array_equal(got[index], expected)


BAD_SPECS = [("[perturbations.noise]\ntorque = [-1.0]\n", "torque holds -1, which must not be negative"),
             ("[perturbations.nosie]\n", "[perturbations.nosie] is not a perturbation kind"),
             ("[perturbations.parameter]\nC_w = [-120]\n", "C_w holds -120, which must be above -100 %"),
             ("[perturbations.bias]\nvoltage = [1.0]\n", "unknown key 'voltage'"),
             ("[study]\nseeds = 0\n", "seeds must be a whole number from 1"),
             ("[filters]\ntime_constants = [0]\n", "time_constants must be positive seconds"),
             ("[study\n", "is not valid TOML")]


@pytest.mark.parametrize(("text", "said"), BAD_SPECS)
def test_a_bad_spec_is_one_sentence(text, said):
    from bench.robustness.kinds import PERTURBATIONS
    from bench.robustness.spec import SpecError, parse_spec

    artifact = load_artifact(default_artifact_path())
    with pytest.raises(SpecError) as raised:
        parse_spec(text, Path("bad.toml"), {n: k.subjects(artifact) for n, k in PERTURBATIONS.items()})
    message = str(raised.value)
    assert said in message and message.startswith("bad.toml") and "\n" not in message


@pytest.mark.parametrize(("content", "said"), [
    (None, "does not exist; give the path of a TOML spec, e.g. examples/robustness/default.toml"),
    (b"[study]\nname = \"\xff\"\n", "cannot be read ("),
])
def test_a_missing_or_unreadable_spec_file_is_one_sentence(tmp_path, content, said):
    from bench.robustness.kinds import PERTURBATIONS
    from bench.robustness.spec import SpecError, load_spec

    path = tmp_path / "spec.toml"
    if content is not None:
        path.write_bytes(content)
    artifact = load_artifact(default_artifact_path())
    with pytest.raises(SpecError) as raised:
        load_spec(path, {n: k.subjects(artifact) for n, k in PERTURBATIONS.items()})
    message = str(raised.value)
    assert message.startswith(f"the robustness spec {path} ") and said in message and "\n" not in message


def test_a_bad_spec_exits_2_with_nothing_written(tmp_path, small_dataset):
    bad = tmp_path / "bad.toml"
    bad.write_text(BAD_SPECS[0][0])
    out = tmp_path / "out"
    result = run_cli("-m", "bench", "robustness", "--data", str(small_dataset), "--spec", str(bad), "--out", str(out))
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and BAD_SPECS[0][1] in lines[0] and "Traceback" not in result.stderr
    assert not out.exists()


def test_a_diverging_model_is_reported_as_diverged(tmp_path, small_dataset):
    # eq. 16: R_cy reaches zero near 151 °C coolant, where no forward-Euler step of the PV LPTN is stable
    spec = tmp_path / "diverge.toml"
    spec.write_text('[study]\nkinds = ["bias"]\n[perturbations.bias]\nsubjects = ["coolant"]\ncoolant = [2.0, 120.0]\n'
                    '[filters]\nenabled = false\n')
    out = tmp_path / "out"
    summary = study(out, spec, small_dataset, "--model", str(default_artifact_path("pv-lptn")), "--serial")
    assert (summary["cases"], summary["diverged"]) == (3, 1)
    (table,) = tables(out)
    by_magnitude = {c["magnitude"]: c for c in table["cases"]}
    assert by_magnitude[120.0]["diverged"] and "nodes" not in by_magnitude[120.0]
    assert "NaN" in by_magnitude[120.0]["reason"] or "±1000" in by_magnitude[120.0]["reason"]
    assert not by_magnitude[2.0]["diverged"] and by_magnitude[2.0]["nodes"]["winding"]["d_rmse_C"]["mean"] != 0
    assert table["worst"]["pm"]["diverged"] and table["worst"]["pm"]["magnitude"] == 120.0
    md = (out / "report" / "report.md").read_text()
    assert "**bias coolant** (diverged at 120 K)" in md and "diverged (1/1)" in md


@pytest.mark.slow
def test_the_local_cluster_and_a_serial_loop_give_the_same_table(tmp_path, spec, small_dataset, serial_run):
    serial_out, serial = serial_run
    local = study(tmp_path / "local", spec, small_dataset, "--workers", "2")
    assert local["cases"] == serial["cases"] == local["ran"] and local["workers"] == 2
    assert tables(tmp_path / "local") == tables(serial_out)
    (table,) = tables(tmp_path / "local")
    kinds = {c["kind"] for c in table["cases"]}
    assert kinds == {"noise", "bias", "dropout", "parameter", "initial", "jitter"}
    noise = next(c for c in table["cases"] if c["kind"] == "noise")
    assert noise["lanes"] == 3 and noise["nodes"]["pm"]["d_rmse_C"]["std"] > 0     # Monte Carlo spread
    initial = next(c for c in table["cases"] if c["kind"] == "initial" and c["magnitude"] > 0)
    assert initial["nodes"]["pm"]["d_rmse_C"]["mean"] > 0.5                         # a 10 K wrong magnet start shows
    assert {f["filter"] for f in table["filtering"]} == {"lowpass", "moving-mean"}
    assert {p.name for p in (tmp_path / "local" / "report").glob("*.png")} >= {
        f"tornado-default-model-on-{small_dataset.stem}-pm.png", f"filtering-default-model-on-{small_dataset.stem}.png"}


def _rows(out: Path) -> int:
    try:
        with sqlite3.connect(out / "robustness.sqlite") as db:
            return db.execute("SELECT count(*) FROM cases").fetchone()[0]
    except sqlite3.OperationalError:
        return 0


@pytest.mark.slow
def test_an_interrupted_study_resumed_gives_the_same_table(tmp_path, spec, small_dataset, serial_run):
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "bench", "robustness", "--data", str(small_dataset), "--spec", str(spec),
            "--out", str(out), "--rows", ROWS, "--serial"]
    proc = subprocess.Popen(argv, cwd=ROOT, env=subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 120
    while _rows(out) < 3 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.1)
    assert proc.poll() is None, "the study ended before it could be interrupted"
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM and "Traceback" not in stderr
    done_before = _rows(out)
    assert done_before >= 3
    resumed = study(out, spec, small_dataset, "--serial", "--resume")
    assert resumed["skipped"] == done_before and resumed["ran"] == resumed["cases"] - done_before
    straight_out, straight = serial_run
    assert straight["cases"] == resumed["cases"]
    assert tables(out) == tables(straight_out)
    again = run_cli("-m", "bench", "robustness", "--data", str(small_dataset), "--spec", str(spec), "--out", str(out))
    assert again.returncode == 2 and "already holds a robustness study" in again.stderr


def test_a_resume_with_another_spec_is_refused_before_any_case(tmp_path, spec, small_dataset, serial_run, capsys):
    """`--resume` into a finished study with another spec (or other --seeds) mixed both studies' cases in one table;
    now one sentence, exit 2, before any case, the table as it was (the same spec resumes, every case skipped)."""
    import shutil

    from bench.cli import main
    from bench.robustness.store import TABLE_NAME, CaseStore

    out = tmp_path / "out"
    shutil.copytree(serial_run[0], out)
    with CaseStore(out / TABLE_NAME) as store:
        before = store.meta(), store.rows()
    other = tmp_path / "other.toml"
    other.write_text(SPEC.replace("seeds = 3", "seeds = 2"))
    base = ["robustness", "--data", str(small_dataset), "--out", str(out), "--rows", ROWS, "--serial", "--resume",
            "--quiet"]
    for extra in (["--spec", str(other)], ["--spec", str(spec), "--seeds", "4"]):
        assert main([*base, *extra]) == 2, extra
        said = capsys.readouterr().err
        assert said.startswith(f"bench: error: {out} holds the robustness study 'small' of {spec} (spec sha256 ")
        assert said.count("\n") == 1 and "whose cases differ from this one's" in said, said
        with CaseStore(out / TABLE_NAME) as store:
            assert (store.meta(), store.rows()) == before
    assert main([arg for arg in base if arg != "--resume"] + ["--spec", str(spec)]) == 2   # exit 2 as campaign's
    assert "already holds a robustness study" in capsys.readouterr().err
    assert main([*base, "--spec", str(spec), "--json"]) == 0
    resumed = json.loads(capsys.readouterr().out)
    assert resumed["ran"] == 0 and resumed["skipped"] == resumed["cases"] == len(before[1])
