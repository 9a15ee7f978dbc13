"""A model with an observer over CAN, end to end (DBC 1.6.0): `bench run --model <observer artifact>` sends each
row's Measurements frame, the Python target updates its filter with it and answers every model step with each
node's 1-sigma and the innovation; the run is clean (CAN = the offline float32 observer on the decoded
measurements); a dropped or corrupted Measurements frame is detected like any other and the filter then predicts
only (CAN = the target's twin); `bench replay` and `bench analyze` of the log; the firmware engine runs it clean too,
and both engines run the flux linkage with the winding resistance (two readings from the same voltages) clean;
data without the measured column is refused in one sentence before any work, and so is an observer whose readings
the frames cannot carry: exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.analysis.logdecode import decode_log
from bench.cli import main
from target_sim.artifact import load_artifact
from target_sim.model import run_offline
from target_sim.observer import run_observer_offline

from helpers import refused_in_one_sentence, run_cli, synthetic_columns, write_synthetic_dataset

ROWS = 300


@pytest.fixture(scope="module")
def validation_run(default_data_root):
    """The built-in motor's 40 °C run, whose winding column the packaged model explains (the observer's sensor)."""
    from bench.drive.generate import ensure_default_datasets

    return ensure_default_datasets(default_data_root)[40]


@pytest.fixture(scope="module")
def run(observer_artifact, validation_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("observer-run")
    log, report = out / "run.blf", out / "report"
    proc = run_cli("-m", "bench", "run", "--model", str(observer_artifact), "--data", str(validation_run), "--rows",
                   str(ROWS), "--log", str(log), "--report", str(report), "--reply-timeout", "0.5", "--json",
                   timeout=300)
    return proc, log, report


def test_bench_run_with_an_observer_is_clean_over_can(run, observer_artifact):
    proc, log, report = run
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert (s["steps_sent"], s["replies"], s["missing"], s["problems"], s["clean"]) == (ROWS, ROWS, 0, [], True)
    metrics = s["metrics"]
    assert metrics["can_reference"] == "offline float32"
    assert all(0 <= v <= 0.005 + 1e-9 for v in s["max_abs_can_minus_float32_C"].values())
    observer = metrics["observer"]
    assert (observer["measured_node"], observer["slot"], observer["rows_measured"]) == ("winding", "sensor", ROWS)
    assert observer["model_steps"] == observer["model_steps_updated"] == metrics["model_steps"] == 120
    assert observer["sigma_final_C"]["magnet"] > observer["sigma_final_C"]["winding"] > 0
    text = (report / "report.md").read_text(encoding="utf-8")
    assert "## Observer" in text and "measuring the **winding** node" in text
    # the log: a Measurements frame before every row's pair; the target answered with the observer, not open loop
    record = decode_log(log)
    assert record.measurement_frames == ROWS and np.isfinite(record.measurements[:, 0]).all()
    assert np.isnan(record.measurements[:, 1]).all()
    artifact = load_artifact(observer_artifact)
    run_ = run_observer_offline(artifact, record.drive, record.measurements[:, 0], record.initial)
    assert np.max(np.abs(record.temps[run_.rows] - run_.outputs)) <= 0.005 + 1e-9
    _, open_loop = run_offline(artifact, record.drive, record.initial)
    assert np.max(np.abs(record.temps[run_.rows] - open_loop)) > 0.05
    assert len(record.observer["row_u1"]) == len(record.observer["row_inn"]) == 120


@pytest.mark.slow
def test_replay_and_analyze_of_an_observer_log(run, observer_artifact, validation_run, tmp_path):
    _, log, _ = run
    replay = run_cli("-m", "bench", "replay", str(log), "--model", str(observer_artifact), "--as-fast-as-possible",
                     "--log", str(tmp_path / "replay.blf"), "--json", timeout=300)
    assert replay.returncode == 0, replay.stderr
    r = json.loads(replay.stdout)
    assert (r["reproduced"], r["identical"], r["different"]) == (True, ROWS, 0)
    analyzed = run_cli("-m", "bench", "analyze", str(log), "--model", str(observer_artifact), "--data",
                       str(validation_run), "--report", str(tmp_path / "report"), "--json", timeout=300)
    assert analyzed.returncode == 0, analyzed.stderr
    a = json.loads(analyzed.stdout)
    assert (a["steps_sent"], a["replies"], a["clean"]) == (ROWS, ROWS, True)


@pytest.mark.slow     # in the default run the node's own tests cover a lost and a corrupted Measurements frame
@pytest.mark.parametrize("kind", ["drop", "corrupt"])
def test_a_faulted_measurement_frame_is_detected_and_the_filter_predicts_only(kind, observer_artifact,
                                                                             validation_run, udp_bus, tmp_path):
    from bench.analysis.canmetrics import compute
    from bench.drive.dataset import load_dataset
    from bench.model.runs import drive_matrix, initial_temperatures
    from bench.run.execute import run_with_target
    from bench.run.inputs import measurements_for
    from host.faults import parse_faults

    dataset, artifact = load_dataset(validation_run), load_artifact(observer_artifact)
    log = tmp_path / f"{kind}.blf"
    outcome = run_with_target(observer_artifact, artifact, udp_bus, drive_matrix(dataset)[:ROWS],
                              initial_temperatures(dataset), sample_period_s=dataset.sample_period_s, log_path=log,
                              reply_timeout_s=0.5, faults=parse_faults([f"{kind}=0.03"], seed=3),
                              measurements=measurements_for(dataset, artifact)[:ROWS])
    faults = outcome.result.faults
    assert faults["undetected"] == 0 and faults["detected"][kind] == faults["injected"][kind] >= 3, faults
    record = decode_log(log)
    hit = {m.row for m in record.marks if m.event == "fault" and m.frame_id == 0x113}
    assert hit, "no Measurements frame was faulted"
    results, _ = compute(record, artifact, dataset)
    metrics = results.to_json()
    assert metrics["missing"] == 0 and metrics["can_reference"] == "target twin"
    assert metrics["can_agrees_with_float32"], metrics["max_abs_can_minus_float32_C"]
    # the steps that lost their measurement predicted only: fewer updates than steps, and not the clean estimate
    assert metrics["observer"]["model_steps_updated"] < metrics["observer"]["model_steps"]
    assert max(metrics["max_abs_can_minus_clean_C"].values()) > 0


@pytest.mark.slow   # 6 s (its C bit-exact in the firmware checks): kept out of the 5-min default run
def test_bench_run_on_the_firmware_engine_with_an_observer_is_clean(observer_artifact, validation_run, tmp_path):
    """The observer in the generated C (fw_obs_*): clean over CAN, its replies the offline float32 observer's, every
    model step updated and answered with each node's 1-sigma, its cycles counted (predict + update)."""
    proc = run_cli("-m", "bench", "run", "--model", str(observer_artifact), "--data", str(validation_run), "--rows",
                   str(ROWS), "--engine", "firmware", "--log", str(tmp_path / "run.blf"), "--no-report",
                   "--reply-timeout", "0.5", "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert (s["steps_sent"], s["missing"], s["clean"]) == (ROWS, 0, True)
    metrics = s["metrics"]
    assert metrics["can_reference"] == "offline float32" and metrics["can_agrees_with_float32"]
    assert metrics["observer"]["model_steps_updated"] == metrics["model_steps"] == 120
    assert metrics["observer"]["sigma_final_C"]["magnet"] > metrics["observer"]["sigma_final_C"]["winding"] > 0
    assert metrics["m4_cycles"]["max"] > 0


def _clean_run(path, data, engine: str, tmp_path) -> dict:
    """`bench run` of 200 rows of `data` with the observer `path` on `engine`: exit 0, no reply missing, clean, CAN
    equal to the offline float32 observer; its metrics."""
    proc = run_cli("-m", "bench", "run", "--model", str(path), "--data", str(data), "--rows", "200", "--engine",
                   engine, "--log", str(tmp_path / "run.blf"), "--no-report", "--reply-timeout", "0.5", "--json",
                   timeout=300)
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert (s["missing"], s["clean"]) == (0, True), s["verdict"]
    metrics = s["metrics"]
    assert metrics["can_reference"] == "offline float32" and metrics["can_agrees_with_float32"]
    return metrics


@pytest.mark.slow   # 6 s, its flux linkage bit-exact in firmware check
def test_bench_run_on_the_firmware_engine_with_the_ntc_and_the_flux_linkage_is_clean(flux_observer_artifact,
                                                                                     tmp_path):
    """Two measurements per row in the generated C (DBC 1.7.0): the NTC in Measurements, the flux linkage from
    DriveVoltages and the row's currents; clean over CAN, each slot used (the flux above its speed only)."""
    metrics = _clean_run(*flux_observer_artifact, "firmware", tmp_path)
    used = {slot: m["model_steps_updated"] for slot, m in metrics["observer"]["measurements"].items()}
    assert used["sensor"] == metrics["model_steps"] and 0 < used["flux"] < metrics["model_steps"], used
    assert metrics["m4_cycles"]["max"] > 0


# the firmware case in -m slow: the NTC + flux linkage run covers the observer firmware over CAN in the default run, and
# test_node_observer_firmware the resistance's C bit for bit
@pytest.mark.parametrize("engine", ["python", pytest.param("firmware", marks=pytest.mark.slow)])
def test_bench_run_with_the_flux_linkage_and_the_winding_resistance_is_clean(engine, resistance_observer_artifact,
                                                                              tmp_path):
    """Two measurements from the same DriveVoltages and the row's currents: the flux linkage answers in the flux
    slot (above its speed), the winding resistance in the sensor slot (below its speed, with enough i_d); clean over
    CAN on both engines, each slot used on some steps and not on others."""
    metrics = _clean_run(*resistance_observer_artifact, engine, tmp_path)
    observer = metrics["observer"]["measurements"]
    used = {slot: m["model_steps_updated"] for slot, m in observer.items()}
    assert 0 < used["sensor"] < metrics["model_steps"] and 0 < used["flux"] < metrics["model_steps"], used
    assert observer["sensor"]["measured_node"] == "winding" and observer["flux"]["measured_node"] == "magnet"


def test_data_without_the_measured_column_is_refused_before_anything_starts(observer_artifact, tmp_path, capsys):
    """An observer of a stator NTC (ntc_C, an optional column) on data without one."""
    from bench.observer.section import with_observer
    from target_sim.artifact import dumps

    artifact = load_artifact(observer_artifact)
    section = artifact.content["observer"]
    sensor = {**section["measurements"][0], "name": "ntc_C", "columns": ["ntc_C"]}
    ntc = tmp_path / "ntc-observer.json"
    ntc.write_text(dumps(with_observer(artifact, {**section, "column": "ntc_C", "measurements": [sensor]})),
                   encoding="utf-8")
    data = write_synthetic_dataset(tmp_path / "no-ntc.csv", synthetic_columns(50, seed=2), "no NTC")
    log = tmp_path / "run.blf"
    model = load_artifact(ntc)
    err = refused_in_one_sentence(capsys, ["run", "--model", str(ntc), "--data", str(data), "--log", str(log),
                                           "--no-report"])
    assert f"model {model.model_id:08x} ({ntc}) has an observer that measures column ntc_C, and {data} has none" \
        in err
    assert not log.exists()


def _uncarried(artifact, tmp_path, what: str):
    """The observer artifact with a section version 2 the Measurements frame cannot carry: `flux` one flux-linkage
    measurement (four raw channels), `two` the lagged sensor twice; (its path, its model)."""
    from bench.observer.section import with_observer
    from target_sim.artifact import dumps, encode_array
    from target_sim.observer.measurements.flux_linkage import COLUMNS, PARAMETERS

    section = artifact.content["observer"]
    sensor = section["measurements"][0]
    if what == "flux":
        arrays = {k: encode_array(v) for k, v in zip(PARAMETERS, (0.1, -1e-3, 60.0, 1e-4, 0.02, 3.9e-3, 20.0, 4.0,
                                                                   1500.0, 1.0, 1.0), strict=True)}
        measurements = [{"kind": "flux-linkage", "name": "flux", "columns": list(COLUMNS), "node": "magnet",
                         "arrays": {**arrays, "sees": sensor["arrays"]["sees"]}}]
        k_ss = section["K_ss"]
    else:
        measurements = [sensor, {**sensor, "name": "second"}]
        gain = artifact.array("observer", "K_ss", dtype=np.float64).reshape(1, -1)
        k_ss = encode_array(np.vstack([gain, gain]))
    path = tmp_path / f"{what}-observer.json"
    path.write_text(dumps(with_observer(artifact, {**section, "measurements": measurements, "K_ss": k_ss})),
                    encoding="utf-8")
    return path, load_artifact(path)


@pytest.mark.parametrize("what", ["flux", "two"])
def test_an_observer_the_frames_cannot_carry_is_refused_before_any_work(what, observer_artifact, small_dataset,
                                                                         tmp_path, capsys):
    """Over CAN each measurement answers in its own Innovations slot, and the target computes the flux linkage from
    the row's voltages (DriveVoltages) and currents (DriveCurrents): a flux linkage on a loss-map model (its rows
    carry no currents) or two sensors in one slot is refused by `bench run`, `bench host` and the target in one
    sentence, exit 2, with nothing written, not run wrongly."""
    from target_sim.observer.node import can_refusal

    artifact = load_artifact(observer_artifact)
    assert artifact.content["observer"]["version"] == 2 and can_refusal(artifact) is None
    path, model = _uncarried(artifact, tmp_path, what)
    sentence = (f"model {model.model_id:08x} ({path}) has an observer that measures the flux linkage from the d/q "
                "currents, and its" if what == "flux" else
                f"model {model.model_id:08x} ({path}) has an observer whose measurements "
                f"{model.content['observer']['measurements'][0]['name']}, second would all answer in the sensor slot")
    assert can_refusal(model).startswith(sentence)
    out = tmp_path / "out"
    for argv in (["run", "--model", str(path), "--data", str(small_dataset), "--log", str(out / "run.blf"),
                  "--report", str(out / "report")],
                 ["host", "--model", str(path), "--data", str(small_dataset), "--log", str(out / "host.blf")]):
        assert main(argv) == 2, argv
        stdout, err = capsys.readouterr()
        assert stdout == "" and err.startswith("bench: error: " + sentence) and err.count("\n") == 1, err
    assert not out.exists()
    target = run_cli("-m", "target_sim", "--model", str(path), "--quiet", timeout=60)
    assert target.returncode == 2 and target.stdout == "", target.stderr
    assert target.stderr.startswith("target_sim: error: " + sentence) and target.stderr.count("\n") == 1


def test_a_lying_sensor_over_can_is_rejected_counted_and_named(observer_artifact, validation_run, tmp_path):
    """The built-in motor's 40 °C run with its winding column +20 K for 100 rows: `bench run` over the bus with the
    observer `bench observer` wrote (its default 3-sigma gate): every lying reading rejected and counted in the CAN
    log (DBC 1.8.0: Innovations' SensorRejected, Uncertainty1's SensorFlagged), as the target's float32 code offline
    counts them step for step, the sensor flagged, the run not clean with a sentence naming winding_C, and the
    observer's magnet while the sensor lies no worse than 1.5× the open loop's (the same observer without the gate:
    far worse); the log with some flags cleared is a finding of the cross-check."""
    from bench.drive.dataset import OPTIONAL_SCHEMA, SCHEMA, load_dataset, write_dataset
    from target_sim.artifact import dumps, seal

    rows, lie = 500, slice(200, 300)
    dataset = load_dataset(validation_run)
    names = [c.name for c in (*SCHEMA, *OPTIONAL_SCHEMA) if dataset.has(c.name)]
    columns = {name: np.array(getattr(dataset, name)[:rows], dtype=np.float64) for name in names}
    columns["winding_C"][lie] += 20.0
    lying = tmp_path / "lying.csv"
    write_dataset(lying, columns, {"coolant_setpoint_C": dataset.coolant_setpoint_C, "note": "winding_C lies"})
    log = tmp_path / "run.blf"
    report = tmp_path / "report"
    proc = run_cli("-m", "bench", "run", "--model", str(observer_artifact), "--data", str(lying), "--log", str(log),
                   "--report", str(report), "--reply-timeout", "0.5", "--json", timeout=300)
    assert proc.returncode != 0
    s = json.loads(proc.stdout)
    assert s["clean"] is False and s["missing"] == 0
    named = [p for p in s["problems"] if "innovation gate flagged the sensor winding_C" in p]
    assert len(named) == 1 and s["problems"] == named, s["problems"]
    slot = s["metrics"]["observer"]["measurements"]["sensor"]
    assert slot["sensor_flagged"] is True and slot["sensor"] == "winding_C"
    text = (report / "report.md").read_text(encoding="utf-8")
    assert f"The innovation gate rejected {slot['readings_rejected']} readings of winding_C (sensor)" in text
    assert "the sensor was flagged" in text
    # every lying reading's step rejected (100 rows: 40 model steps), as the target's own code offline counts them
    artifact = load_artifact(observer_artifact)
    record = decode_log(log)
    gated = run_observer_offline(artifact, record.drive, record.measurements[:, 0], record.initial)
    in_lie = (gated.rows >= lie.start) & (gated.rows < lie.stop)
    assert gated.rejected[in_lie, 0].all() and slot["readings_rejected"] == int(gated.rejected.sum()) >= 40
    assert np.max(np.abs(record.temps[gated.rows] - gated.outputs)) <= 0.005 + 1e-9     # CAN = that code
    # DBC 1.8.0: the CAN log itself carries them (a Rejected flag per step, the Flagged flag), and they were
    # checked against that code at every step
    on_bus = record.observer["sensor_rejected"] > 0
    assert int(on_bus.sum()) == slot["readings_rejected"] == slot["readings_rejected_float32"]
    assert set(record.observer["row_inn"][on_bus].astype(int)) == set(gated.rows[gated.rejected[:, 0]].tolist())
    assert not (on_bus & (record.observer["sensor_used"] > 0)).any()
    assert record.observer["sensor_flagged"].any() and slot["gate_source"] == "bus"
    assert slot["gate_steps_compared"] == len(gated.rows) and slot["gate_steps_differing"] == 0
    _a_gate_the_bus_does_not_match_is_a_finding(artifact, record, lying)
    section = {k: v for k, v in artifact.content["observer"].items() if k != "gate"}
    plain = load_artifact_content(dumps(seal({**artifact.content, "observer": section})), tmp_path)
    ungated = run_observer_offline(plain, record.drive, record.measurements[:, 0], record.initial)
    _, open_loop = run_offline(artifact, record.drive, record.initial)
    pm = columns["pm_C"][gated.rows[in_lie]]

    def rmse(values):
        return float(np.sqrt(np.mean((values[in_lie, 3] - pm) ** 2)))

    figures = {"open loop": rmse(open_loop), "observer": rmse(ungated.outputs), "gated": rmse(gated.outputs)}
    print(figures)
    assert figures["gated"] <= 1.5 * figures["open loop"] < figures["observer"], figures


def _a_gate_the_bus_does_not_match_is_a_finding(artifact, record, data) -> None:
    """The same log with the Rejected flags of three steps cleared (a target whose gate is not its code's): the
    cross-check counts those steps and the run's problems name the sensor."""
    from dataclasses import replace

    from bench.analysis.canmetrics import compute
    from bench.analysis.verdict import gate_problems
    from bench.drive.dataset import load_dataset

    observer = dict(record.observer)
    flags = observer["sensor_rejected"].copy()
    flags[np.flatnonzero(flags > 0)[:3]] = 0
    observer["sensor_rejected"] = flags
    results, _ = compute(replace(record, observer=observer), artifact, load_dataset(data))
    slot = results.observer.measurements["sensor"]
    assert slot.gate_steps_differing == 3 and slot.readings_rejected == slot.readings_rejected_float32 - 3
    said = [p for p in gate_problems(results) if "differs from its float32 code offline" in p]
    assert len(said) == 1 and "winding_C (sensor)" in said[0] and "at 3 of" in said[0], said


def load_artifact_content(text: str, folder):
    path = folder / "plain.json"
    path.write_text(text, encoding="utf-8")
    return load_artifact(path)
