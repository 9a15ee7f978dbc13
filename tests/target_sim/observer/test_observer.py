"""The observer: the float32 covariance forms (target_sim.observer) against each other and the float64 filter
(bench.thermal.kalman), the algebra of the UD form, the artifact's observer section (schema version 3), and that
the filter, on data its model explains, recovers a wrong initial magnet temperature the open loop cannot."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.artifact_eval import artifact_drive
from bench.model.default import default_artifact_path
from bench.observer.measures.lagged_sensor import Sensor
from bench.observer.reference import FilterData, FilterModel, filter_data, initial_covariance, reference_run, run_filter
from bench.observer.section import observer_section, with_observer
from bench.observer.tune import ObserverFit, tune_observer
from bench.thermal.estimator import run_batch
from bench.thermal.kalman import augmented_transition
from target_sim.artifact import (
    BIAS_KINDS,
    OBSERVER_FORM_NAMES,
    ArtifactError,
    encode_array,
    load_artifact,
    seal,
    verify,
)
from target_sim.observer import OBSERVER_FORMS, Float32Observer, ObserverError, run_observer_offline
from target_sim.observer.forms import Joseph
from target_sim.observer.ud import BiermanThornton, ud_factor


def random_spd(rng, n=4, scale=1.0):
    m = rng.standard_normal((n, n))
    return scale * (m @ m.T + n * np.eye(n))


@pytest.fixture(scope="module")
def packaged():
    return load_artifact(default_artifact_path())


@pytest.fixture(scope="module")
def observed(packaged, small_dataset):
    """The packaged hammerstein model with a hand-set observer (no tuning) on the winding column."""
    dataset = load_dataset(small_dataset)
    fit = ObserverFit((Sensor(),), np.array([1e-4, 1e-4, 1e-4, 1e-6]), np.array([0.05]), None, "magnet", 0.0,
                      0.0, 0, 0, [])
    return verify(with_observer(packaged, observer_section(packaged, fit, [dataset]))), dataset


def test_the_forms_are_the_ones_the_artifact_names():
    assert OBSERVER_FORMS.names() == OBSERVER_FORM_NAMES


def test_ud_factor_reconstructs_the_matrix():
    rng = np.random.default_rng(1)
    m = random_spd(rng)
    u, d = ud_factor(m, np.float64)
    assert np.allclose(np.triu(u), u) and np.allclose(np.diag(u), 1.0)
    assert np.allclose((u * d) @ u.T, m, rtol=1e-12, atol=1e-12)


def test_thornton_prediction_and_bierman_update_equal_the_joseph_form_in_float64():
    rng = np.random.default_rng(2)
    p0, g = random_spd(rng), rng.standard_normal((4, 4))
    q_nodes = rng.uniform(0.1, 1.0, 4)
    q = (g * q_nodes) @ g.T
    f = np.eye(4) + 0.1 * rng.standard_normal((4, 4))
    h, r = rng.standard_normal(4), 0.3
    ud = BiermanThornton(p0, g, q_nodes, np.float64)
    joseph = Joseph(p0, q, np.float64)
    for _ in range(3):
        ud.predict(f)
        joseph.predict(f)
        assert np.allclose(ud.covariance(), joseph.covariance(), rtol=1e-10)
        assert np.allclose(ud.update(h, r), joseph.update(h, r), rtol=1e-10)
        assert np.allclose(ud.covariance(), joseph.covariance(), rtol=1e-10)


def test_every_float32_form_follows_the_float64_filter(observed):
    artifact, dataset = observed
    data, reference = reference_run(artifact, dataset)
    drive, z = artifact_drive(artifact, dataset), dataset.column("winding_C")
    covariances, errors = {}, {}
    for form in OBSERVER_FORMS.names():
        run = run_observer_offline(artifact, drive, z, data.run.initial, form, keep_covariance=True)
        assert np.all(np.isfinite(run.innovations))
        if form == "steady":
            continue   # another gain: not the time-varying filter
        errors[form] = np.max(np.abs(run.outputs - reference.estimates[0]))
        covariances[form] = run.covariances[-1]
    # measured on these 2 minutes with the covariance in the state coordinates (cond P ≈ 2.5e5): conventional
    # 0.061 °C, Joseph 0.021, UD 0.0011; in the node coordinates the filter now runs in: conventional 4.9e-4, Joseph
    # 1.6e-3, UD 9.5e-4 (no form is clearly ahead any more). The same code in float64 follows the reference within
    # 2e-5 °C (its inputs are float32 interval means)
    assert max(errors.values()) < 5e-3
    for form, p in covariances.items():
        assert np.allclose(p, covariances["ud"], rtol=0.05, atol=1e-3 * np.abs(p).max()), form


def test_the_target_code_in_float64_is_the_reference_filter(observed):
    artifact, dataset = observed
    data, reference = reference_run(artifact, dataset)
    run = run_observer_offline(artifact, artifact_drive(artifact, dataset), dataset.column("winding_C"),
                               data.run.initial, "joseph", dtype=np.float64)
    assert np.max(np.abs(run.outputs - reference.estimates[0])) < 1e-4


def test_a_row_without_a_measurement_only_predicts(observed):
    artifact, dataset = observed
    drive = artifact_drive(artifact, dataset)
    initial = [40.0, 40.0, 40.0, 45.0]
    from target_sim.model import run_offline

    _, open_loop = run_offline(artifact, drive, initial)
    blind = run_observer_offline(artifact, drive, np.full(len(drive), np.nan), initial)
    assert np.array_equal(blind.outputs, open_loop) and np.all(np.isnan(blind.innovations))
    obs = Float32Observer(artifact)
    obs.reset(initial)
    sigma0 = obs.sigma()
    obs.step(*drive[0])
    assert np.all(obs.sigma() >= 0) and sigma0[3] == pytest.approx(15.0, rel=1e-4)


@pytest.fixture(scope="module")
def ten_minutes(tmp_path_factory):
    from helpers import synthetic_columns, write_synthetic_dataset

    return load_dataset(write_synthetic_dataset(tmp_path_factory.mktemp("observer") / "ten_minutes.csv",
                                                synthetic_columns(3000, seed=11), "ten minutes for the observer"))


def test_the_filter_recovers_a_wrong_magnet_start_on_data_its_model_explains(observed, ten_minutes):
    """Truth = the model itself, the winding measured with 0.1 K noise: started 30 K off, the observer's magnet is
    within 2 K after five minutes; the open loop's is still more than 10 K off."""
    artifact, _ = observed
    model = FilterModel.of(artifact)
    data = filter_data(artifact, ten_minutes, (Sensor(),))
    steps = len(data.run.step_time_s)
    _, truth = run_batch(model.a[None], model.b[None], model.c[None], model.theta[None], model.sigmoid[None],
                         data.run.inputs, data.run.initial, keep_trajectories=True)
    truth = truth[0]
    z = truth[:, 1:2] + 0.1 * np.random.default_rng(0).standard_normal((steps, 1))
    start = data.run.initial.copy()
    start[3] += 30.0
    shifted = FilterData(replace(data.run, initial=start), replace(data.readings, z0=z), data.measurements)
    q = model.to_state([1e-6] * 4)[None]
    estimate = run_filter(model, shifted, q, [[0.01]], initial_covariance(model), keep=True).estimates[0]
    _, open_loop = run_batch(model.a[None], model.b[None], model.c[None], model.theta[None], model.sigmoid[None],
                             data.run.inputs, start, keep_trajectories=True)
    error, open_error = estimate[:, 3] - truth[:, 3], open_loop[0][:, 3] - truth[:, 3]
    settled = int(300 / artifact.dt)
    assert np.max(np.abs(error[settled:])) < 2.0
    assert np.min(np.abs(open_error[:settled])) > 10.0


