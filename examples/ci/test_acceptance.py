"""Acceptance suite of the packaged model: the same file against any target.

    pytest examples/ci                                   a Python target the bench starts
    pytest examples/ci --bench-engine firmware           the firmware in the emulated Cortex-M4F
    pytest examples/ci --bench-interface udp_multicast --bench-channel 239.74.163.2
                                                         the target already on that bus (a real ECU)

(from a source tree, without the package installed: add `-p no:bench -p bench.pytest_plugin`). The bench's figures
land in pytest's JUnit XML (`--junitxml`, with `-o junit_family=xunit1`) as properties of each test.
"""

from pathlib import Path

import pytest

HERE = Path(__file__).parent
CRITERIA = HERE / "criteria.toml"
ROWS = 1500           # the first 1500 rows (5 minutes) of the 40 °C validation run
PM_RMSE_LIMIT_C = 3.0


def test_meets_the_acceptance_criteria(thermal_bench):
    result = thermal_bench.run(rows=ROWS, criteria=CRITERIA)
    assert result.clean, result.verdict
    assert result.acceptance.passed, result.acceptance.sentence()
    assert result.passed


def test_magnet_estimate_tracks_the_measurement(thermal_bench):
    result = thermal_bench.run(rows=ROWS)
    accuracy = result.metrics.accuracy
    assert accuracy.rmse_reference.magnet == "measured"
    assert accuracy.rmse_C.magnet < PM_RMSE_LIMIT_C
    assert result.metrics.counts.replies == ROWS


@pytest.mark.bench_engines("python", "firmware")   # kill/freeze need a target the bench owns
def test_survives_a_lost_target(thermal_bench):
    result = thermal_bench.run(rows=600, faults="drop=0.01,kill=1", tolerate_faults=True)
    assert result.passed, result.verdict
    faults = result.summary.faults
    assert faults.injected["kill"] == 1 and faults.undetected == 0


@pytest.mark.bench_engines("firmware")
def test_firmware_step_cycles_are_counted(thermal_bench):
    result = thermal_bench.run(rows=600, criteria=CRITERIA)
    (cycles,) = [c for c in result.acceptance.checks if c.kind == "cycles"]
    assert cycles.source.startswith("counted"), cycles.source
    assert cycles.passed, cycles.message
