"""The key-on release of the consider states (the section's `consider_release_C2`, `bench observer
--consider-release SIGMA`) and the `unmeasured` consider kind: a held magnet whose variance exceeds the release is
updated by a winding sensor (key-on: a magnet nobody measured), so a wrong initial magnet is corrected, and once its
variance is below the release it is held again (steady operation as with the consider states); the float32 forms
follow the float64 filter, the generated C is bit for bit the float32 reference, and a section without the field
runs as before."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.artifact_eval import artifact_drive
from bench.model.default import default_artifact_path
from bench.observer.evaluate import recovery_time_s
from bench.observer.measures.lagged_sensor import Sensor
from bench.observer.reference import FilterData, FilterModel, filter_data, initial_covariance, reference_run, run_filter
from bench.observer.section import observer_section, with_observer
from bench.observer.tune import ObserverFit
from bench.thermal.estimator import run_batch
from target_sim.artifact import ArtifactError, dumps, encode_array, load_artifact, seal, verify
from target_sim.observer import Float32Observer, run_observer_offline

NTC = Sensor("winding", "winding_C", 0.5, 25.0, -0.1)   # lagged end-winding mix: reads no magnet, no tooth
RELEASE_C2 = 4.0        # the magnet held once its 1-sigma is below 2 K


@pytest.fixture(scope="module")
def packaged():
    return load_artifact(default_artifact_path())


def _observer(packaged, dataset, consider="magnet", release=RELEASE_C2):
    fit = ObserverFit((NTC,), np.array([1e-6] * 5), np.array([0.01]), None, "magnet", 0.0, 0.0, 0, 0, [],
                      consider=consider, release_C2=release)
    return verify(with_observer(packaged, observer_section(packaged, fit, [dataset])))


@pytest.fixture(scope="module")
def ten_minutes(tmp_path_factory):
    from helpers import synthetic_columns, write_synthetic_dataset

    return load_dataset(write_synthetic_dataset(tmp_path_factory.mktemp("release") / "ten_minutes.csv",
                                                synthetic_columns(3000, seed=11), "ten minutes for the release"))


def _model_truth(artifact, dataset):
    """The model's own trajectory from the file's initial state, and the sensor's lagged view of it (0.1 K noise)."""
    model = FilterModel.of(artifact)
    data = filter_data(artifact, dataset, (NTC,), None, "magnet")
    steps = len(data.run.step_time_s)
    _, truth = run_batch(model.a[None], model.b[None], model.c[None], model.theta[None], model.sigmoid[None],
                         data.run.inputs, data.run.initial, keep_trajectories=True)
    truth = truth[0]
    a, sees = data.readings.lag_pole[0], data.readings.sees[0]
    seen, state = np.empty(steps), sees @ data.run.initial
    for k in range(steps):
        state = a * state + (1 - a) * (sees @ truth[k])
        seen[k] = state
    return model, data, truth, seen + 0.1 * np.random.default_rng(0).standard_normal(steps)


def test_a_released_magnet_recovers_from_a_wrong_start_the_held_one_does_not(packaged, ten_minutes):
    """Truth = the model, the NTC through its lag: started 30 K too warm and too cold, the magnet held always (the
    consider states) is as far off as the open loop after ten minutes; released while its variance exceeds 4 K² it
    is within 2 K in a few minutes, and from then on it is held (its variance stays below the release)."""
    model, data, truth, z = _model_truth(packaged, ten_minutes)
    q = np.diag([1e-6] * 5)
    q[:4, :4] = model.to_state([1e-6] * 4)
    p0 = initial_covariance(model, data.readings)
    for offset in (30.0, -30.0):
        start = data.run.initial.copy()
        start[3] += offset
        times = {}
        for release in (None, RELEASE_C2):
            shifted = FilterData(replace(data.run, initial=start),
                                 replace(data.readings, z0=z[:, None], release_C2=release), data.measurements)
            runs = run_filter(model, shifted, q[None], [[0.01]], p0, keep=True)
            times[release] = recovery_time_s(runs.estimates[0][:, 3] - truth[:, 3], data.run.step_time_s)
            if release is not None:
                held_from = int(np.argmax(runs.sigmas[0][:, 3] ** 2 <= release))
                assert 0 < held_from and np.all(runs.sigmas[0][held_from:, 3] ** 2 <= 1.01 * release)
        _, open_loop = run_batch(model.a[None], model.b[None], model.c[None], model.theta[None], model.sigmoid[None],
                                 data.run.inputs, start, keep_trajectories=True)
        open_s = recovery_time_s(open_loop[0][:, 3] - truth[:, 3], data.run.step_time_s)
        assert open_s == float("inf") and times[None] == float("inf"), (offset, times)
        assert times[RELEASE_C2] < 400.0, (offset, times)


