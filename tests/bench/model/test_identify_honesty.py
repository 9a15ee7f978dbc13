"""`bench identify` says what it cannot know: the parameters the data do not determine (by side), advice true for
the command as given, and validation or training files that cannot check the speed-dependent terms."""

import numpy as np
import pytest

from bench.commands.identify import _bound_warning, _deployment, _print_uncertainty, _warnings
from bench.drive.dataset import load_dataset
from bench.model.coverage import coverage_warnings
from bench.model.undetermined import SIDES, undetermined
from bench.thermal.parameters import TABLE1, LptnParameters

from helpers import synthetic_columns, write_synthetic_dataset

NAMES = LptnParameters.names()
MAGNET = ["C_m", "R_tm0", "a_tm", "R_ma0", "a_ma"]     # what the IPM motor's measured data left undetermined


def _record(unidentifiable, correlated=()) -> dict:
    """A synthetic `uncertainty` record: the named parameters unidentifiable, the pairs (a, b, r) correlated."""
    corr = np.eye(len(NAMES))
    for a, b, r in correlated:
        i, j = NAMES.index(a), NAMES.index(b)
        corr[i, j] = corr[j, i] = r
    table = {n: {"value": getattr(TABLE1, n), "se": None if n in unidentifiable else 0.01,
                 "relative_se": None if n in unidentifiable else 0.05} for n in NAMES}
    return {"parameters": table, "correlation": corr.tolist(), "names": NAMES,
            "unidentifiable": list(unidentifiable), "nodes": ["winding", "pm"]}


def test_the_sides_cover_every_parameter_once():
    covered = [n for side in SIDES.values() for n in side.parameters]
    assert sorted(covered) == sorted(NAMES)


def test_the_undetermined_parameters_are_one_sentence_by_side_with_their_meaning():
    gaps = undetermined(_record(MAGNET, [("R_ma0", "a_ma", -0.99996)]))
    assert gaps["parameters"] == MAGNET and gaps["sides"] == {"magnet": MAGNET}
    assert gaps["correlated_pairs"] == [{"parameters": ["R_ma0", "a_ma"], "r": -0.99996}]
    assert gaps["rule"] == {"relative_se_above": pytest.approx(0.693147), "or_se_above_share_of_range": 0.5,
                            "correlation_at_least": 0.999}
    assert gaps["sentence"] == (
        "the training data do not determine 5 of the 22 LPTN parameters: on the magnet side C_m, R_tm0, a_tm, "
        "R_ma0, a_ma, where the magnet estimate rests on the prior (add training profiles that heat the magnet "
        "differently from the winding: high speed at low torque); of R_ma0 and a_ma only their combination is "
        "determined (r = -0.99996)")


def test_a_pair_correlated_beyond_the_threshold_is_named_even_with_small_standard_errors():
    gaps = undetermined(_record(["k_2"], [("R_yw", "R_wt", 0.9995), ("R_yt", "C_t", 0.998)]))
    assert gaps["parameters"] == ["R_yw", "R_wt", "k_2"]       # the 0.998 pair is below the threshold
    assert gaps["sides"] == {"stator": ["R_yw", "R_wt"], "loss_split": ["k_2"]}
    assert "on the stator side R_yw, R_wt, where the winding estimate rests on the prior" in gaps["sentence"]
    assert "; in the stator iron-loss split k_2, where how the iron loss divides" in gaps["sentence"]
    assert gaps["sentence"].endswith("of R_yw and R_wt only their combination is determined (r = +0.99950)")


def test_nothing_undetermined_is_no_sentence():
    assert undetermined(None) is None and undetermined(_record([])) is None


def test_the_summary_and_the_warnings_name_the_undetermined_parameters(capsys):
    record = _record(MAGNET, [("R_ma0", "a_ma", -0.99996)])
    gaps = undetermined(record)
    _print_uncertainty(record, gaps)
    assert f"  {gaps['sentence']}\n" in capsys.readouterr().out
    # also when a parameter on the box's bound takes the place of the other warnings
    hit = {"name": "R_yw", "value": 0.9, "bound": "upper", "limit": 0.9}
    prov = {"pso": {"prior": "table1", "bounds": [0.5, 2.0]}, "polish": {"frozen": ["b_wm"]}}
    warnings = _warnings([hit], prov, gaps)
    assert len(warnings) == 2 and "bound of the search" in warnings[0] and warnings[1] == gaps["sentence"]
    assert _warnings([], prov, gaps)[0].startswith("b_wm was frozen at the prior's value")


