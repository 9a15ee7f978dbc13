"""The observer in the generated C (bench/firmware/observergen.py, fw_obs_* in fw_model.c) against the Python float32
reference: `bench firmware check` bit for bit over a run (outputs, each node's 1-sigma, the innovation) for a winding
sensor without lag, for a lagged sensor with the winding heat-bias state and for the steady-state-gain form; the
firmware node answers the Python node's frames byte for byte, Uncertainty1/2 and Innovations included, through ABSENT
and INVALID measurements, a lost, corrupted or misplaced Measurements frame, lost rows and a RESTORE; an observer the
frames cannot carry (the flux linkage) or in another form than UD or the steady-state gain is refused in one sentence
before any work; open-loop artifacts get none of the observer's C."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest

from bench.cli import main
from dbc import Command, FrameCodec, decode_any
from dbc.database import frame_id
from host.replay import encode_row
from target_sim.artifact import dumps, load_artifact
from target_sim.firmware.node_engine import FirmwareNode
from target_sim.firmware.node_protocol import firmware_refusal
from target_sim.model import run_offline
from target_sim.node import TargetNode

from .test_node_firmware import comparable
from helpers import SESSION_INITIAL, session_drive

ROWS = 240


@pytest.fixture(scope="module")
def lagged_artifact(small_dataset, tmp_path_factory):
    """The packaged hammerstein model with a lagged winding sensor (τ 60 s) and the winding heat-bias state: six
    filter states."""
    out = tmp_path_factory.mktemp("observer-lag") / "lagged.json"
    assert main(["observer", "--train", str(small_dataset), "--evaluations", "2", "--lag", "60", "--bias", "--out",
                 str(out), "--quiet"]) == 0
    return out


@pytest.fixture(params=["sensor", "lagged"])
def observer_path(request, observer_artifact, lagged_artifact):
    return observer_artifact if request.param == "sensor" else lagged_artifact


@pytest.fixture(scope="module")
def steady_artifact(lagged_artifact, tmp_path_factory):
    """The lagged sensor + bias observer in the steady-state-gain form (the same K_ss the artifact stores)."""
    from bench.model.observer import with_observer

    artifact = load_artifact(lagged_artifact)
    out = tmp_path_factory.mktemp("observer-steady") / "steady.json"
    out.write_text(dumps(with_observer(artifact, {**artifact.content["observer"], "form": "steady"})),
                   encoding="utf-8")
    return out


def sensor_column(artifact, drive: np.ndarray) -> np.ndarray:
    """A winding sensor 1.5 K warm of the open loop, with noise; NaN (ABSENT) every 7th row, one INVALID reading
    (beyond the DBC's range)."""
    steps, open_loop = run_offline(artifact, drive, SESSION_INITIAL)
    rng = np.random.default_rng(1)
    sensor = np.round(np.interp(np.arange(len(drive)), steps, open_loop[:, 1]) + 1.5 + rng.normal(0, 0.3, len(drive)),
                      2)
    sensor[::7] = np.nan
    sensor[50] = 900.0
    return sensor


def test_bench_firmware_check_is_bit_exact_over_a_run(observer_path, firmware_elf):
    _bit_exact_over_a_run(observer_path, firmware_elf)


def test_the_steady_state_gain_form_is_bit_exact_and_cheaper(steady_artifact, lagged_artifact, firmware_elf):
    """The steady-state gain in the generated C: no covariance, a constant 1-sigma, fewer cycles than the UD form."""
    steady = _bit_exact_over_a_run(steady_artifact, firmware_elf)
    ud = _bit_exact_over_a_run(lagged_artifact, firmware_elf)
    assert steady["cycles"]["max"] < ud["cycles"]["max"]


def _bit_exact_over_a_run(observer_path, firmware_elf) -> dict:
    from bench.firmware.check import check_firmware

    artifact = load_artifact(observer_path)
    drive = session_drive(ROWS, 3)
    sensor = sensor_column(artifact, drive)
    sensor[50] = np.nan                 # the check feeds the column as the target decodes it: INVALID is NaN
    result = check_firmware(artifact, firmware_elf(observer_path), drive, SESSION_INITIAL, sensor)
    assert result["observer"] and result["mismatches"] == 0, result["first_mismatch"]
    assert 0 < result["updates"] < result["steps"]          # the steps whose interval lacks a reading predict only
    assert result["cycles"]["max"] > 0
    return result


def _session(node, drive, sensor, faults: dict[int, str], lost: set[int], restore_at: int | None = None):
    """RESET, START, every row (its Measurements first) with the given faults and lost rows, a RESTORE from the first
    checkpoint at `restore_at`; every frame the node sent."""
    host = FrameCodec("HOST")
    out = list(node.startup_frames())

    def send(*frames):
        for frame in frames:
            out.extend(node.handle(frame))

    yoke, winding, tooth, magnet = SESSION_INITIAL
    send(host.encode("ResetTemps1", {"Step": 0, "WindingTempInit": winding, "MagnetTempInit": magnet}),
         host.encode("ResetTemps2", {"Step": 0, "YokeTempInit": yoke, "ToothTempInit": tooth}),
         host.encode("Control", {"Command": int(Command.RESET), "Step": 0}),
         host.encode("Control", {"Command": int(Command.START), "Step": 0}))
    for row in range(len(drive)):
        if row in lost:
            continue
        frames = encode_row(host, row, drive[row].tolist(), [float(sensor[row]), math.nan])
        fault = faults.get(row)
        if fault == "drop":
            frames = frames[1:]
        elif fault == "corrupt":
            data = bytearray(frames[0].data)
            data[4] ^= 0x10
            frames = [can.Message(arbitration_id=frames[0].arbitration_id, is_extended_id=False, data=bytes(data)),
                      *frames[1:]]
        elif fault == "other_step":
            frames = [encode_row(host, row + 5, drive[row].tolist(), [float(sensor[row]), math.nan])[0], *frames[1:]]
        send(*frames)
        if row == restore_at:
            state = _first_checkpoint(out)
            start = row + 1 if (row + 1) % 5 == 0 else row + 5 - (row + 1) % 5    # the first row of an interval
            for index, value in enumerate(state):
                send(host.encode("RestoreState", {"Step": start, "StateIndex": index, "StateValue": value}))
            send(host.encode("Control", {"Command": int(Command.RESTORE), "Step": start}),
                 host.encode("Control", {"Command": int(Command.START), "Step": start}))
            lost |= set(range(row + 1, start))
    return out


def _first_checkpoint(frames) -> list[float]:
    elements: dict[int, dict[int, float]] = {}
    for frame in frames:
        d = decode_any(frame)
        if d.name == "StateCheckpoint":
            elements.setdefault(int(d.signals["Step"]), {})[int(d.signals["StateIndex"])] = d.signals["StateValue"]
    step = min(elements)
    return [elements[step][i] for i in range(4)]


def test_the_firmware_node_answers_the_python_node_byte_for_byte(observer_path, firmware_elf):
    """ABSENT and INVALID readings, a lost, a corrupted and a misplaced Measurements frame, lost rows (a step held on
    the previous inputs predicts only) and a RESTORE without the filter's checkpoint (x bit for bit, the covariance P0,
    the lag state at what its sensor sees): the same frames out,
    Uncertainty1/2 and Innovations included (timing frames and TargetInfo aside)."""
    artifact = load_artifact(observer_path)
    drive = session_drive(ROWS, 3)
    sensor = sensor_column(artifact, drive)
    faults = {40: "drop", 61: "corrupt", 83: "other_step"}
    lost = {100, 101, 102, 103, 104, 105, 106}
    python_node = TargetNode(artifact, clock_ns=lambda: 0)
    python = _session(python_node, drive, sensor, faults, set(lost), restore_at=150)
    firmware_node = FirmwareNode(artifact, firmware_elf(observer_path))
    firmware = _session(firmware_node, drive, sensor, faults, set(lost), restore_at=150)
    info = {frame_id("TargetInfo")}
    # the firmware does not checkpoint the filter (no ObserverCheckpoint; its RESTORE is the Python node's without
    # the filter's elements: P0, the lag state at what its sensor sees), so the Python node's are set aside
    filter_checkpoint = {frame_id("ObserverCheckpoint")}
    expected, got = comparable(python, info | filter_checkpoint), comparable(firmware, info)
    assert any(frame.arbitration_id in filter_checkpoint for frame in python)
    assert len(got) == len(expected) and got == expected
    names = {decode_any(can.Message(arbitration_id=i, data=d, is_extended_id=False)).name for i, d in expected}
    assert {"Uncertainty1", "Uncertainty2", "Innovations", "StateCheckpoint"} <= names
    innovations = [decode_any(can.Message(arbitration_id=i, data=d, is_extended_id=False)).signals
                   for i, d in expected if i == frame_id("Innovations")]
    used = [s["SensorUsed"] for s in innovations]
    assert 0 < sum(used) < len(used)                        # some steps predicted only, on both engines
    # the corrupted frame, the alive-counter jumps after the lost frame and rows, the misplaced one and the lost rows
    errors = {k: n for k, n in firmware_node.errors.items() if n}
    assert errors == {k: n for k, n in python_node.errors.items() if n}
    assert errors["crc"] == 1 and errors["sequence"] == 2 and errors["counter"] >= 2


def _flux(artifact_path, tmp_path):
    """The observer artifact whose one measurement is the flux linkage (four raw channels); (its path, its model)."""
    from bench.model.observer import with_observer
    from target_sim.artifact import encode_array
    from target_sim.measurements.flux_linkage import COLUMNS, PARAMETERS

    artifact = load_artifact(artifact_path)
    section = artifact.content["observer"]
    values = (0.1, -1e-3, 60.0, 1e-4, 0.02, 3.9e-3, 20.0, 4.0, 1500.0, 1.0, 1.0)
    arrays = {k: encode_array(v) for k, v in zip(PARAMETERS, values, strict=True)}
    flux = {"kind": "flux-linkage", "name": "flux", "columns": list(COLUMNS), "node": "magnet",
            "arrays": {**arrays, "sees": section["measurements"][0]["arrays"]["sees"]}}
    path = tmp_path / "flux-observer.json"
    path.write_text(dumps(with_observer(artifact, {**section, "measurements": [flux]})), encoding="utf-8")
    return path, load_artifact(path)


def test_a_flux_observer_is_refused_in_one_sentence_before_any_work(observer_artifact, small_dataset, tmp_path,
                                                                      capsys):
    from target_sim.observer_node import can_refusal

    path, model = _flux(observer_artifact, tmp_path)
    sentence = can_refusal(model)
    assert firmware_refusal(model) == sentence
    out = tmp_path / "out"
    for argv in (["firmware", "check", "--model", str(path), "--data", str(small_dataset)],
                 ["firmware", "build", "--model", str(path), "--out", str(out)],
                 ["run", "--model", str(path), "--engine", "firmware", "--data", str(small_dataset), "--log",
                  str(out / "run.blf"), "--no-report"]):
        assert main(argv) == 2, argv
        stdout, err = capsys.readouterr()
        assert stdout == "" and err == f"bench: error: {sentence}\n", err
    assert not out.exists()


def test_an_observer_in_another_form_is_refused_by_the_firmware(observer_artifact, tmp_path):
    from bench.model.observer import with_observer

    artifact = load_artifact(observer_artifact)
    path = tmp_path / "joseph.json"
    path.write_text(dumps(with_observer(artifact, {**artifact.content["observer"], "form": "joseph"})),
                    encoding="utf-8")
    model = load_artifact(path)
    assert firmware_refusal(model) == (
        f"the firmware engine runs an observer in the ud form (Bierman-Thornton) or the steady form (the "
        f"steady-state gain), and model {model.model_id:08x} ({path}) deploys the joseph form: rebuild it with "
        "'bench observer --form ud' or use --engine python")


def test_open_loop_artifacts_get_none_of_the_observer_code(artifacts):
    from bench.firmware.codegen import generate

    for name in ("lti", "hammerstein"):
        source = generate(load_artifact(artifacts[name]))
        assert "fw_obs_" not in source.source + source.header and "obs_gains" not in source.source
        assert "FW_OBSERVER" not in source.header


def test_an_observer_the_can_node_runs_but_the_firmware_lacks_is_refused_in_its_own_sentence(flux_observer_artifact,
                                                                                             capsys):
    """The Python node runs the NTC and the flux linkage together over CAN (DBC 1.7.0); the generated C has one
    lagged sensor, so the firmware says so, before any work."""
    from target_sim.observer_node import can_refusal

    path, dataset = flux_observer_artifact
    model = load_artifact(path)
    assert can_refusal(model) is None
    sentence = firmware_refusal(model)
    assert sentence is not None and "one lagged temperature sensor" in sentence and "(flux-linkage)" in sentence
    for argv in (["firmware", "check", "--model", str(path), "--data", str(dataset), "--rows", "50"],
                 ["run", "--model", str(path), "--engine", "firmware", "--data", str(dataset), "--no-report"]):
        assert main(argv) == 1, argv
        stdout, err = capsys.readouterr()
        assert stdout == "" and err == f"bench: error: {sentence}\n", err


def test_bench_firmware_check_names_the_observers_measurement(observer_artifact, small_dataset, capsys):
    assert main(["firmware", "check", "--model", str(observer_artifact), "--data", str(small_dataset), "--rows", "200",
                 "--quiet"]) == 0
    stdout = capsys.readouterr().out
    assert "observer (winding_C):" in stdout and "mismatches 0 " in stdout, stdout
