"""The observer in the generated C (bench/firmware/observergen.py, fw_obs_* in fw_model.c) against the Python float32
reference: `bench firmware check` bit for bit over a run (outputs, each node's 1-sigma, each innovation, the
periodic checkpoint) for a winding sensor without lag, a lagged sensor with the winding heat-bias state (and with
the magnet heat-bias state: its column of B is data, the C the same), and a stator NTC with the flux linkage (two
measurements per row), each also in the steady-state-gain form (its
checkpoint: the extra states only, none without lag or bias), and the flux linkage with the winding temperature from
the stator resistance (both from the same voltages and currents); the firmware node answers the Python node's frames
byte for byte, Uncertainty1/2, Innovations and ObserverCheckpoint included, through ABSENT and INVALID measurements,
a lost, corrupted or misplaced Measurements (and DriveVoltages) frame, lost rows and a RESTORE with and without the
filter's checkpoint; an observer the frames cannot carry (the flux linkage on a loss-map model) or in another form
than UD or the steady-state gain is refused in one sentence before any work; open-loop artifacts get none of the
observer's C."""

from __future__ import annotations

import re

import can
import numpy as np
import pytest

from bench.cli import main
from dbc import Command, FrameCodec, decode_any
from dbc.contract import INNOVATION_SIGNALS, measurement_messages
from dbc.database import frame_id
from host.replay import encode_row, measurement_signals
from target_sim.artifact import dumps, load_artifact
from target_sim.firmware.node_engine import FirmwareNode
from target_sim.firmware.node_protocol import firmware_refusal
from target_sim.model import run_offline
from target_sim.node import TargetNode
from target_sim.observer import Float32Observer
from target_sim.observer.node import measurement_slots

from ..test_node_firmware import comparable
from helpers import SESSION_INITIAL, built_observer, observer_in_form, session_drive, steady_form

ROWS = 240


@pytest.fixture(scope="module")
def lagged_artifact(small_dataset, tmp_path_factory):
    """The packaged hammerstein model with a lagged winding sensor (τ 60 s) and the winding heat-bias state: six
    filter states."""
    return built_observer(tmp_path_factory, small_dataset, "lagged", "--lag", "60", "--bias")


@pytest.fixture(scope="module")
def magnet_bias_artifact(small_dataset, tmp_path_factory):
    """The lagged winding sensor (τ 60 s) with the magnet heat-bias state (`--bias magnet`, the magnet no consider
    state: a winding sensor would never move a held bias): six filter states, the bias heating the magnet through
    the magnet loss's column of B."""
    return built_observer(tmp_path_factory, small_dataset, "magnet-bias", "--lag", "60", "--bias", "magnet",
                          "--consider", "none")


@pytest.fixture(scope="module")
def consider_artifact(small_dataset, tmp_path_factory):
    """The lagged winding sensor (τ 60 s) with the winding heat-bias state and the magnet a consider state
    (`--consider magnet`): the sensor's update holds the magnet node, a column Bierman's update for the lag state's
    row does not touch, so Agee-Turner's update reads and writes its own part of U and d."""
    return built_observer(tmp_path_factory, small_dataset, "consider", "--lag", "60", "--bias", "winding",
                          "--consider", "magnet")


@pytest.fixture(scope="module")
def consider_sensor_artifact(small_dataset, tmp_path_factory):
    """The winding sensor without lag or bias, the magnet a consider state: the held column is one of Bierman's."""
    return built_observer(tmp_path_factory, small_dataset, "consider-sensor", "--consider", "magnet")


@pytest.fixture(scope="module")
def consider_steady_artifact(consider_artifact, tmp_path_factory):
    """The consider observer in the steady-state-gain form (its K_ss's magnet row held at -0)."""
    return steady_form(consider_artifact, tmp_path_factory)


@pytest.fixture(scope="module")
def output_bias_artifact(small_dataset, tmp_path_factory):
    """The lagged winding sensor (τ 60 s) with the winding output bias (`--bias winding-output`): the sensor's update
    holds every node and moves the lag and the bias, which the lag row of F sees and the reported winding adds."""
    return built_observer(tmp_path_factory, small_dataset, "output-bias", "--lag", "60", "--bias", "winding-output")


