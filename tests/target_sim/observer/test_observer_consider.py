"""Consider states (`bench observer --consider magnet`, the section's `consider`): a measurement that does not read the
magnet never updates the magnet node (nor a magnet heat bias), and each covariance form keeps the covariance of the
gain actually used: the rule of which states are held, the artifact field, every float32 form's held rows and
covariance (symmetric, positive semidefinite; in float64 the UD form's Agee-Turner update and the conventional form's
s δδᵀ equal Joseph's form of the masked gain), the steady state of the consider filter, and the CLI option."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.artifact_eval import artifact_drive
from bench.model.default import default_artifact_path
from bench.observer.choices import DEFAULT_CONSIDER
from bench.observer.measures.lagged_sensor import Sensor
from bench.observer.reference import reference_run
from bench.observer.section import observer_section, with_observer
from bench.observer.tune import ObserverFit, consider_problem
from bench.thermal.kalman import consider_projections, steady_state
from target_sim.artifact import CONSIDER_KINDS, ArtifactError, consider_held, load_artifact, seal, verify
from target_sim.observer import Float32Observer, run_observer_offline

NTC = Sensor("winding", "winding_C", 0.5, 25.0, -0.1)   # lagged end-winding mix: reads no magnet


@pytest.fixture(scope="module")
def packaged():
    return load_artifact(default_artifact_path())


def _observer(packaged, dataset, bias, consider, q_bias=1e-4):
    q = [1e-4, 1e-4, 1e-4, 1e-6, 1e-4] + ([q_bias] if bias else [])
    fit = ObserverFit((NTC,), np.array(q), np.array([0.05]), None, "magnet", 0.0, 0.0, 0, 0, [], bias,
                      consider=consider)
    return verify(with_observer(packaged, observer_section(packaged, fit, [dataset])))


@pytest.fixture(scope="module")
def consider(packaged, small_dataset):
    """The lagged NTC with the winding heat bias, the magnet a consider state: 6 states, the magnet (3) held."""
    dataset = load_dataset(small_dataset)
    return _observer(packaged, dataset, "winding-heat", "magnet", 10.0), dataset


def test_a_measurement_that_does_not_read_the_magnet_holds_it_and_a_magnet_bias():
    ntc, flux = [0.1, 0.9, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]
    held = consider_held("magnet", np.array([ntc, flux]), "magnet-heat", 6)
    assert held.tolist() == [[False, False, False, True, False, True], [False] * 6]
    assert consider_held("magnet", np.array([ntc]), "winding-heat", 6).tolist() == [[False, False, False, True,
                                                                                    False, False]]
    assert not consider_held(None, np.array([ntc]), None, 4).any()
    assert CONSIDER_KINDS["magnet"] == ("magnet",)


def test_unmeasured_holds_every_node_a_measurement_does_not_read_and_a_bias_with_its_node():
    ntc, winding, flux = [0.1, 0.9, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]
    held = consider_held("unmeasured", np.array([ntc, winding, flux]), "winding-heat", 5)
    # the NTC with a gradient reads the yoke and the winding: it holds the tooth and the magnet; the flux linkage
    # holds the winding and its heat bias
    assert held.tolist() == [[False, False, True, True, False], [True, False, True, True, False],
                             [True, True, True, False, True]]
    assert consider_problem("unmeasured", "winding-heat", [NTC]) is None
    assert consider_problem("unmeasured", "magnet-heat", [NTC]).startswith(
        "--consider unmeasured holds the magnet heat bias for every measurement")


def test_a_magnet_bias_every_measurement_holds_is_refused_in_one_sentence():
    """Never corrected, the bias would be a random walk whose variance grows without bound."""
    problem = consider_problem("magnet", "magnet-heat", [NTC])
    assert problem.startswith("--consider magnet holds the magnet heat bias for every measurement") and "\n" not in \
        problem
    assert consider_problem("magnet", "winding-heat", [NTC]) is None and consider_problem(None, "magnet-heat",
                                                                                          [NTC]) is None


def test_the_section_records_the_kind_and_without_it_is_written_as_before(consider, packaged):
    artifact, dataset = consider
    section = artifact.content["observer"]
    assert section["consider"] == "magnet" and "consider states (magnet)" in section["rule"]
    plain = with_observer(packaged, observer_section(packaged, ObserverFit(
        (NTC,), np.array([1e-4, 1e-4, 1e-4, 1e-6, 1e-4, 10.0]), np.array([0.05]), None, "magnet", 0.0, 0.0, 0, 0, [],
        "winding-heat"), [dataset]))
    assert "consider" not in plain["observer"]           # no field: the bytes an older bench wrote
    assert Float32Observer(verify(plain)).consider.held == [None]


@pytest.mark.parametrize("value", ["rotor", 1, True, ["magnet"]])
def test_a_bad_consider_kind_is_refused_in_one_sentence(consider, value):
    artifact, _ = consider
    content = json.loads(json.dumps(artifact.content))
    content["observer"]["consider"] = value
    with pytest.raises(ArtifactError, match="observer.consider .* is not one of magnet, unmeasured or null; rebuild "
                                            "it with 'bench observer'") as info:
        verify(seal(content))
    assert "\n" not in str(info.value)
    content["observer"]["consider"] = None               # null: none, as an absent field
    assert Float32Observer(verify(seal(content))).consider.held == [None]


@pytest.mark.parametrize("form", ["conventional", "joseph", "ud", "steady"])
def test_a_winding_reading_leaves_the_held_rows_as_they_were(consider, form):
    """The gain's magnet row is -0 in every form, so the update moves the winding (and the lag and bias states) and
    not the magnet: after the step the magnet equals the predict-only step's up to the float32 rounding of x's
    round trip (y = C x again), the extra states move by the gain alone."""
    artifact, dataset = consider
    drive = artifact_drive(artifact, dataset)
    start = [40.0, 40.0, 40.0, 45.0]
    with_reading, without = Float32Observer(artifact, form), Float32Observer(artifact, form)
    for obs in (with_reading, without):
        obs.reset(start)
    for row in drive[:20]:     # from the same state each step; the reading 3 K warm of the winding estimate
        predicted = without.step(*row)
        updated = with_reading.step(*row, z=float(with_reading.est.y[1]) + 3.0)
        without.est.x, without.est.y = with_reading.est.x.copy(), with_reading.est.y.copy()
        without.extra = with_reading.extra.copy()
        assert abs(updated[1] - predicted[1]) > 1e-3              # the winding is corrected
        assert abs(updated[3] - predicted[3]) <= 2e-5 * abs(predicted[3])   # the magnet is not (rounding only)


def test_the_held_row_of_every_gain_is_exactly_zero(consider):
    artifact, _ = consider
    for form in ("conventional", "joseph", "ud"):
        obs = Float32Observer(artifact, form)
        obs.reset([40.0, 40.0, 40.0, 45.0])
        gain = obs.cov.update(obs.layout.rows[0], np.float32(0.05), 0, obs.consider.held[0])
        assert gain[3] == 0 and np.signbit(gain[3]), form       # -0: y + (-0)·ν is y
        assert gain[1] > 0.5 and gain[4] > 0.5, form             # the winding and the lag state move
    steady = Float32Observer(artifact, "steady")
    assert steady.gain_steady[0][3] == 0 and np.signbit(steady.gain_steady[0][3])
    assert np.all(np.delete(steady.gain_steady[0], 3) != 0)


def test_every_float32_form_follows_the_float64_consider_filter_and_keeps_p_symmetric_psd(consider):
    """Over the 2-minute file, started as measured: each propagating form against the float64 reference
    (bench.thermal.kalman, Joseph's form of the masked gain); the covariance's symmetry and definiteness as the
    forms keep them (UD: symmetric by construction, d >= 0)."""
    artifact, dataset = consider
    data, reference = reference_run(artifact, dataset)
    drive, z = artifact_drive(artifact, dataset), dataset.column("winding_C")
    for form in ("conventional", "joseph", "ud"):
        run = run_observer_offline(artifact, drive, z, data.run.initial, form, keep_covariance=True)
        error = float(np.max(np.abs(run.outputs - reference.estimates[0])))
        # measured: conventional 7.8e-5 °C, Joseph 8.3e-5, UD 9.5e-5
        assert error < 1e-3, (form, error)
        own = run.filter_covariances
        scale = np.max(np.abs(own), axis=(1, 2))
        asymmetry = np.max(np.abs(own - own.transpose(0, 2, 1)), axis=(1, 2)) / scale
        assert np.all(asymmetry < 1e-5), (form, float(asymmetry.max()))
        if form == "ud":
            assert np.all(asymmetry == 0)
        lowest = np.linalg.eigvalsh(0.5 * (own + own.transpose(0, 2, 1)))[:, 0]
        assert np.all(lowest > -1e-6 * scale), (form, float(lowest.min()))


def test_in_float64_the_ud_and_conventional_consider_updates_are_josephs_form(consider):
    """The consider covariance (I - K h) P⁻ (I - K h)ᵀ + R K Kᵀ of the masked gain equals the optimal update plus
    s δδᵀ (conventional) and Bierman's update followed by Agee-Turner's rank-one update (UD): the three forms run in
    float64 agree to rounding, and the consider covariance is larger than the optimal filter's for the magnet."""
    artifact, dataset = consider
    drive, z = artifact_drive(artifact, dataset)[:300], dataset.column("winding_C")[:300]
    start = [40.0, 40.0, 40.0, 45.0]
    runs = {form: run_observer_offline(artifact, drive, z, start, form, keep_covariance=True, dtype=np.float64)
            for form in ("conventional", "joseph", "ud")}
    reference = runs["joseph"].filter_covariances
    scale = np.max(np.abs(reference))
    for form in ("conventional", "ud"):
        assert np.max(np.abs(runs[form].filter_covariances - reference)) < 1e-10 * scale, form
        assert np.max(np.abs(runs[form].outputs - runs["joseph"].outputs)) < 1e-9, form
    content = json.loads(json.dumps(artifact.content))
    del content["observer"]["consider"]
    optimal = run_observer_offline(verify(seal(content)), drive, z, start, "joseph", keep_covariance=True,
                                   dtype=np.float64).filter_covariances
    assert np.all(reference[:, 3, 3] >= optimal[:, 3, 3] * (1 - 1e-12)) and np.any(reference[:, 3, 3] > optimal[:, 3,
                                                                                                                3])


def test_the_steady_state_is_the_consider_filters_fixed_point():
    """A stable random system (5 states, the node block of C random, a state held): K_ss's held row is zero in node
    coordinates, and P_ss is the fixed point: predicted (F P Fᵀ + Q) and updated with the masked gain again, it
    returns to itself with the same gain; the optimal filter's steady posterior is smaller."""
    rng = np.random.default_rng(3)
    n = 5
    f = 0.9 * np.linalg.qr(rng.standard_normal((n, n)))[0]
    c = np.eye(4) + 0.2 * rng.standard_normal((4, 4))
    q = np.diag(rng.uniform(0.01, 0.1, n))
    h = np.zeros((1, n))
    h[0, :4] = np.array([0.0, 1.0, 0.0, 0.0]) @ c           # the winding node, in the state coordinates
    held = np.array([[False, False, False, True, False]])
    projections = consider_projections(c, held)
    gain, post = steady_state(f, h, q, [0.2], projections)
    assert abs((c @ gain[0, :4])[3]) < 1e-12 * np.max(np.abs(gain))
    prior = f @ post @ f.T + q
    again = projections[0] @ (prior @ h[0] / (h[0] @ prior @ h[0] + 0.2))
    i_kh = np.eye(n) - np.outer(again, h[0])
    assert np.allclose(again, gain[0], rtol=1e-9, atol=1e-12)
    assert np.allclose(i_kh @ prior @ i_kh.T + 0.2 * np.outer(again, again), post, rtol=1e-9, atol=1e-12)
    assert np.min(np.linalg.eigvalsh(post)) > 0
    _, optimal = steady_state(f, h, q, [0.2])
    assert np.min(np.linalg.eigvalsh(post - optimal)) > -1e-12


def test_the_cli_option(tmp_path, small_dataset, capsys):
    from bench.cli import build_parser, main

    parse = build_parser().parse_args
    assert parse(["observer"]).consider == DEFAULT_CONSIDER
    assert parse(["observer", "--consider", "magnet"]).consider == "magnet"
    out = tmp_path / "consider.json"
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--consider", "none", "--out",
                 str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["consider"] is None and "consider" not in load_artifact(out).content[
        "observer"]
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--out", str(out)]) == 0
    assert "consider states: magnet" in capsys.readouterr().out
    assert load_artifact(out).content["observer"]["consider"] == DEFAULT_CONSIDER == "magnet"


@pytest.mark.parametrize(("argv", "sentence"), [
    (["--consider", "rotor"], "argument --consider: invalid choice: 'rotor'"),
    (["--lag", "60", "--bias", "magnet", "--consider", "magnet"],
     "--consider magnet holds the magnet heat bias for every measurement"),
])
def test_a_bad_consider_option_is_one_sentence_and_exit_2(tmp_path, small_dataset, capsys, argv, sentence):
    from bench.cli import main

    out = tmp_path / "never.json"
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert sentence in err and err.count("\n") == 1 and not out.exists()