def test_in_steady_operation_the_released_filter_holds_the_magnet(packaged, small_dataset):
    """Once the magnet's variance is below the release, a winding reading leaves the magnet as the predict-only
    step does (the gain's magnet row -0), in every propagating form; above it the magnet moves."""
    dataset = load_dataset(small_dataset)
    artifact = _observer(packaged, dataset)
    drive = artifact_drive(artifact, dataset)
    for form in ("conventional", "joseph", "ud"):
        obs = Float32Observer(artifact, form)
        obs.reset([40.0, 40.0, 40.0, 45.0])
        assert obs.consider.holds(0, obs.cov) is None     # key-on: sigma 15 K, the magnet free (nothing else held)
        gain = obs.cov.update(obs.layout.rows[0], np.float32(0.01), 0, obs.consider.holds(0, obs.cov))
        assert gain[3] != 0, form
        obs.consider.release = np.float32(1e6)     # as if its variance were below: held
        assert obs.consider.holds(0, obs.cov)[3] == np.True_
        gain = obs.cov.update(obs.layout.rows[0], np.float32(0.01), 0, obs.consider.holds(0, obs.cov))
        assert gain[3] == 0 and np.signbit(gain[3]), form
        obs.step(*drive[0], z=45.0)


def _crossing(packaged, dataset):
    """The NTC observer (unmeasured consider states: the magnet and the tooth held) with its release at the median
    of the magnet's float64 variance over the 2-minute file, so a run takes both branches."""
    artifact = _observer(packaged, dataset, "unmeasured", 1.0)
    _, reference = reference_run(artifact, dataset)
    release = float(np.median(reference.sigmas[0][:, 3] ** 2))
    content = json.loads(json.dumps(artifact.content))
    content["observer"]["consider_release_C2"] = encode_array(release)
    return verify(seal(content)), release


def test_the_float32_forms_follow_the_float64_released_filter(packaged, small_dataset):
    dataset = load_dataset(small_dataset)
    artifact, release = _crossing(packaged, dataset)
    data, reference = reference_run(artifact, dataset)
    variance = reference.sigmas[0][:, 3] ** 2
    assert np.any(variance > release) and np.any(variance < release)
    drive, z = artifact_drive(artifact, dataset), dataset.column("winding_C")
    for form in ("conventional", "joseph", "ud"):
        run = run_observer_offline(artifact, drive, z, data.run.initial, form)
        error = float(np.max(np.abs(run.outputs - reference.estimates[0])))
        assert error < 5e-3, (form, error)
    held = run_observer_offline(artifact, drive, z, data.run.initial, "ud")
    content = json.loads(json.dumps(artifact.content))
    del content["observer"]["consider_release_C2"]
    always = run_observer_offline(verify(seal(content)), drive, z, data.run.initial, "ud")
    assert np.max(np.abs(always.outputs[:, 3] - held.outputs[:, 3])) > 1e-3      # the release changed the magnet