def test_tuning_runs_and_writes_a_version_3_artifact(packaged, small_dataset):
    dataset = load_dataset(small_dataset)
    fit = tune_observer(packaged, [dataset], Sensor(), "likelihood", max_evaluations=12)
    assert fit.evaluations <= 13 and fit.r_reference_C2 is not None and fit.r_C2 > 0
    content = with_observer(packaged, observer_section(packaged, fit, [dataset], "joseph"))
    assert content["schema_version"] == 3 and content["observer"]["form"] == "joseph"
    assert verify(content).content["observer"]["tuning"]["updates"] == fit.updates > 0


def _edited(artifact, change) -> dict:
    content = json.loads(json.dumps(artifact.content))
    change(content)
    return seal(content)


@pytest.mark.parametrize(("change", "sentence"), [
    (lambda c: c.update(schema_version=2), "schema version 2 has no observer section"),
    (lambda c: c["observer"].update(form="kalman"), "observer.form 'kalman' is not one of conventional"),
    (lambda c: c["observer"].update(node="rotor"), "observer.node 'rotor' is not one of yoke"),
    (lambda c: c["observer"].update(R={"shape": [], "f64": [-1.0], "f32_hex": [(-1.0).hex()]}),
     "observer.R is -1, a measurement variance must be positive"),
    (lambda c: c["observer"].pop("P0"), "missing the field observer.P0"),
    (lambda c: c["observer"].update(bias="rotor-heat"),
     "observer.bias 'rotor-heat' is not one of winding-heat, magnet-heat, winding-output or null"),
    # a section of a version this target does not know was read as version 2 (99) or ended in a traceback ("two")
    (lambda c: c["observer"].update(version=99), "observer.version 99 is not supported .* versions 1 to 2"),
    (lambda c: c["observer"].update(version="two"), "observer.version 'two' is not supported"),
    (lambda c: c["observer"].update(version=True), "observer.version True is not supported"),
])
def test_a_bad_observer_section_is_refused_in_one_sentence(observed, change, sentence):
    artifact, _ = observed
    with pytest.raises(ArtifactError, match=sentence) as info:
        verify(_edited(artifact, change))
    assert "\n" not in str(info.value)