@pytest.fixture(scope="module")
def output_bias_sensor_artifact(small_dataset, tmp_path_factory):
    """The winding sensor without lag and the winding output bias: the bias in the sensor's row h."""
    return built_observer(tmp_path_factory, small_dataset, "output-bias-sensor", "--bias", "winding-output")


class Case:
    """An observer artifact with its drive (rows, 4 or 6) and its host measurement matrix (rows, 2 or 4)."""

    def __init__(self, path, drive: np.ndarray, measured: np.ndarray):
        self.path, self.drive, self.measured = path, drive, measured
        self.artifact = load_artifact(path)


def _sensor_case(path) -> Case:
    artifact = load_artifact(path)
    drive = session_drive(ROWS, 3)
    return Case(path, drive, np.column_stack([sensor_column(artifact, drive), np.full(len(drive), np.nan)]))


def _flux_case(flux_observer_artifact) -> Case:
    """The NTC + flux linkage observer on its dataset's first rows: NTC in Measurements, u_d/u_q in DriveVoltages
    (ABSENT every 11th row), the currents in the row; one NTC reading INVALID."""
    from bench.drive.dataset import load_dataset
    from bench.run.inputs import drive_for, measurements_for

    path, data = flux_observer_artifact
    artifact = load_artifact(path)
    dataset = load_dataset(data)
    drive, measured = drive_for(dataset, artifact)[:ROWS], measurements_for(dataset, artifact)[:ROWS].copy()
    measured[::11, 2:] = np.nan
    measured[50, 0] = 900.0
    return Case(path, drive, measured)


@pytest.fixture(scope="module")
def steady_artifact(lagged_artifact, tmp_path_factory):
    """The lagged sensor + bias observer in the steady-state-gain form."""
    return steady_form(lagged_artifact, tmp_path_factory)


@pytest.fixture(scope="module")
def steady_flux_artifact(flux_observer_artifact, tmp_path_factory):
    """The NTC + flux linkage observer in the steady-state-gain form (a row of K_ss per measurement); (path, data)."""
    path, data = flux_observer_artifact
    return steady_form(path, tmp_path_factory), data


@pytest.fixture(scope="module")
def steady_sensor_artifact(observer_artifact, tmp_path_factory):
    """The winding sensor without lag or bias in the steady-state-gain form: a filter with an empty checkpoint."""
    return steady_form(observer_artifact, tmp_path_factory)


# Each case builds its firmware and emulates a run (5-10 s): the default run keeps one per feature of the generated
# observer (a sensor, its lag, several measurements, the consider state); the forms and combinations run under
# `-m slow`, as .ci/run does (the default run has a 5-minute budget).
DEFAULT_RUN_CASES = ("sensor", "lagged", "ntc+flux", "consider")
OBSERVER_CASES = ("sensor", "lagged", "magnet-bias", "ntc+flux", "steady", "sensor-steady", "ntc+flux-steady",
                  "flux+resistance", "consider", "consider-sensor", "consider-steady", "output-bias",
                  "output-bias-sensor", "output-bias-steady")


@pytest.fixture(params=[pytest.param(c, marks=() if c in DEFAULT_RUN_CASES else (pytest.mark.slow,))
                        for c in OBSERVER_CASES])
def case(request, observer_artifact, lagged_artifact, magnet_bias_artifact, flux_observer_artifact, steady_artifact,
         steady_sensor_artifact, steady_flux_artifact, resistance_observer_artifact, consider_artifact,
         consider_sensor_artifact, consider_steady_artifact, output_bias_artifact, output_bias_sensor_artifact,
         tmp_path_factory) -> Case:
    if request.param == "ntc+flux":
        return _flux_case(flux_observer_artifact)
    if request.param == "flux+resistance":        # both from DriveVoltages and the row's currents, no sensor
        return _flux_case(resistance_observer_artifact)
    if request.param == "ntc+flux-steady":
        return _flux_case(steady_flux_artifact)
    paths = {"sensor": observer_artifact, "lagged": lagged_artifact, "magnet-bias": magnet_bias_artifact,
             "steady": steady_artifact,
             "sensor-steady": steady_sensor_artifact, "consider": consider_artifact,
             "consider-sensor": consider_sensor_artifact, "consider-steady": consider_steady_artifact,
             "output-bias": output_bias_artifact, "output-bias-sensor": output_bias_sensor_artifact}
    if request.param == "output-bias-steady":
        return _sensor_case(steady_form(output_bias_artifact, tmp_path_factory))
    return _sensor_case(paths[request.param])


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


