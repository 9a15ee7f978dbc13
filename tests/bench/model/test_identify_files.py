"""`bench identify --motor --train --validate` and `bench evaluate --data FILE…` on a motor's own files."""

import json

import numpy as np
import pytest

from bench.cli import main
from bench.model.deploy import choose_kind
from bench.model.lptn_fit import FIXED_BOUNDS
from bench.motor.template import template
from target_sim.artifact import load_artifact

ROWS = 1500   # 25 min at 1 s
# how bench.model.coverage's warnings begin
COVERAGE_OPENINGS = ("the validation file", "every validation file", "every training file")


def _profile(seed: int) -> dict[str, np.ndarray]:
    """A 1 s profile of the template motor in the user's own names and units (speed in krpm, coolant in K, two
    winding sensors), with d/q currents."""
    rng = np.random.default_rng(seed)
    t = np.arange(ROWS, dtype=float)
    torque = np.clip(np.cumsum(rng.normal(0, 6, ROWS)) + 60, 0, 170)
    speed = np.clip(np.abs(np.cumsum(rng.normal(0, 150, ROWS))) + 2000, 0, 12000)
    i_q, i_d = 2.1 * torque, -0.012 * speed
    copper = 1.5 * 0.018 * (i_q**2 + i_d**2)
    rise = np.convolve(copper, np.exp(-np.arange(600) / 200.0) / 200.0)[:ROWS] * 0.05
    coolant = 40 + 3 * np.sin(t / 300)
    return {"speed_krpm": np.round(speed / 1000, 4), "torque": np.round(torque, 1),
            "coolant_K": np.round(coolant + 273.15, 2), "ambient": np.full(ROWS, 25.0),
            "w1": np.round(coolant + rise + 0.2, 1), "w2": np.round(coolant + rise - 0.2, 1),
            "magnet": np.round(coolant + 0.4 * rise, 1), "id": np.round(i_d, 1), "iq": np.round(i_q, 1)}


@pytest.fixture(scope="module")
def motor_files(tmp_path_factory):
    root = tmp_path_factory.mktemp("ipm")
    (root / "motor.toml").write_text(template("toml"))
    mapping = {"columns": {"speed_krpm": "speed_rpm", "torque": "torque_Nm", "coolant_K": "coolant_C",
                           "ambient": "ambient_C", "magnet": "pm_C", "id": "i_d_A", "iq": "i_q_A"},
               "units": {"speed_rpm": "krpm", "coolant_C": "K"},
               "derived": {"winding_C": {"mean_of": ["w1", "w2"]}},
               "time": {"column": None, "sample_period_s": 1.0}}
    (root / "mapping.json").write_text(json.dumps(mapping))
    for n in range(1, 4):
        columns = _profile(n)
        rows = zip(*columns.values(), strict=True)
        lines = [",".join(columns)] + [",".join(repr(float(v)) for v in row) for row in rows]
        (root / f"profile_{n:02d}.csv").write_text("\n".join(lines) + "\n")
    return root


def _identify(root, out, *extra):
    return main(["identify", "--motor", str(root / "motor.toml"), "--train", str(root / "profile_0[12].csv"),
                 "--validate", str(root / "profile_03.csv"), "--mapping", str(root / "mapping.json"),
                 "--swarm", "8", "--iterations", "2", "--lm-iterations", "3", "--all-kinds", "--out", str(out),
                 "--json", *extra])