def test_a_q_not_diagonal_in_the_node_temperatures_is_refused_in_one_sentence(observed):
    """The filter runs in node coordinates with Q = diag(q_nodes_C2); a section whose Q is something else (here Q
    itself diagonal in the state coordinates) would be another filter: refused."""
    artifact, _ = observed

    def change(content):
        q = np.diag(np.diag(artifact.array("observer", "Q", dtype=np.float64)))
        content["observer"]["Q"] = encode_array(q)

    with pytest.raises(ObserverError, match="the observer's Q is not C⁻¹ diag\\(q_nodes_C2\\) C⁻ᵀ") as info:
        Float32Observer(verify(_edited(artifact, change)))
    assert "\n" not in str(info.value)


def test_in_node_coordinates_q_is_diagonal_and_a_sensor_row_is_what_it_sees(observed):
    """The winding sensor's row h is the winding node alone (4 nonzeros in the state coordinates), so Bierman's
    update runs over the columns from the winding on (3 of 4); Q's factor G is the identity; P comes back to the
    state coordinates for the reports (the float64 UD form equals the Joseph form there)."""
    artifact, dataset = observed
    obs = Float32Observer(artifact)
    assert np.array_equal(obs.layout.rows[0], [0.0, 1.0, 0.0, 0.0])
    assert [step.column for step in obs.cov.bierman(obs.layout.rows[0]).steps] == [1, 2, 3]
    assert np.array_equal(obs.cov.g_nonzero, np.eye(4, dtype=bool))
    drive, z = artifact_drive(artifact, dataset)[:200], dataset.column("winding_C")[:200]
    start = [40.0, 40.0, 40.0, 45.0]
    ud, joseph = (run_observer_offline(artifact, drive, z, start, form, keep_covariance=True, dtype=np.float64)
                  for form in ("ud", "joseph"))
    assert np.allclose(ud.covariances, joseph.covariances, rtol=1e-8, atol=1e-12)
    assert np.allclose(ud.outputs, joseph.outputs, rtol=0, atol=1e-9)
    assert np.array_equal(ud.filter_covariances[-1], ud.filter_covariances[-1].T)