def test_bench_firmware_check_is_bit_exact_over_a_run(case, firmware_elf):
    """Outputs, each node's 1-sigma, each innovation and the checkpoint every CHECKPOINT_EVERY_STEPS steps."""
    _bit_exact_over_a_run(case, firmware_elf)


@pytest.mark.slow   # 5 s: kept out of the 5-min default run
def test_the_steady_state_gain_form_is_cheaper(steady_artifact, lagged_artifact, firmware_elf):
    """The steady-state gain in the generated C: no covariance, a constant 1-sigma, fewer cycles than the UD form."""
    steady = _bit_exact_over_a_run(_sensor_case(steady_artifact), firmware_elf)
    ud = _bit_exact_over_a_run(_sensor_case(lagged_artifact), firmware_elf)
    assert steady["cycles"]["max"] < ud["cycles"]["max"]


def _bit_exact_over_a_run(case, firmware_elf) -> dict:
    from bench.firmware.check import check_firmware
    from target_sim.observer.node import raw_channels, raw_sources

    measured = case.measured.copy()
    measured[50, 0] = np.nan            # the check feeds the channels as the target decodes them: INVALID is NaN
    raw = raw_channels(raw_sources(case.artifact), case.drive, measured)
    result = check_firmware(case.artifact, firmware_elf(case.path), case.drive, SESSION_INITIAL, raw)
    assert result["observer"] and result["mismatches"] == 0, result["first_mismatch"]
    for used in result["updates_per_measurement"]:           # each measurement's readings were used, not all
        assert 0 < used < result["steps"], result["updates_per_measurement"]
    assert result["cycles"]["max"] > 0
    return result


def _session(node, drive, measured, faults: dict[int, str], lost: set[int], restore_at: int | None = None,
             with_filter: bool = False, filter_size: int = 1):
    """RESET, START, every row (its measurement frames first) with the given faults and lost rows, a RESTORE from the
    first checkpoint at `restore_at` (with the filter's ObserverCheckpoint echoed in RestoreObserver when
    `with_filter`: `filter_size` elements, 0 for a steady filter without lag or bias); every frame the node sent."""
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
        values = [float(v) for v in measured[row]]
        fault = faults.get(row)
        if fault == "other_step":       # the row's measurement frames carry the Step of a row 5 ahead
            misplaced = measurement_signals(row + 5, values)
            frames = [*(host.encode(message, misplaced[message]) for message in measurement_messages(len(values))),
                      *encode_row(host, row, drive[row].tolist())]
        else:
            frames = encode_row(host, row, drive[row].tolist(), values)
        if fault == "drop":
            frames = frames[1:]
        elif fault == "corrupt":
            data = bytearray(frames[0].data)
            data[4] ^= 0x10
            frames = [can.Message(arbitration_id=frames[0].arbitration_id, is_extended_id=False, data=bytes(data)),
                      *frames[1:]]
        elif fault == "drop_voltages":
            frames = [frame for frame in frames if frame.arbitration_id != frame_id("DriveVoltages")]
        send(*frames)
        if row == restore_at:
            state, filter_state = _first_checkpoint(out)
            start = row + 1 if (row + 1) % 5 == 0 else row + 5 - (row + 1) % 5    # the first row of an interval
            for index, value in enumerate(state):
                send(host.encode("RestoreState", {"Step": start, "StateIndex": index, "StateValue": value}))
            if with_filter:
                assert len(filter_state) == filter_size, "the node sent no ObserverCheckpoint"
                send(*(host.encode("RestoreObserver", {"Index": index, "StepLow": start % 4096, "Value": value})
                       for index, value in enumerate(filter_state)))
            send(host.encode("Control", {"Command": int(Command.RESTORE), "Step": start}),
                 host.encode("Control", {"Command": int(Command.START), "Step": start}))
            lost |= set(range(row + 1, start))
    return out


