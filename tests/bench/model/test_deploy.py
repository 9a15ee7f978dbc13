"""`bench identify --kind auto`'s rule: the smallest pooled winding + magnet float32 MSE on the validation files
deploys, a tie goes to the simpler kind, a diverged kind never deploys; and what the command then warns."""

import math

import pytest

from bench.commands.identify import _deployment
from bench.model.deploy import CANDIDATES, RULE, choose_kind, validation_score

ALL = {"hammerstein": "out/m-hammerstein.json", "lti-lptn": "out/m.json", "pv-lptn": "out/m-pv-lptn.json"}


def _figures(winding_mse: float, pm_mse: float) -> dict:
    def node(mse):
        return {"mse": mse, "rmse": math.sqrt(mse) if mse >= 0 else math.nan}

    return {"float32": {"winding": node(winding_mse), "pm": node(pm_mse)},
            "float64": {"winding": node(0.0), "pm": node(0.0)}}   # float64 never decides


def _metrics(**by_kind: tuple[float, float]) -> dict:
    return {kind.replace("_", "-"): _figures(*mse) for kind, mse in by_kind.items()}


def test_the_score_is_the_sum_of_the_float32_winding_and_magnet_mse():
    assert validation_score(_figures(12.5, 7.75)) == 20.25
    assert validation_score(_figures(math.nan, 1.0)) == math.inf
    assert validation_score(_figures(math.inf, 1.0)) == math.inf


def test_the_smallest_score_deploys_whatever_the_kind():
    # the outrunner's designer prior (suite record, validation MSE K²): the LTI network beats the Hammerstein model
    chosen = choose_kind(_metrics(hammerstein=(12.553, 7.7371), lti_lptn=(7.3243, 5.809), pv_lptn=(7.4, 5.9)))
    assert chosen.kind == "lti-lptn" and chosen.tied == ()
    assert chosen.mse_K2 == pytest.approx({"hammerstein": 20.2901, "lti-lptn": 13.1333, "pv-lptn": 13.3})
    # a node may be worse if the sum is better: the rule is the pooled sum
    assert choose_kind(_metrics(hammerstein=(3.0, 6.0), lti_lptn=(5.0, 5.0), pv_lptn=(5.0, 5.0))).kind == "hammerstein"
    assert choose_kind(_metrics(hammerstein=(9.0, 9.0), lti_lptn=(8.0, 9.0), pv_lptn=(7.0, 9.0))).kind == "pv-lptn"


def test_a_tie_goes_to_the_simpler_kind():
    assert CANDIDATES == ("lti-lptn", "pv-lptn", "hammerstein")
    exact = choose_kind(_metrics(hammerstein=(4.0, 1.0), lti_lptn=(4.0, 1.0), pv_lptn=(6.0, 1.0)))
    assert exact.kind == "lti-lptn" and exact.tied == ("hammerstein",)
    # within the tie's relative 1e-6 the simpler kind stays; a smaller difference than that is no evidence
    near = choose_kind(_metrics(hammerstein=(5.0, 5.0), lti_lptn=(5.0, 5.000009), pv_lptn=(5.0, 5.000001)))
    assert near.kind == "lti-lptn" and near.tied == ("pv-lptn", "hammerstein")
    beyond = choose_kind(_metrics(hammerstein=(5.0, 5.0), lti_lptn=(5.0, 5.0001), pv_lptn=(5.0, 5.0001)))
    assert beyond.kind == "hammerstein" and beyond.tied == ()


def test_a_diverged_kind_is_never_deployed_and_its_score_is_null_in_json():
    chosen = choose_kind(_metrics(hammerstein=(math.nan, 1.0), lti_lptn=(50.0, 40.0), pv_lptn=(math.inf, 1.0)))
    assert chosen.kind == "lti-lptn"
    record = chosen.record()
    assert record["validation_mse_K2"] == {"lti-lptn": 90.0, "pv-lptn": None, "hammerstein": None}
    assert record["deployed_kind"] == "lti-lptn" and record["rule"] == RULE
    assert "diverged" in chosen.sentence("m.json")


def test_the_sentence_says_what_went_where_and_why_with_the_figures():
    chosen = choose_kind(_metrics(hammerstein=(12.553, 7.7371), lti_lptn=(7.3243, 5.809), pv_lptn=(7.4, 5.9)))
    assert chosen.sentence("out/m.json") == (
        "--kind auto deployed lti-lptn to out/m.json: its winding + magnet float32 MSE on the validation files, "
        "13.13 K², is the smallest (pv-lptn 13.3 K², hammerstein 20.29 K²)")
    tied = choose_kind(_metrics(hammerstein=(4.0, 1.0), lti_lptn=(4.0, 1.0), pv_lptn=(6.0, 1.0)))
    assert tied.sentence("m.json").endswith("; it ties with hammerstein, and a tie goes to the simpler kind")


# ---------------------------------------------------------------- the warning, true for --kind auto

SELECTION_LTI = {"recommended": "lti-lptn", "selected_rms_C": 1.9, "lti_rms_C": 1.5}
SELECTION_HAM = {"recommended": "hammerstein", "selected_rms_C": 1.2, "lti_rms_C": 1.5}


def _rmse(ham: tuple[float, float], lti: tuple[float, float]) -> dict:
    return {"hammerstein": _figures(ham[0] ** 2, ham[1] ** 2), "lti-lptn": _figures(lti[0] ** 2, lti[1] ** 2)}


def test_no_advice_to_deploy_the_lti_network_when_auto_deployed_it():
    metrics = _rmse((2.0, 1.0), (1.5, 0.8))       # worse on both nodes and on the left-out files
    assert "deploy the lti-lptn artifact" in _deployment(SELECTION_LTI, metrics, ALL)      # --kind hammerstein
    assert _deployment(SELECTION_LTI, metrics, ALL, "lti-lptn") is None
    assert _deployment(SELECTION_HAM, _rmse((1.3, 0.5), (1.6, 0.7)), ALL, "hammerstein") is None
    assert _deployment(SELECTION_LTI, metrics, ALL, "pv-lptn") is None   # neither of the two compared


def test_evidence_against_the_auto_choice_is_said_with_both_files():
    # the left-out training files favour the Hammerstein model, the validation files' winding the LTI network
    sentence = _deployment(SELECTION_HAM, _rmse((2.0, 0.5), (1.5, 0.8)), ALL, "lti-lptn")
    assert sentence == (
        "the evidence disagrees on which model to deploy: the LTI LPTN is better on the validation files (RMSE "
        "Hammerstein vs LTI: winding 2.000 vs 1.500 °C), the Hammerstein model on left-out training files (RMS "
        "Hammerstein 1.200 vs LTI 1.500 °C) and on the validation files (RMSE Hammerstein vs LTI: pm 0.500 vs "
        "0.800 °C); --kind auto deployed lti-lptn, out/m.json, by the validation files' pooled winding + magnet "
        "MSE and wrote hammerstein beside it, out/m-hammerstein.json: compare the two with bench evaluate on "
        "profiles like those the motor will run")
    assert "--all-kinds" not in sentence