def test_an_artifact_without_an_observer_is_still_written_as_version_2(packaged):
    assert packaged.content["schema_version"] == 2 and "observer" not in packaged.content
    from bench.model.builder import artifact_content

    from helpers import model_spec

    assert artifact_content(model_spec())["schema_version"] == 2


@pytest.fixture(scope="module")
def augmented(packaged, small_dataset):
    """The packaged model with a lagged, offset end-winding sensor (τ 25 s, gradient -0.1, +0.5 K) on the
    winding column and a winding heat-bias state: 6 states."""
    dataset = load_dataset(small_dataset)
    fit = ObserverFit((Sensor("winding", "winding_C", 0.5, 25.0, -0.1),),
                      np.array([1e-4, 1e-4, 1e-4, 1e-6, 1e-4, 10.0]), np.array([0.05]), None, "magnet", 0.0, 0.0, 0,
                      0, [], True)
    return verify(with_observer(packaged, observer_section(packaged, fit, [dataset]))), dataset


def test_the_augmented_float32_forms_follow_the_float64_filter(augmented):
    artifact, dataset = augmented
    assert artifact.content["observer"]["states"][4:] == ["lag of winding_C", "winding heat bias (W)"]
    data, reference = reference_run(artifact, dataset)
    errors, error64 = _augmented_forms_against_reference(artifact, dataset, data, reference)
    # measured on these 2 minutes: conventional 2.8e-3 °C, Joseph 3.6e-3, UD 9.1e-4; the target's code in float64
    # follows the reference within 1.6e-5 °C (float32 interval means)
    assert errors["ud"] < 5e-3 and max(errors.values()) < 0.05
    assert error64 < 1e-4


def _augmented_forms_against_reference(artifact, dataset, data, reference) -> tuple[dict[str, float], float]:
    """The six-state observer offline against the float64 reference on the winding column: the largest error of
    each float32 form (its covariance 6×6), and of the Joseph form in float64."""
    drive, z = artifact_drive(artifact, dataset), dataset.column("winding_C")
    errors = {}
    for form in ("conventional", "joseph", "ud"):
        run = run_observer_offline(artifact, drive, z, data.run.initial, form, keep_covariance=True)
        assert run.covariances.shape[1:] == (6, 6)
        errors[form] = float(np.max(np.abs(run.outputs - reference.estimates[0])))
    run64 = run_observer_offline(artifact, drive, z, data.run.initial, "joseph", dtype=np.float64)
    return errors, float(np.max(np.abs(run64.outputs - reference.estimates[0])))


def test_a_lagged_sensor_recovers_a_wrong_magnet_start_faster_than_the_open_loop(augmented, ten_minutes):
    """Truth = the model; the sensor reads its end-winding mix through the 25 s lag plus 0.5 K and 0.1 K noise.
    Started 30 K too warm and too cold, the filter that carries the lag (no bias state: a heat bias would explain
    the winding's start as well as the magnet does) brings the magnet within 2 K in about 2.5 minutes; the open
    loop never does in ten."""
    from bench.observer.evaluate import recovery_time_s

    artifact, _ = augmented
    model = FilterModel.of(artifact)
    data = filter_data(artifact, ten_minutes, (Sensor("winding", "winding_C", 0.5, 25.0, -0.1),))
    steps = len(data.run.step_time_s)
    _, truth = run_batch(model.a[None], model.b[None], model.c[None], model.theta[None], model.sigmoid[None],
                         data.run.inputs, data.run.initial, keep_trajectories=True)
    truth = truth[0]
    a, sees = data.readings.lag_pole[0], data.readings.sees[0]
    seen = np.empty(steps)
    state = sees @ data.run.initial
    for k in range(steps):
        state = a * state + (1 - a) * (sees @ truth[k])
        seen[k] = state
    z = seen + 0.1 * np.random.default_rng(0).standard_normal(steps)   # the reading less its offset
    q = np.diag([1e-6] * 5)
    q[:4, :4] = model.to_state([1e-6] * 4)
    for offset in (30.0, -30.0):
        start = data.run.initial.copy()
        start[3] += offset
        shifted = FilterData(replace(data.run, initial=start), replace(data.readings, z0=z[:, None]),
                             data.measurements)
        estimate = run_filter(model, shifted, q[None], [[0.01]], initial_covariance(model, data.readings),
                        keep=True).estimates[0]
        _, open_loop = run_batch(model.a[None], model.b[None], model.c[None], model.theta[None],
                                 model.sigmoid[None], data.run.inputs, start, keep_trajectories=True)
        observed_s = recovery_time_s(estimate[:, 3] - truth[:, 3], data.run.step_time_s)
        open_s = recovery_time_s(open_loop[0][:, 3] - truth[:, 3], data.run.step_time_s)
        assert open_s == float("inf") and observed_s < 400.0, (offset, observed_s)