def _first_checkpoint(frames) -> tuple[list[float], list[float]]:
    """x of the first StateCheckpoint and the ObserverCheckpoint elements of the same row ([] if none came)."""
    elements: dict[int, dict[int, float]] = {}
    filters: dict[int, dict[int, float]] = {}
    for frame in frames:
        d = decode_any(frame)
        if d.name == "StateCheckpoint":
            elements.setdefault(int(d.signals["Step"]), {})[int(d.signals["StateIndex"])] = d.signals["StateValue"]
        elif d.name == "ObserverCheckpoint":
            filters.setdefault(int(d.signals["StepLow"]), {})[int(d.signals["Index"])] = d.signals["Value"]
    step = min(elements)
    filter_state = filters.get(step % 4096, {})
    return [elements[step][i] for i in range(4)], [filter_state[i] for i in range(len(filter_state))]


@pytest.mark.parametrize("with_filter", [False, True], ids=["restore-P0", "restore-filter"])
def test_the_firmware_node_answers_the_python_node_byte_for_byte(case, with_filter, firmware_elf):
    """ABSENT and INVALID readings, a lost, a corrupted and a misplaced Measurements frame (and a lost DriveVoltages
    frame), lost rows (a step held on the previous inputs predicts only) and a RESTORE without the filter's
    checkpoint (x bit for bit, the covariance P0, the lag state at what its sensor sees) or with it (the filter
    continues bit for bit): the same frames out, Uncertainty1/2, Innovations and ObserverCheckpoint included (timing
    frames and TargetInfo aside)."""
    artifact = case.artifact
    faults = {40: "drop", 61: "corrupt", 83: "other_step", 130: "drop_voltages"}
    # rows 94-98 lost: row 99 runs two model steps and the first checkpoint (x and the filter's) in one call, more
    # frames than an open-loop node queues; 110-116 lost: steps held on the previous inputs
    lost = {94, 95, 96, 97, 98, 110, 111, 112, 113, 114, 115, 116}
    size = Float32Observer(artifact).checkpoint_size()
    python_node = TargetNode(artifact, clock_ns=lambda: 0)
    python = _session(python_node, case.drive, case.measured, faults, set(lost), restore_at=150,
                      with_filter=with_filter, filter_size=size)
    firmware_node = FirmwareNode(artifact, firmware_elf(case.path))
    firmware = _session(firmware_node, case.drive, case.measured, faults, set(lost), restore_at=150,
                        with_filter=with_filter, filter_size=size)
    info = {frame_id("TargetInfo")}
    expected, got = comparable(python, info), comparable(firmware, info)
    assert len(got) == len(expected) and got == expected
    names = {decode_any(can.Message(arbitration_id=i, data=d, is_extended_id=False)).name for i, d in expected}
    checkpoint = {"ObserverCheckpoint"} if size else set()
    assert {"Uncertainty1", "Uncertainty2", "Innovations", "StateCheckpoint"} | checkpoint <= names
    assert checkpoint or "ObserverCheckpoint" not in names      # a steady filter without lag or bias has none
    innovations = [decode_any(can.Message(arbitration_id=i, data=d, is_extended_id=False)).signals
                   for i, d in expected if i == frame_id("Innovations")]
    for slot in measurement_slots(artifact):
        used = [s[INNOVATION_SIGNALS[slot][1]] for s in innovations]
        assert 0 < sum(used) < len(used), slot              # some steps did not use it, on both engines
    # the corrupted frame, the alive-counter jumps after the lost frames and rows, the misplaced ones and the two losses
    errors = {k: n for k, n in firmware_node.errors.items() if n}
    assert errors == {k: n for k, n in python_node.errors.items() if n}
    misplaced = len(measurement_messages(case.measured.shape[1]))      # each misplaced frame is a sequence error
    assert errors["crc"] == 1 and errors["sequence"] == 2 + misplaced and errors["counter"] >= 2