@pytest.mark.slow   # 4 s: kept out of the 5-min default run
def test_the_release_is_bit_exact_in_the_firmware(packaged, small_dataset, tmp_path, firmware_elf):
    from .test_node_observer_firmware import _bit_exact_over_a_run, _sensor_case

    dataset = load_dataset(small_dataset)
    artifact, _ = _crossing(packaged, dataset)
    content = json.loads(json.dumps(artifact.content))
    content["observer"]["gate"] = {"sigma": 3.0, "flag_after": 10}
    path = tmp_path / "released.json"
    path.write_text(dumps(seal(content)), encoding="utf-8")
    _bit_exact_over_a_run(_sensor_case(path), firmware_elf)


@pytest.mark.parametrize("value", [encode_array(-1.0), encode_array([1.0, 2.0]), encode_array(0.0)])
def test_a_bad_release_is_refused_in_one_sentence(packaged, small_dataset, value):
    artifact = _observer(packaged, load_dataset(small_dataset))
    content = json.loads(json.dumps(artifact.content))
    content["observer"]["consider_release_C2"] = value
    with pytest.raises(ArtifactError, match="observer.consider_release_C2 must be one finite variance > 0") as info:
        verify(seal(content))
    assert "\n" not in str(info.value)
    content["observer"]["consider_release_C2"] = encode_array(4.0)
    del content["observer"]["consider"]
    with pytest.raises(ArtifactError, match="beside a consider kind"):
        verify(seal(content))


def test_without_the_field_the_section_is_written_as_before(packaged, small_dataset):
    dataset = load_dataset(small_dataset)
    without = _observer(packaged, dataset, release=None).content["observer"]
    assert "consider_release_C2" not in without and "key-on release" not in without["rule"]
    assert _observer(packaged, dataset).content["observer"]["consider_release_C2"]["f64"] == [RELEASE_C2]


def test_unmeasured_consider_states_leave_the_tooth_and_the_magnet_to_the_model(packaged, small_dataset):
    """`--consider unmeasured` with the end-winding NTC (it reads the winding and, through its gradient, the yoke):
    every form's gain has the tooth's and the magnet's rows -0, so a winding reading moves them only through the
    model's coupling; the winding, the yoke and the lag state move. Without the release the magnet stays held at
    key-on too."""
    dataset = load_dataset(small_dataset)
    artifact = _observer(packaged, dataset, "unmeasured", None)
    assert artifact.content["observer"]["consider"] == "unmeasured"
    for form in ("conventional", "joseph", "ud"):
        obs = Float32Observer(artifact, form)
        obs.reset([40.0, 40.0, 40.0, 45.0])
        assert obs.consider.holds(0, obs.cov).tolist() == [False, False, True, True, False]
        gain = obs.cov.update(obs.layout.rows[0], np.float32(0.01), 0, obs.consider.holds(0, obs.cov))
        assert all(gain[i] == 0 and np.signbit(gain[i]) for i in (2, 3)), form
        assert all(gain[i] != 0 for i in (0, 1, 4)), form
    steady = Float32Observer(artifact, "steady")
    assert all(steady.gain_steady[0][i] == 0 for i in (2, 3))


def test_the_cli_option(tmp_path, small_dataset, capsys):
    from bench.cli import build_parser, main

    assert build_parser().parse_args(["observer"]).consider_release == "none"
    out = tmp_path / "released.json"
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--lag", "60", "--consider",
                 "unmeasured", "--consider-release", "5", "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["consider"] == "unmeasured" and report["consider_release_sigma_C"] == 5.0
    section = load_artifact(out).content["observer"]
    assert section["consider_release_C2"]["f64"] == [25.0] and "key-on release" in section["rule"]
    for value in ("0", "-1", "warm", "nan"):
        assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--consider-release", value,
                     "--out", str(tmp_path / "never.json")]) == 2
        err = capsys.readouterr().err
        assert "--consider-release must be a 1-sigma in K above 0 or none" in err and err.count("\n") == 1
    assert not (tmp_path / "never.json").exists()