def test_a_version_1_observer_section_still_runs_as_before(observed):
    """An artifact written before the measurement list (observer section without `version`) reads its one sensor
    as an unlagged measurement of its node: the same float32 run as the version 2 section that says so."""
    artifact, dataset = observed
    content = json.loads(json.dumps(artifact.content))
    for key in ("version", "measurements", "states", "bias"):
        content["observer"].pop(key, None)
    content["observer"]["K_ss"] = {k: v for k, v in content["observer"]["K_ss"].items()}
    content["observer"]["K_ss"]["shape"] = [4]
    legacy = verify(seal(content))
    drive, z = artifact_drive(artifact, dataset), dataset.column("winding_C")
    for form in ("ud", "steady"):
        old = run_observer_offline(legacy, drive, z, [40.0, 40.0, 40.0, 45.0], form)
        new = run_observer_offline(artifact, drive, z, [40.0, 40.0, 40.0, 45.0], form)
        assert np.array_equal(old.outputs, new.outputs), form


@pytest.fixture(scope="module")
def magnet_augmented(packaged, small_dataset):
    """The augmented observer of `augmented` with the magnet heat-bias state instead of the winding's: 6 states."""
    dataset = load_dataset(small_dataset)
    fit = ObserverFit((Sensor("winding", "winding_C", 0.5, 25.0, -0.1),),
                      np.array([1e-4, 1e-4, 1e-4, 1e-6, 1e-4, 1.0]), np.array([0.05]), None, "magnet", 0.0, 0.0, 0,
                      0, [], "magnet-heat")
    return verify(with_observer(packaged, observer_section(packaged, fit, [dataset]))), dataset


def test_the_magnet_bias_heats_the_magnet_and_the_float32_forms_follow_the_float64_filter(magnet_augmented):
    """The section records the kind; both filters heat through the magnet loss's column of B (P_m, the fourth
    input), not the winding's; the float32 forms follow the float64 filter as they do with the winding bias."""
    artifact, dataset = magnet_augmented
    section = artifact.content["observer"]
    assert section["bias"] == "magnet-heat" and section["states"][4:] == ["lag of winding_C", "magnet heat bias (W)"]
    assert "the bias heats the magnet" in section["rule"]
    target = Float32Observer(artifact)
    part, model = target.est.part, FilterModel.of(artifact)
    assert BIAS_KINDS["magnet-heat"] == 3 and target.layout.bias_index == 5
    assert np.array_equal(target.layout.bias_column, part.b[:, 3] * target.est.dt)   # the packaged model: delta form
    data, reference = reference_run(artifact, dataset)
    assert data.readings.bias == "magnet-heat" and data.readings.bias_input == 3
    assert np.allclose(augmented_transition(model.a, model.b, model.c, data.readings)[:4, 5], model.b[:, 3])
    errors, error64 = _augmented_forms_against_reference(artifact, dataset, data, reference)
    # measured on these 2 minutes: conventional 1.2e-3 °C, Joseph 7.5e-4, UD 9.2e-4
    assert errors["ud"] < 5e-3 and max(errors.values()) < 0.05, errors
    assert error64 < 1e-4