def _flux(artifact_path, tmp_path):
    """The observer artifact whose one measurement is the flux linkage (four raw channels); (its path, its model)."""
    from bench.observer.section import with_observer
    from target_sim.artifact import encode_array
    from target_sim.observer.measurements.flux_linkage import COLUMNS, PARAMETERS

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
    from target_sim.observer.node import can_refusal

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
    path = observer_in_form(observer_artifact, "joseph", tmp_path / "joseph.json")
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


@pytest.mark.slow   # the same firmware as the bit-exact cases 'ntc+flux'/'flux+resistance'
def test_bench_firmware_check_runs_the_ntc_and_the_flux_linkage(flux_observer_artifact, capsys):
    """The Python node's NTC + flux linkage observer (DBC 1.7.0) runs in the firmware too (the refusal of several
    measurements and of the flux linkage is gone): the check names both and counts each one's updates."""
    path, dataset = flux_observer_artifact
    assert firmware_refusal(load_artifact(path)) is None
    assert main(["firmware", "check", "--model", str(path), "--data", str(dataset), "--rows", "200", "--quiet"]) == 0
    stdout = capsys.readouterr().out
    assert "observer (ntc_C, flux): " in stdout and "mismatches 0 " in stdout, stdout
    assert re.search(r"\(ntc_C \d+, flux \d+\)", stdout), stdout


@pytest.mark.slow   # the same firmware as the bit-exact cases 'ntc+flux'/'flux+resistance'
def test_bench_firmware_check_runs_the_winding_resistance(resistance_observer_artifact, capsys):
    """The flux linkage and the winding resistance read the same raw channels; the generated C reads both bit for
    bit, the resistance at low speed only and the flux linkage at high speed only."""
    path, dataset = resistance_observer_artifact
    assert firmware_refusal(load_artifact(path)) is None
    assert main(["firmware", "check", "--model", str(path), "--data", str(dataset), "--rows", "200", "--quiet"]) == 0
    stdout = capsys.readouterr().out
    assert "observer (flux, resistance): " in stdout and "mismatches 0 " in stdout, stdout
    used = re.search(r"\(flux (\d+), resistance (\d+)\)", stdout)
    assert used and int(used[1]) > 0 and int(used[2]) > 0, stdout


@pytest.mark.slow   # the same firmware check as the bit-exact case "sensor": kept out of the 5-min default run
def test_bench_firmware_check_names_the_observers_measurement(observer_artifact, small_dataset, capsys):
    assert main(["firmware", "check", "--model", str(observer_artifact), "--data", str(small_dataset), "--rows", "200",
                 "--quiet"]) == 0
    stdout = capsys.readouterr().out
    assert "observer (winding_C):" in stdout and "mismatches 0 " in stdout, stdout


@pytest.mark.slow
def test_a_long_run_with_the_ntc_and_the_flux_linkage_is_bit_exact(flux_observer_artifact, firmware_elf, tmp_path):
    """4000 rows (1600 model steps) of fresh synthetic data with voltages, a tenth of the rows' voltages and NTC
    readings ABSENT at random: every output, 1-sigma, innovation and checkpoint bit for bit."""
    from bench.drive.dataset import load_dataset
    from bench.firmware.check import check_firmware
    from bench.model.runs import initial_temperatures
    from bench.run.inputs import drive_for, measurements_for
    from target_sim.observer.node import raw_channels, raw_sources

    from helpers import flux_columns, write_synthetic_dataset

    path, _ = flux_observer_artifact
    artifact = load_artifact(path)
    dataset = load_dataset(write_synthetic_dataset(tmp_path / "long.csv", flux_columns(4000, seed=11), "long"))
    drive, measured = drive_for(dataset, artifact), measurements_for(dataset, artifact)
    rng = np.random.default_rng(4)
    measured[rng.random(len(measured)) < 0.1, 2:] = np.nan
    measured[rng.random(len(measured)) < 0.1, 0] = np.nan
    raw = raw_channels(raw_sources(artifact), drive, measured)
    result = check_firmware(artifact, firmware_elf(path), drive, initial_temperatures(dataset), raw)
    assert result["steps"] == 1600 and result["mismatches"] == 0, result["first_mismatch"]
    assert all(0 < n < result["steps"] for n in result["updates_per_measurement"]), result