# ---------------------------------------------------------------- which artifact to deploy

SELECTION_LTI = {"recommended": "lti-lptn", "selected_rms_C": 1.9, "lti_rms_C": 1.5}
SELECTION_HAM = {"recommended": "hammerstein", "selected_rms_C": 1.2, "lti_rms_C": 1.5}
ALL = {"hammerstein": "out/m.json", "lti-lptn": "out/m-lti-lptn.json", "pv-lptn": "out/m-pv-lptn.json"}


def _metrics(ham: tuple[float, float], lti: tuple[float, float]) -> dict:
    def one(w, pm):
        return {"float32": {"winding": {"rmse": w}, "pm": {"rmse": pm}}}

    return {"hammerstein": one(*ham), "lti-lptn": one(*lti)}


def test_deployment_with_all_kinds_names_the_file_it_wrote():
    sentence = _deployment(SELECTION_LTI, _metrics((2.0, 1.0), (1.5, 0.8)), ALL)
    assert sentence == ("the Hammerstein model is worse than the LTI LPTN it refines on left-out training files "
                        "(RMS Hammerstein 1.900 vs LTI 1.500 °C) and on the validation files (RMSE Hammerstein vs "
                        "LTI: winding 2.000 vs 1.500, pm 1.000 vs 0.800 °C); deploy the lti-lptn artifact this "
                        "command wrote, out/m-lti-lptn.json")
    assert "--all-kinds" not in sentence and "--kind" not in sentence


def test_deployment_without_the_lti_artifact_says_how_to_write_it():
    sentence = _deployment(SELECTION_LTI, _metrics((2.0, 1.0), (1.5, 0.8)), {"hammerstein": "out/m.json"})
    assert sentence.endswith("; deploy the lti-lptn artifact (write it with --kind lti-lptn, or --all-kinds for all "
                             "three kinds)")


def test_deployment_with_kind_lti_does_not_advise_it_again():
    sentence = _deployment(SELECTION_LTI, _metrics((2.0, 1.0), (1.5, 0.8)), {"lti-lptn": "out/lti.json"})
    assert sentence.endswith("deploy the lti-lptn artifact this command wrote, out/lti.json")
    assert "--kind" not in sentence


def test_deployment_says_when_the_evidence_disagrees():
    # the IPM case: the cross-validation favours the LTI network, the validation files the Hammerstein model
    sentence = _deployment(SELECTION_LTI, _metrics((1.3, 0.5), (1.6, 0.7)), ALL)
    assert sentence == ("the evidence disagrees on which model to deploy: the LTI LPTN is better on left-out "
                        "training files (RMS Hammerstein 1.900 vs LTI 1.500 °C), the Hammerstein model on the "
                        "validation files (RMSE Hammerstein vs LTI: winding 1.300 vs 1.600, pm 0.500 vs 0.700 °C); "
                        "compare out/m.json and out/m-lti-lptn.json with bench evaluate on profiles like those the "
                        "motor will run before choosing one")
    # and the reverse, with the LTI network not written
    reverse = _deployment(SELECTION_HAM, _metrics((1.3, 0.9), (1.6, 0.7)), {"hammerstein": "out/m.json"})
    assert reverse.startswith("the evidence disagrees on which model to deploy: the LTI LPTN is better on the "
                              "validation files (RMSE Hammerstein vs LTI: pm 0.900 vs 0.700 °C), the Hammerstein "
                              "model on left-out training files")
    assert reverse.endswith("write both with --all-kinds and compare them with bench evaluate on profiles like "
                            "those the motor will run before choosing one")


def test_no_deployment_sentence_when_the_hammerstein_model_is_better_everywhere():
    assert _deployment(SELECTION_HAM, _metrics((1.3, 0.5), (1.6, 0.7)), ALL) is None


HIT = [{"name": "R_yw", "value": 9.0, "bound": "upper", "limit": 9.0}]


@pytest.mark.parametrize(("prior", "bounds", "advice"), [
    ("table1", [0.5, 2.0], "(widen --bounds or use --prior auto)"),
    ("auto", [0.5, 2.0], "(widen --bounds)"),
    ("table1", [0.1, 10.0], "(use --prior auto)"),
    ("auto", [0.1, 10.0], "(a box this wide around a prior read from these data already holds any network they "
                          "support, so a wider one would only bend the network further: check the motor file's "
                          "losses and the data's units)"),
])
def test_the_bound_warning_advises_only_what_the_command_did_not_do(prior, bounds, advice):
    assert _bound_warning(HIT, prior, bounds).endswith(advice)


