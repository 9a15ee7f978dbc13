"""The output bias (`--bias winding-output`): a random walk in °C added to the winding's output, which its sensor
sees and the estimate reports, heating nothing. A winding reading moves the bias and no node, so the model's
dynamics, and the magnet with them, stay the open loop's (bit for bit in float32), while the winding follows the
sensor; the float32 forms follow the float64 filter (the firmware's C bit for bit: test_node_observer_firmware's
output-bias cases, `-m slow`)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.artifact_eval import artifact_drive
from bench.model.default import default_artifact_path
from bench.observer.measures.lagged_sensor import Sensor
from bench.observer.reference import reference_run
from bench.observer.section import observer_section, with_observer
from bench.observer.tune import ObserverFit, consider_problem
from target_sim.artifact import consider_held, load_artifact, verify
from target_sim.firmware.node_protocol import firmware_refusal
from target_sim.model import run_offline
from target_sim.observer import Float32Observer, run_observer_offline

SENSOR = Sensor("winding", "winding_C", 0.5, 25.0, -0.1)    # an end-winding NTC: lag, gradient, offset


def _with_output_bias(dataset, sensor: Sensor, q: list[float]):
    packaged = load_artifact(default_artifact_path())
    fit = ObserverFit((sensor,), np.array(q), np.array([0.05]), None, "magnet", 0.0, 0.0, 0, 0, [], "winding-output")
    return verify(with_observer(packaged, observer_section(packaged, fit, [dataset])))


@pytest.fixture(scope="module")
def output_biased(small_dataset):
    """The packaged model with the lagged end-winding sensor and a winding output bias: 6 states."""
    dataset = load_dataset(small_dataset)
    return _with_output_bias(dataset, SENSOR, [1e-4, 1e-4, 1e-4, 1e-6, 1e-4, 1e-2]), dataset


@pytest.fixture(scope="module")
def direct(small_dataset):
    """The same with a sensor that reads the winding column at once (no lag, no gradient): 5 states."""
    dataset = load_dataset(small_dataset)
    return _with_output_bias(dataset, Sensor(), [1e-4, 1e-4, 1e-4, 1e-6, 1e-2]), dataset


def test_the_section_names_the_output_bias_and_its_rule(output_biased):
    artifact, _ = output_biased
    section = artifact.content["observer"]
    assert section["bias"] == "winding-output"
    assert section["states"][4:] == ["lag of winding_C", "winding output bias (°C)"]
    assert "the bias adds to the winding's output" in section["rule"] and "heats nothing" in section["rule"]


def test_a_winding_reading_holds_every_node_and_moves_only_the_bias():
    ntc, magnet_only = np.array([-0.1, 1.1, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])
    held = consider_held(None, np.array([ntc, magnet_only]), "winding-output", 6)
    assert held[0].tolist() == [True, True, True, True, False, False]   # nodes held; lag and bias free
    assert not held[1].any()                                            # a magnet reading is not the bias's


@pytest.mark.parametrize("form", ["conventional", "joseph", "ud", "steady"])
@pytest.mark.parametrize("which", ["direct", "output_biased"])
def test_the_model_stays_the_open_loop_and_the_winding_follows_the_sensor(request, which, form):
    """Yoke, tooth and magnet are the float32 open loop's bit for bit in every form, with or without a lag state;
    the winding is the open loop's plus the bias, which brings it towards what a sensor that reads it at once reads
    (the synthetic file's winding is not the model's: measured open loop 14.2 K², the filter 1.27 K² over these 2
    minutes of fast changes; a 25 s lag and a gradient the file does not have leave 8.9 K²)."""
    artifact, dataset = request.getfixturevalue(which)
    drive, z = artifact_drive(artifact, dataset), dataset.column("winding_C")
    start = [40.0, float(z[0]), 40.0, 45.0]
    _, open_loop = run_offline(artifact, drive, start)
    run = run_observer_offline(artifact, drive, z, start, form)
    assert np.array_equal(run.outputs[:, [0, 2, 3]], open_loop[:, [0, 2, 3]])
    reference = np.interp(np.arange(1, len(run.outputs) + 1) * artifact.dt, dataset.time_s, z)
    mse_open = float(np.mean((open_loop[:, 1] - reference) ** 2))
    mse_filter = float(np.mean((run.outputs[:, 1] - reference) ** 2))
    assert mse_filter < (0.2 if which == "direct" else 0.8) * mse_open, (form, mse_filter, mse_open)


def test_the_float32_forms_follow_the_float64_filter(output_biased):
    artifact, dataset = output_biased
    data, reference = reference_run(artifact, dataset)
    drive, z = artifact_drive(artifact, dataset), dataset.column("winding_C")
    errors = {form: float(np.max(np.abs(run_observer_offline(artifact, drive, z, data.run.initial, form).outputs
                                        - reference.estimates[0]))) for form in ("conventional", "joseph", "ud")}
    run64 = run_observer_offline(artifact, drive, z, data.run.initial, "joseph", dtype=np.float64)
    error64 = float(np.max(np.abs(run64.outputs - reference.estimates[0])))
    assert max(errors.values()) < 5e-3 and error64 < 1e-4, (errors, error64)
    # the reported winding's 1-σ includes the bias's variance: above the open-loop node's own
    obs = Float32Observer(artifact)
    obs.reset(data.run.initial)
    assert obs.sigma()[1] > 0.9 * float(np.sqrt(obs.cov.variance(np.eye(6, dtype=np.float32)[5])))


def test_an_output_bias_nobody_reads_is_refused_in_one_sentence_and_the_firmware_runs_one(output_biased):
    problem = consider_problem("magnet", "winding-output", [Sensor("magnet", "pm_C")])
    assert problem.startswith("--bias winding-output adds to the winding's output, which no measurement reads")
    assert firmware_refusal(output_biased[0]) is None
    from bench.cli import build_parser

    assert build_parser().parse_args(["observer", "--bias", "winding-output"]).bias == "winding-output"


def test_bench_observer_adds_the_output_bias_by_default_where_a_measurement_reads_the_winding(small_dataset,
                                                                                             tmp_path):
    """The default (`DEFAULT_BIAS`, chosen on the motor suite) where a sensor reads the winding; --bias none and a
    measurement of the magnet alone keep no bias state (an output bias nobody reads would never move)."""
    import json

    from bench.cli import main
    from bench.observer.section import DEFAULT_BIAS, default_bias

    out = tmp_path / "default.json"
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--out", str(out), "--quiet"]) == 0
    assert DEFAULT_BIAS == "winding-output"
    assert json.loads(out.read_text(encoding="utf-8"))["observer"]["bias"] == DEFAULT_BIAS
    assert default_bias([Sensor("magnet", "pm_C")]) is None and default_bias([SENSOR]) == DEFAULT_BIAS