def test_a_section_without_the_new_kind_is_written_and_read_as_before(augmented, observed):
    """The winding bias keeps its section (kind, state name, rule) and `--bias` alone still means it; no bias: null."""
    artifact, _ = augmented
    section = artifact.content["observer"]
    assert section["bias"] == "winding-heat" and section["states"][-1] == "winding heat bias (W)"
    assert section["rule"].startswith("after each model step: the bias heats the winding (x += b_w beta), each lag")
    assert Float32Observer(artifact).layout.bias_column.tolist() == (
        Float32Observer(artifact).est.part.b[:, 1] * Float32Observer(artifact).est.dt).tolist()
    assert observed[0].content["observer"]["bias"] is None and Float32Observer(observed[0]).layout.bias_index == -1
    from bench.cli import build_parser

    parse = build_parser().parse_args
    assert [parse(["observer", *flags]).bias for flags in ([], ["--bias"], ["--bias", "magnet"])] == [
        "auto", "winding", "magnet"]


def _magnet_heat_truth(model: FilterModel, artifact, path, rows: int, scale: float):
    """A synthetic drive at 4000 rpm and more (the magnet's losses a few hundred W) whose winding and magnet
    columns are the model's own run with `scale` times the magnet's heat (the magnet loss's column of B), from the
    same start: a magnet-side model error the winding sees only through the coupling."""
    from helpers import synthetic_columns, write_synthetic_dataset

    columns = synthetic_columns(rows, seed=11, speed_offset=4000.0, torque_max=150.0)
    data = filter_data(artifact, load_dataset(write_synthetic_dataset(path.with_suffix(".model.csv"), columns, "")),
                       (Sensor(),))
    b = model.b.copy()
    b[:, 3] *= scale
    _, truth = run_batch(model.a[None], b[None], model.c[None], model.theta[None], model.sigmoid[None],
                         data.run.inputs, data.run.initial, keep_trajectories=True)
    times = np.r_[0.0, data.run.step_time_s]
    for node, column in ((1, "winding_C"), (3, "pm_C")):
        values = np.r_[data.run.initial[node], truth[0][:, node]]
        columns[column] = np.round(np.interp(columns["time_s"], times, values), 2)
    return load_dataset(write_synthetic_dataset(path, columns, "the model with the magnet's heat × 1.3"))


def test_a_magnet_bias_absorbs_an_underrated_magnet_loss_a_winding_bias_cannot(packaged, tmp_path):
    """Truth: the model with 30 % more magnet heat over 15 minutes; a winding sensor reads the true winding
    (0.01 K). Tuned on that file (magnet criterion, 150 filter runs), the magnet heat-bias state explains the
    winding's small drift as magnet heat and brings the magnet's MSE (started as measured) well below the winding
    heat bias's (measured: magnet bias 2.32 K², winding bias 7.94 K², open loop 29.7 K²); the magnet's kind heating
    the winding's column instead tunes to the winding bias's (measured: 8.13 K²)."""
    model = FilterModel.of(packaged)
    dataset = _magnet_heat_truth(model, packaged, tmp_path / "magnet-heat.csv", 4500, 1.3)
    mse = {}
    for bias in ("winding-heat", "magnet-heat"):
        fit = tune_observer(packaged, [dataset], Sensor(), "magnet", 150, bias=bias)
        artifact = verify(with_observer(packaged, observer_section(packaged, fit, [dataset])))
        data, reference = reference_run(artifact, dataset)
        mse[bias] = float(np.mean((reference.estimates[0][:, 3] - data.run.ref_pm) ** 2))
    _, open_loop = run_batch(model.a[None], model.b[None], model.c[None], model.theta[None], model.sigmoid[None],
                             data.run.inputs, data.run.initial, keep_trajectories=True)
    open_mse = float(np.mean((open_loop[0][:, 3] - data.run.ref_pm) ** 2))
    assert mse["magnet-heat"] < 0.5 * mse["winding-heat"] and mse["magnet-heat"] < 0.2 * open_mse, (mse, open_mse)