@pytest.fixture(scope="module")
def identified(motor_files, tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "ham.json"
    capture = pytest.MonkeyPatch()
    import io
    import sys
    buffer = io.StringIO()
    capture.setattr(sys, "stdout", buffer)
    try:
        # the polish route and the cross-validated ridge, asked for, with the Hammerstein model at --out whatever the
        # validation file favours
        assert _identify(motor_files, out, "--polish", "2", "--freeze", "yes", "--kind", "hammerstein",
                         "--regularization", "cv") == 0
    finally:
        capture.undo()
    return out, json.loads(buffer.getvalue())


def test_identify_on_files_records_the_motor_and_the_split(identified, motor_files):
    out, summary = identified
    art = load_artifact(out)
    assert art.loss_model == "electrical" and art.drive_signals[-2:] == ("i_d_A", "i_q_A")
    assert art.dt == 1.0 and art.data_sample_period == 1.0   # Δt defaults to the data's period when longer
    prov = art.content["provenance"]
    assert prov["motor"]["name"] == "my-ipm-60kw" and len(prov["motor"]["sha256"]) == 64
    assert [f["file"] for f in prov["split"]["train"]] == ["profile_01.csv", "profile_02.csv"]
    assert [f["file"] for f in prov["split"]["validate"]] == ["profile_03.csv"]
    assert all(len(f["sha256"]) == 64 and f["rows"] == ROWS for f in prov["split"]["train"])
    assert prov["pso"]["prior"] == "auto" and prov["pso"]["bounds"] == [0.1, 10.0]
    auto = prov["pso"]["auto_prior"]
    assert set(auto["responses"]) == {"winding", "pm"} and auto["responses"]["winding"]["gain_stator_K_per_W"] > 0
    # asked to, the files route polishes; it gives error bars and cross-validates the Hammerstein ridge by default
    assert prov["polish"]["starts"] >= 1 and prov["polish"]["cost"] <= prov["polish"]["swarm_cost"]
    assert summary["pso_stalled_at"] is None and len(summary["pso_history"]) == 2     # 2 iterations: no stall yet
    names = prov["uncertainty"]["names"]
    assert set(prov["uncertainty"]["parameters"]) == set(names) and len(prov["uncertainty"]["correlation"]) == 22
    assert prov["lm"]["regularization"]["method"].startswith("leave-one-file-out cross-validation")
    assert summary["uncertainty"] == prov["uncertainty"] and summary["polish"] == prov["polish"]
    assert set(prov["baselines"]["copper_lowpass"]) == {"winding", "pm"}
    assert summary["split"] == prov["split"]
    # every parameter the fit left on a bound is named, in JSON and as a warning; then the frozen ones, the
    # parameters the data do not determine, and which model to deploy when the Hammerstein model did worse
    # (after the data's coverage warnings, said before the fit: profile_03 is hotter than the training files)
    coverage = [w for w in summary["warnings"] if w.startswith(COVERAGE_OPENINGS)]
    assert summary["warnings"][:len(coverage)] == coverage
    fitted = summary["warnings"][len(coverage):]
    hits = summary["parameters_on_bounds"]
    if hits:     # one sentence names them all
        assert all(f"{hit['name']} = " in fitted[0] for hit in hits)
        assert "bound of the search" in fitted[0]
    rest = fitted[1 if hits else 0:]
    frozen = prov["polish"]["frozen"]
    if any(hit["name"] not in FIXED_BOUNDS for hit in hits):   # the prior cannot hold the motor: no frozen sentence
        assert not any("frozen" in w for w in rest)
    else:
        assert all(name in rest[0] for name in frozen) and set(frozen) <= set(names)
        rest = rest[1 if frozen else 0:]
    gaps = summary["undetermined"]      # said in any case
    assert set(prov["uncertainty"]["unidentifiable"]) <= set(gaps["parameters"] if gaps else [])
    assert bool(gaps) == any(w.startswith("the training data do not determine") for w in rest)
    if gaps:
        assert rest[0] == gaps["sentence"] and all(name in rest[0] for name in gaps["parameters"])
    worse = prov["lm"]["regularization"]["recommended"] == "lti-lptn"
    assert worse <= any("deploy the lti-lptn artifact" in w or "the evidence disagrees" in w for w in rest)
    for metrics in summary["validation"].values():
        assert {"rmse", "max_abs", "mse", "nrmse"} <= set(metrics["float32"]["winding"])


def test_evaluate_on_files_gives_per_file_pooled_and_baselines(identified, motor_files, tmp_path, capsys):
    out, _ = identified
    lti = out.with_name("ham-lti-lptn.json")
    plots = tmp_path / "plots"
    assert main(["evaluate", "--model", str(out), "--model", str(lti), "--data", str(motor_files / "profile_0[23].csv"),
                 "--mapping", str(motor_files / "mapping.json"), "--plots", str(plots), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    ham, lti_report = report["models"]
    assert ham["kind"] == "hammerstein" and lti_report["kind"] == "lti-lptn"
    assert [f["file"].split("/")[-1] for f in ham["files"]] == ["profile_02.csv", "profile_03.csv"]
    for node in ("winding", "pm"):
        per_file = [f["nodes"][node]["float32"] for f in ham["files"]]
        pooled = ham["pooled"]["nodes"][node]["float32"]
        assert pooled["max_abs"] == max(m["max_abs"] for m in per_file)
        assert pooled["mse"] == pytest.approx(np.mean([m["mse"] for m in per_file]))   # equal lengths
        assert set(ham["pooled"]["baselines"]) == {"coolant", "copper_lowpass"}
    assert ham["pooled"]["max_abs_f32_minus_f64_C"] < 0.01
    assert sorted(p.name for p in plots.iterdir()) == ["profile_02.png", "profile_03.png"]


def test_a_bad_split_is_one_sentence(motor_files, tmp_path, capsys):
    base = ["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
            "--out", str(tmp_path / "m.json")]
    cases = [
        (["--train", str(motor_files / "profile_01.csv")], "--validate is missing"),
        (["--train", str(motor_files / "profile_0*.csv"), "--validate", str(motor_files / "profile_03.csv")],
         "is in both --train and --validate"),
        (["--train", str(motor_files / "nothing_*.csv"), "--validate", str(motor_files / "profile_03.csv")],
         "--train"),
        ([], "with --motor, name the data with --train"),
        (["--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_03.csv"),
          "--dt", "0.5"], "is shorter than the data's 1 s sample period"),
    ]
    for extra, expected in cases:
        assert main(base + extra) != 0
        err = capsys.readouterr().err
        assert expected in err and err.count("\n") == 1 and "Traceback" not in err, (extra, err)
    assert not (tmp_path / "m.json").exists()


def test_an_electrical_motor_needs_currents(motor_files, tmp_path, capsys):
    mapping = json.loads((motor_files / "mapping.json").read_text())
    for source in ("id", "iq"):
        mapping["columns"].pop(source)
    (tmp_path / "mapping.json").write_text(json.dumps(mapping))
    assert main(["identify", "--motor", str(motor_files / "motor.toml"), "--train",
                 str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_03.csv"),
                 "--mapping", str(tmp_path / "mapping.json"), "--out", str(tmp_path / "m.json")]) == 1
    err = capsys.readouterr().err
    assert "has no d/q current columns" in err and "my-ipm-60kw" in err


def test_a_bad_mapping_or_motor_is_one_sentence_and_writes_nothing(motor_files, tmp_path, capsys):
    bad_mapping = tmp_path / "mapping.json"
    bad_mapping.write_text(json.dumps({"columns": {"speed_krpm": "speed"}}))
    bad_motor = tmp_path / "motor.json"
    bad_motor.write_text(json.dumps({**json.loads(template("json")), "pole_pairs": 0}))
    common = ["--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_03.csv"),
              "--out", str(tmp_path / "m.json")]
    cases = [
        (["--motor", str(motor_files / "motor.toml"), "--mapping", str(bad_mapping)], "'speed'"),
        (["--motor", str(bad_motor), "--mapping", str(motor_files / "mapping.json")], "pole_pairs"),
        (["--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
          "--bounds", "2,3"], "--bounds must be two factors"),
    ]
    for extra, expected in cases:
        assert main(["identify", *extra, *common]) != 0
        err = capsys.readouterr().err
        assert expected in err and err.count("\n") == 1 and "Traceback" not in err, (extra, err)
    assert set(tmp_path.iterdir()) == {bad_mapping, bad_motor}   # no artifact, no temporary file


def test_the_summary_names_what_the_data_cannot_determine_or_check(motor_files, tmp_path, capsys):
    """End to end, a tiny fit: a standstill validation file is named before the fit, and the human summary (not
    only --json) names the parameters the data do not determine, by side, as the warning does."""
    columns = _profile(3)
    columns["speed_krpm"] = np.where(np.arange(ROWS) % 50 == 0, 0.031, 0.0)    # at most 31 rpm
    rows = zip(*columns.values(), strict=True)
    lines = [",".join(columns)] + [",".join(repr(float(v)) for v in row) for row in rows]
    (tmp_path / "standstill.csv").write_text("\n".join(lines) + "\n")
    assert main(["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
                 "--train", str(motor_files / "profile_01.csv"), "--validate", str(tmp_path / "standstill.csv"),
                 "--swarm", "4", "--iterations", "1", "--lm-iterations", "1", "--polish", "1",
                 "--regularization", "fixed", "--out", str(tmp_path / "m.json")]) == 0
    out, err = capsys.readouterr()
    warnings = [line.removeprefix("bench: warning: ") for line in err.splitlines() if line.startswith("bench: warn")]
    assert warnings[0].startswith("every validation file stays below 20 % of the motor's 14000 rpm")
    assert "standstill.csv (at most 31 rpm, at standstill in 100 % of its samples)" in warnings[0]
    assert warnings[0].endswith("cannot check the speed-dependent convection (R_wm, R_tm, R_ma) or the "
                                "speed-dependent iron and magnet losses")
    sentence = next(w for w in warnings if w.startswith("the training data do not determine"))
    assert f"  {sentence}\n" in out       # the summary says it too, by default
    assert "on the magnet side C_m, " in sentence and "where the magnet estimate rests on the prior" in sentence


def test_without_a_polish_the_files_path_still_names_what_the_data_cannot_determine(motor_files, tmp_path, capsys):
    """--polish 0 on --train files: the standard errors are taken at the swarm's result, so the summary and --json
    still name the undetermined parameters (the built-in campaign's path computes none: its artifact keeps its
    bytes)."""
    assert main(["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
                 "--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_02.csv"),
                 "--swarm", "4", "--iterations", "1", "--lm-iterations", "1", "--polish", "0",
                 "--regularization", "fixed", "--out", str(tmp_path / "m.json"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["polish"] is None
    assert summary["uncertainty"]["unidentifiable"] and summary["undetermined"]["parameters"]
    assert "standard_errors" in summary["timings_s"]


def test_without_a_swarm_the_polish_starts_from_the_prior_and_the_seed_changes_nothing(motor_files, tmp_path,
                                                                                         capsys):
    """--swarm 0: no search; the polish's one start is the prior itself, so two seeds give the same network and model;
    --prior-factor is recorded with the polish's prior. Bad values are one sentence before any work."""
    common = ["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
              "--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_02.csv"),
              "--swarm", "0", "--lm-iterations", "1", "--regularization", "fixed", "--kind", "lti-lptn",
              "--prior-factor", "2", "--json"]
    summaries = []
    for seed in ("0", "7"):
        assert main([*common, "--seed", seed, "--out", str(tmp_path / f"seed{seed}.json")]) == 0
        summaries.append(json.loads(capsys.readouterr().out))
    polished = summaries[0]["polish"]
    assert polished["starts"] == 1 and polished["prior"]["factor"] == 2.0
    assert len(summaries[0]["pso_history"]) == 1       # the prior's cost, no iteration
    for key in ("lptn_parameters", "validation", "lm"):
        assert summaries[0][key] == summaries[1][key], key
    for bad, fragment in ((("--swarm", "1"), "--swarm must be 0"), (("--prior-factor", "1"), "--prior-factor must"),
                          (("--polish", "0"), "does not polish")):
        assert main([*common[:-1], *bad, "--out", str(tmp_path / "bad.json")]) != 0
        err = capsys.readouterr().err
        assert fragment in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "bad.json").exists()


def test_the_files_path_factors_blocked_and_says_so_where_the_fits_say_how_they_ran(motor_files, tmp_path, capsys):
    """--train files factor the LM's Jacobian blocked by default (the suite's decision): the polish's method and the
    Hammerstein fit's record name it; --lm-factorization minpack adds nothing, as the built-in campaign, whose
    packaged artifacts keep their bytes."""
    common = ["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
              "--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_02.csv"),
              "--swarm", "0", "--lm-iterations", "2", "--regularization", "fixed", "--kind", "hammerstein",
              "--json"]
    assert main([*common, "--out", str(tmp_path / "blocked.json")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert "blocked QR" in summary["polish"]["method"] and "blocked QR" in summary["lm"]["factorization"]
    assert main([*common, "--lm-factorization", "minpack", "--out", str(tmp_path / "minpack.json")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert "(MINPACK)" in summary["polish"]["method"] and "factorization" not in summary["lm"]
    assert main([*common, "--lm-factorization", "qr", "--out", str(tmp_path / "bad.json")]) != 0
    err = capsys.readouterr().err
    assert "--lm-factorization" in err and "Traceback" not in err and not (tmp_path / "bad.json").exists()


def test_the_files_path_polishes_by_default_unless_the_prior_is_adapted(motor_files, tmp_path, capsys):
    """--polish unset: the motor suite's choice (docs/method.md): --train files are polished from POLISH_STARTS
    starts, freezing what the data cannot place (the record names what was frozen, if anything), from the
    automatic, the motor's own or a named prior; an adapted foreign network (Table 1 named in a prior file,
    --adapt-prior yes) is not."""
    from bench.commands.identify import default_polish
    from bench.model.polish import POLISH_STARTS

    assert default_polish(files=True, adapt=False) == POLISH_STARTS
    assert default_polish(files=True, adapt=True) == 0 and default_polish(files=False, adapt=False) == 0
    common = ["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
              "--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_02.csv"),
              "--swarm", "4", "--iterations", "1", "--lm-iterations", "1", "--regularization", "fixed",
              "--kind", "lti-lptn", "--json"]
    assert main([*common, "--prior", "auto", "--out", str(tmp_path / "auto.json")]) == 0
    polished = json.loads(capsys.readouterr().out)["polish"]
    assert polished["starts"] == POLISH_STARTS and isinstance(polished["frozen"], list)
    (tmp_path / "table1-prior.json").write_text('{"parameters": "table1"}')
    table1 = ["--prior", str(tmp_path / "table1-prior.json")]
    assert main([*common, *table1, "--adapt-prior", "yes", "--out", str(tmp_path / "adapted.json")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["adapted_prior"] and summary["polish"] is None
    assert main([*common, *table1, "--out", str(tmp_path / "table1.json")]) == 0    # named, not adapted: polished
    summary = json.loads(capsys.readouterr().out)
    assert not summary.get("adapted_prior") and summary["polish"]["starts"] == POLISH_STARTS


def test_kind_auto_deploys_the_kind_the_validation_file_favours(motor_files, tmp_path, capsys):
    """The default with --train files: all three kinds from one fit, the one with the smallest validation winding +
    magnet MSE at --out, the others beside it, the choice in --json and in every artifact's provenance."""
    out = tmp_path / "m.json"
    assert main(["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
                 "--train", str(motor_files / "profile_02.csv"), "--validate", str(motor_files / "profile_01.csv"),
                 "--swarm", "4", "--iterations", "1", "--lm-iterations", "2", "--regularization", "fixed",
                 "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary["validation"]) == {"lti-lptn", "pv-lptn", "hammerstein"}
    chosen = choose_kind(summary["validation"])
    deployed = summary["deployed_kind"]
    assert deployed == chosen.kind == summary["deployment"]["deployed_kind"]
    # this split's Hammerstein model is worse than its network (measured: 26.85 K² LTI, 26.85 pv, 27.92 Hammerstein)
    assert deployed == "lti-lptn" and chosen.mse_K2["hammerstein"] > 1.02 * chosen.mse_K2["lti-lptn"]
    assert summary["deployment"]["validation_mse_K2"] == pytest.approx(chosen.mse_K2)
    assert summary["deployment"]["sentence"] == chosen.sentence(str(out))
    assert summary["artifacts"] == {k: str(out if k == deployed else tmp_path / f"m-{k}.json")
                                    for k in ("hammerstein", "lti-lptn", "pv-lptn")}
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["m.json", *(f"m-{k}.json" for k in
                                                                              summary["artifacts"] if k != deployed)])
    assert load_artifact(out).kind == deployed
    for kind, path in summary["artifacts"].items():
        art = load_artifact(path)
        assert art.kind == kind and art.content["provenance"]["deployment"]["deployed_kind"] == deployed
    assert not any("deploy the lti-lptn artifact" in w for w in summary["warnings"])


def test_a_kind_the_target_would_refuse_is_neither_deployed_nor_written(motor_files, tmp_path, capsys, monkeypatch):
    """A kind whose artifact the target refuses (its step unstable somewhere in the operating range: the PV LPTN's
    forward Euler at 1 s on a suite motor's fold) does not end the identification: --kind auto deploys the best of
    the others and says why that kind has no file; asked for by name, it is one sentence and no file."""
    from target_sim.kinds import MODEL_KINDS

    why = "artifact lti-lptn: unstable here (test)"
    monkeypatch.setattr(MODEL_KINDS["lti-lptn"], "instability", lambda artifact: why)   # this kind only
    common = ["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
              "--train", str(motor_files / "profile_02.csv"), "--validate", str(motor_files / "profile_01.csv"),
              "--swarm", "4", "--iterations", "1", "--lm-iterations", "2", "--regularization", "fixed"]
    out = tmp_path / "auto" / "m.json"
    assert main([*common, "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["validation"]["lti-lptn"] == {"refused": why}
    assert summary["deployed_kind"] == "pv-lptn"     # the lti-lptn network's twin (26.85 K² both, above)
    assert set(summary["artifacts"]) == {"pv-lptn", "hammerstein"}
    assert not (tmp_path / "auto" / "m-lti-lptn.json").exists()
    assert f"no lti-lptn artifact written (the target would refuse it): {why}" in summary["warnings"]
    named = tmp_path / "named" / "m.json"
    assert main([*common, "--kind", "lti-lptn", "--out", str(named)]) == 1
    err = capsys.readouterr().err
    assert err.strip().endswith(why) and "Traceback" not in err
    assert not named.parent.exists() or not any(named.parent.iterdir())


def test_kind_auto_without_validation_files_is_refused_before_any_work(motor_files, tmp_path, capsys):
    assert main(["identify", "--motor", str(tmp_path / "no-such-motor.toml"), "--train",
                 str(motor_files / "profile_01.csv"), "--kind", "auto", "--out", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "--kind auto chooses the deployed kind on held-out validation files: name them with --validate" in err
    assert not any(tmp_path.iterdir())


class _Stop(Exception):
    pass


@pytest.mark.parametrize(("extra", "freeze", "stator_weight"), [((), True, "rule"),
                                                                  (("--freeze", "no", "--stator-weight", "fixed"),
                                                                   False, "fixed")])
def test_the_freezing_and_stator_weight_options_reach_the_identification(motor_files, tmp_path, monkeypatch, extra,
                                                                         freeze, stator_weight):
    import bench.model.identify

    asked = {}

    def identify(*args, **kwargs):
        asked.update(kwargs)
        raise _Stop

    monkeypatch.setattr(bench.model.identify, "identify", identify)
    with pytest.raises(_Stop):
        _identify(motor_files, tmp_path / "m.json", *extra)
    assert asked["freeze"] is freeze and asked["stator_weight"] == stator_weight


def test_a_named_parameter_set_is_not_frozen_at_by_default(motor_files, tmp_path, monkeypatch):
    """--freeze unset: freezing at the motor's own or automatic prior (the suite's decision), not at a named
    parameter set as named (Table 1 is another machine's network), unless it was adapted to the data first."""
    import bench.model.identify
    from bench.commands.identify import default_freeze
    from bench.motor.description import ThermalPrior, automatic_prior
    from bench.thermal.parameters import TABLE1

    table1 = ThermalPrior(TABLE1, "table1")
    assert default_freeze(ThermalPrior(TABLE1, "file"), adapt=False) and default_freeze(automatic_prior(), False)
    assert not default_freeze(table1, adapt=False) and not default_freeze(None, adapt=False)
    assert default_freeze(table1, adapt=True)
    asked = {}

    def identify(*args, **kwargs):
        asked.update(kwargs)
        raise _Stop

    monkeypatch.setattr(bench.model.identify, "identify", identify)
    (tmp_path / "table1-prior.json").write_text('{"parameters": "table1"}')
    with pytest.raises(_Stop):
        _identify(motor_files, tmp_path / "m.json", "--prior", str(tmp_path / "table1-prior.json"))
    assert asked["freeze"] is False


def test_loss_scales_are_fitted_only_when_asked_and_the_artifact_carries_them(motor_files, tmp_path, capsys):
    """--loss-scales fit: the summary gives each factor within the box and every artifact's loss model holds the
    motor file's iron and magnet coefficients times them (copper untouched); the default (none) leaves them."""
    from bench.model.loss_scales import SCALE_BOX
    from bench.motor.description import load_motor

    common = ["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
              "--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_02.csv"),
              "--swarm", "4", "--iterations", "1", "--lm-iterations", "1", "--regularization", "fixed",
              "--kind", "hammerstein", "--json"]
    given = load_motor(motor_files / "motor.toml").loss_model
    assert main([*common, "--out", str(tmp_path / "plain.json")]) == 0
    assert json.loads(capsys.readouterr().out)["loss_scales"] is None
    plain = load_artifact(tmp_path / "plain.json")
    assert float(plain.array("losses", "magnet_W", dtype=np.float64)) == given.magnet_W
    assert main([*common, "--loss-scales", "fit", "--out", str(tmp_path / "scaled.json")]) == 0
    summary = json.loads(capsys.readouterr().out)
    factors = summary["loss_scales"]["factors"]
    assert set(factors) == {"p_stator", "p_magnet"}
    assert all(SCALE_BOX[0] <= f <= SCALE_BOX[1] for f in factors.values())
    assert any(abs(f - 1.0) > 1e-4 for f in factors.values())      # they moved: the check below can fail
    assert summary["timings_s"]["scales"] > 0
    scaled = load_artifact(tmp_path / "scaled.json")
    for key, name in (("iron_hysteresis_W", "p_stator"), ("iron_eddy_W", "p_stator"), ("magnet_W", "p_magnet")):
        expected = getattr(given, key) * factors[name]
        assert float(scaled.array("losses", key, dtype=np.float64)) == pytest.approx(expected, rel=1e-6)
    assert float(scaled.array("losses", "stator_resistance_ohm", dtype=np.float64)) == given.stator_resistance_ohm
    assert float(scaled.array("losses", "ac_factor", dtype=np.float64)) == given.ac_factor


def test_the_files_path_keeps_the_hammerstein_poles_by_default(motor_files, tmp_path, capsys):
    """--hammerstein-poles unset: the decision rule's choice (docs/method.md, the rule's margin): the poles are kept
    on the files path as in the built-in campaign; --hammerstein-poles fit is obeyed."""
    from bench.model.hammerstein_fit import POLES_FIT

    common = ["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
              "--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_02.csv"),
              "--swarm", "4", "--iterations", "1", "--lm-iterations", "2", "--polish", "0",
              "--regularization", "fixed", "--kind", "hammerstein"]
    for given, fitted in (([], False), (["--hammerstein-poles", POLES_FIT], True)):
        out = tmp_path / f"m{len(given)}.json"
        assert main([*common, *given, "--out", str(out)]) == 0
        lm = json.loads(out.read_text())["provenance"]["lm"]
        assert ("poles" in lm) is fitted, lm.keys()
    capsys.readouterr()


def test_the_network_cost_reaches_the_swarm_and_the_polish_and_is_recorded(motor_files, tmp_path, capsys):
    """--network-cost pooled: the swarm's history and the polish's costs are the pooled criterion's (log Σ w MSE of
    the kept network, recomputed here), the provenance names it; the default (likelihood) is not recorded."""
    common = ["identify", "--motor", str(motor_files / "motor.toml"), "--mapping", str(motor_files / "mapping.json"),
              "--train", str(motor_files / "profile_01.csv"), "--validate", str(motor_files / "profile_02.csv"),
              "--swarm", "4", "--iterations", "1", "--lm-iterations", "1", "--polish", "1",
              "--regularization", "fixed", "--kind", "hammerstein"]
    costs = {}
    for cost in ("likelihood", "pooled"):
        out = tmp_path / f"{cost}.json"
        assert main([*common, "--network-cost", cost, "--out", str(out)]) == 0
        pso = json.loads(out.read_text())["provenance"]["pso"]
        assert pso.get("criterion") == (None if cost == "likelihood" else cost)
        costs[cost] = json.loads(out.read_text())["provenance"]["polish"]["cost"]
    capsys.readouterr()
    # a log of a sum of MSEs (K², several nodes) is positive here; a sum of four logs of small MSEs is not the same
    assert costs["pooled"] != costs["likelihood"]