# ---------------------------------------------------------------- what the files can check

TOP_RPM = 9000.0


def _dataset(path, *, speed=None, torque_max=600.0):
    columns = synthetic_columns(400, torque_max=torque_max, speed_offset=3000.0)
    if speed is not None:
        columns["speed_rpm"] = np.round(speed(len(columns["time_s"])), 0)
    if torque_max < 600.0:
        columns["torque_Nm"] = np.clip(columns["torque_Nm"], -torque_max, torque_max)
    return load_dataset(write_synthetic_dataset(path, columns, "coverage test"))


def _standstill(rows):
    speed = np.zeros(rows)
    speed[::50] = 31.0      # the IPM validation file: a few samples at up to 31 rpm
    return speed


def test_files_that_cover_the_range_give_no_coverage_warning(tmp_path):
    train = [_dataset(tmp_path / "a.csv")]
    assert coverage_warnings(train, [_dataset(tmp_path / "b.csv")], TOP_RPM) == []


def test_a_standstill_validation_file_is_named_with_what_it_cannot_check(tmp_path):
    train = [_dataset(tmp_path / "train.csv")]
    still = _dataset(tmp_path / "still.csv", speed=_standstill)
    assert coverage_warnings(train, [still], TOP_RPM) == [
        "every validation file stays below 20 % of the motor's 9000 rpm (or at standstill in 90 % of its "
        "samples): still.csv (at most 31 rpm, at standstill in 100 % of its samples); the validation figures cannot "
        "check the speed-dependent convection (R_wm, R_tm, R_ma) or the speed-dependent iron and magnet losses"]
    moving = _dataset(tmp_path / "moving.csv")
    assert coverage_warnings(train, [still, moving], TOP_RPM) == [
        "the validation file still.csv (at most 31 rpm, at standstill in 100 % of its samples) stays below 20 % of "
        "the motor's 9000 rpm (or at standstill in 90 % of its samples), so it cannot check the speed-dependent "
        "convection (R_wm, R_tm, R_ma) or the speed-dependent iron and magnet losses; the other validation files "
        "can"]


def test_training_files_all_at_standstill_and_a_light_validation_load_are_named(tmp_path):
    train = [_dataset(tmp_path / "t1.csv", speed=_standstill)]
    light = _dataset(tmp_path / "light.csv", torque_max=40.0)
    warnings = coverage_warnings(train, [light], TOP_RPM)
    trained = float(np.abs(train[0].torque_Nm).max())
    assert warnings == [
        "every training file stays below 20 % of the motor's 9000 rpm (or at standstill in 90 % of its samples): "
        "t1.csv (at most 31 rpm, at standstill in 100 % of its samples); the fit cannot determine the "
        "speed-dependent convection (R_wm, R_tm, R_ma) or the speed-dependent iron and magnet losses, so their "
        "values will be the prior's",
        f"the validation file light.csv reaches at most 40 Nm, under 25 % of the training files' {trained:.0f} Nm, "
        "so it checks the model only at light load, not the copper losses and loss split it was trained on"]


def test_a_validation_file_hotter_than_every_training_file_is_named(tmp_path):
    """On the suite's air-cooled motor a validation profile reached 128 °C at the winding where the training files
    stayed below 98 °C; its error grew to a -6.6 K bias: an extrapolation, said before the fit."""
    columns = synthetic_columns(400, torque_max=600.0, speed_offset=3000.0)
    train = [load_dataset(write_synthetic_dataset(tmp_path / "t.csv", columns, "coverage test"))]
    hot = dict(columns, winding_C=columns["winding_C"] + 30.0)
    warm = dict(columns, winding_C=columns["winding_C"] + 5.0, pm_C=columns["pm_C"] + 5.0)
    trained = float(train[0].winding_C.max())
    found = coverage_warnings(train, [load_dataset(write_synthetic_dataset(tmp_path / "hot.csv", hot, "hot")),
                                      load_dataset(write_synthetic_dataset(tmp_path / "warm.csv", warm, "warm"))],
                              TOP_RPM)
    assert found == [f"the validation file hot.csv reaches {trained + 30:.0f} °C at the winding, 30 K above the "
                     f"training files' {trained:.0f} °C, so its figures check an extrapolation of the "
                     "temperature-dependent terms; add a training file that hot if the motor runs there"]
