"""Each fault kind through a real target process on a real bus: injected == detected, and the temperatures
outside the marked gaps are the clean run's. With the Python engine and with the firmware engine (the compiled
model in the emulated core) a representative subset in the default run, every kind under `-m slow`.

Every kind (the host's drive-frame and process faults, the target's reply faults) runs once over the same 500
rows (lockstep, udp_multicast, a port per run) with a seed that injects several faults, and is compared with a
clean run of the same rows:

* every injected fault is detected by the side that receives it (the target's journal, the host's validator,
  deadline misses and heartbeat monitor), exactly, and each is in the sidecar and, for the host's own kinds,
  marked in the log (BenchEvent);
* every row has a reply, and every reply equals the offline float32 reference restarted as the target was, within
  the 0.005 °C quantization;
* the temperatures outside the marked gaps are the clean run's within 0.005 °C — in fact equal: bus faults
  leave the trajectory identical (the lost rows are retransmitted, nothing corrupted reaches the model), and
  after a kill or a freeze (a marked gap) the target is restored from its last StateCheckpoint, float32 bit for
  bit, so even the rows inside the gap, answered again, equal the clean run's.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.model.default import default_artifact_path
from host.faults import KINDS, parse_faults, read_sidecar
from target_sim.artifact import load_artifact

from .conftest import bench_run
from helpers import private_udp_bus

ROWS = 500
RATES = {"drop": "0.015", "duplicate": "0.015", "corrupt": "0.015", "stale_counter": "0.015",
         "wrong_length": "0.015", "unknown_id": "0.015", "out_of_range": "0.015", "reorder": "0.02",
         "delay": "0.02", "kill": "1", "freeze": "1",
         **{f"reply_{k}": "0.015" for k in ("drop", "duplicate", "corrupt", "stale_counter", "wrong_length",
                                             "unknown_id", "out_of_range")}}
assert set(RATES) == set(KINDS)


@pytest.fixture(scope="module")
def clean(tmp_path_factory, fault_dataset):
    bus = private_udp_bus()
    log = tmp_path_factory.mktemp("clean") / "clean.blf"
    result, metrics, record = bench_run(fault_dataset, log, bus, rows=ROWS)
    assert result.aborted is None and result.missing == 0 and metrics["missing"] == 0, result.problems()
    return record


# The firmware engine (the packaged ELF in the emulated Cortex-M4F) through a representative subset in the default
# run: a kill restored from a checkpoint (a corrupted drive frame, the node's own checks, and the whole sweep with
# `-m slow`). Its replies are compared with the Python engine's clean run: equal, bit for bit.
FIRMWARE_DEFAULT = ("kill",)    # the rest with -m slow: the default run has a 5-minute budget
# The Python engine: one kind of each way a frame can go wrong (lost, damaged, late, out of order, a dead or frozen
# target, and a reply lost or damaged) in the default run; the kinds whose detection is the same check on another
# field (duplicate, stale counter, wrong length, unknown id, out of range, both ways) with -m slow.
PYTHON_DEFAULT = ("drop", "corrupt", "delay", "reorder", "kill", "freeze", "reply_drop", "reply_corrupt")
CASES = [pytest.param(kind, "python", id=kind, marks=() if kind in PYTHON_DEFAULT else (pytest.mark.slow,))
         for kind in KINDS] + [
    pytest.param(kind, "firmware", id=f"{kind}-firmware",
                 marks=() if kind in FIRMWARE_DEFAULT else (pytest.mark.slow,)) for kind in KINDS]


@pytest.mark.parametrize(("kind", "engine"), CASES)
def test_each_fault_kind_is_detected_and_the_temperatures_survive(kind, engine, clean, fault_dataset, tmp_path,
                                                                  udp_bus):
    spec = parse_faults([f"{kind}={RATES[kind]}"], seed=3)
    log = tmp_path / f"{kind}.blf"
    result, metrics, record = bench_run(fault_dataset, log, udp_bus, spec, rows=ROWS, engine=engine)
    assert metrics["engine"] == engine and (metrics["m4_cycles"] is not None) == (engine == "firmware")
    faults = result.faults
    injected, detected = faults["injected"][kind], faults["detected"][kind]
    assert injected >= (1 if kind in ("kill", "freeze") else 3), faults
    assert detected == injected and faults["undetected"] == 0, faults["undetected_faults"]
    assert sum(faults["injected"].values()) == injected  # nothing else was injected
    # marked in the log and in the sidecar
    assert metrics["faults"]["injected"][kind] == injected
    assert read_sidecar(log)["detected"][kind] == injected
    # every row answered; every reply = the float32 reference restarted as the target was
    assert result.missing == 0 and result.aborted is None and metrics["missing"] == 0, result.problems()
    assert metrics["can_agrees_with_float32"], metrics["max_abs_can_minus_float32_C"]
    assert record.rows == clean.rows == ROWS
    diff = np.abs(record.temps - clean.temps)
    gaps = faults["gaps"]
    assert [g["rows"] for g in metrics["faults"]["gaps"]] == [g["rows"] for g in gaps]  # marked in the log
    outside = np.ones(ROWS, dtype=bool)
    for gap in gaps:
        outside[gap["rows"][0]:gap["rows"][1] + 1] = False
    # the bound outside the marked gaps; and in fact every reply is the clean run's (nothing corrupted
    # reached the model, lost rows were retransmitted, a lost target was restored bit for bit)
    assert diff[outside].max() <= 0.005
    assert diff.max() == 0.0
    if kind in ("kill", "freeze"):
        assert len(gaps) == injected + faults["unexplained_heartbeat_losses"] and faults["heartbeat_losses"] >= 1
        assert len(record.segments) == len(gaps) + 1 and record.segments[1].recovery
        # restored from a checkpoint (the state vector echoed in RestoreState), not from rounded temperatures
        assert all(r["checkpoint_row"] is not None and r["restart_row"] == r["checkpoint_row"] + 1
                   for r in faults["recoveries"]), faults["recoveries"]
        assert record.segments[1].state is not None and record.segments[1].initial is None
        # a killed target's journal survives it; the restarted one appends to the same file
        assert faults["target_processes"] == (2 if kind == "kill" else 1)
    else:
        # no gap, so the whole trajectory is the clean run's (a gap here can only be a heartbeat lost to load)
        assert len(gaps) == faults["unexplained_heartbeat_losses"]
        if kind not in ("duplicate", "reply_duplicate"):  # a duplicate loses nothing: nothing to send again
            assert faults["retransmitted_rows"] >= 1
    if kind in ("corrupt", "out_of_range", "wrong_length", "unknown_id"):
        category = {"corrupt": "crc"}.get(kind, kind)
        assert faults["target_rejections"][category] == injected  # none of them reached the model
    if kind.startswith("reply_"):
        # the host refused every faulted reply and reported none of them as a temperature (diff == 0 above); the
        # refusals other than the counter jumps that follow a lost reply are exactly the injected faults
        category = {"corrupt": "crc", "drop": "counter", "duplicate": "counter", "stale_counter": "counter"}.get(
            kind.removeprefix("reply_"), kind.removeprefix("reply_"))
        assert faults["host_rejections_confirming_faults"] == {category: injected}
        assert faults["unexplained_host_rejections"] == {}
        if category != "counter":
            assert faults["host_rejections"][category] == injected


def test_the_twin_answers_a_clean_run_as_the_target_and_the_offline_float32_run(clean):
    """The real-time fault reference (the target's node code fed the logged frames) is the offline float32 run
    where nothing was lost, reply for reply."""
    from bench.analysis.canmetrics import segment_estimates
    from bench.analysis.twin import twin_estimates

    artifact = load_artifact(default_artifact_path())
    twin = twin_estimates(artifact, clean)
    assert clean.answered.all() and np.array_equal(twin, clean.temps)
    offline = segment_estimates(artifact, clean.drive, 0, clean.initial, clean.rows)
    assert np.abs(twin - offline).max() <= 0.005 + 1e-9
