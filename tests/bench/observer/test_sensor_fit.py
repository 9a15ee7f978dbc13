"""A sensor's lag, gradient and offset estimated from the training files (`bench observer --lag auto --gradient auto
--offset auto`, `bench.observer.measures.sensor_fit`): recovered from a known lag filter applied to a synthetic winding
and yoke pair plus noise, pooled over files of their own start; without a yoke reference the gradient is held at 0
and the estimate says so; a file without the node's reference is one sentence, exit 2."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import pytest

from bench.errors import UsageError
from bench.observer.measures import LAB_MEASUREMENT_KINDS, sensor_fit
from bench.observer.measures.sensor_fit import fit_sensor

TAU_S, GRADIENT, OFFSET_K, NOISE_K = 25.0, -0.12, 0.8, 0.2


class _Data:
    """What the estimate reads of a dataset: columns per name, the sample period, a path."""

    def __init__(self, columns: dict, name: str = "synthetic.csv"):
        self.columns, self.sample_period_s, self.path = columns, 1.0, Path(name)

    def has(self, name):
        return name in self.columns

    def column(self, name):
        return self.columns[name]


def _lagged(x: np.ndarray, tau: float) -> np.ndarray:
    """x through a first-order lag τ at 1 s, settled at x[0], written out (not the module's lfilter)."""
    a = math.exp(-1.0 / tau)
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, len(x)):
        y[k] = a * y[k - 1] + (1 - a) * x[k]
    return y


def _file(rows: int, seed: int, yoke: bool = True, gradient: float = GRADIENT) -> _Data:
    """A winding that steps between load levels (minutes each, so the lag shows), a yoke following it slowly, and a
    stator NTC: the winding moved `gradient` of the way toward the yoke, lagged τ, read OFFSET_K high, noisy and
    rounded to 0.1 K as a real one."""
    rng = np.random.default_rng(seed)
    level = np.repeat(rng.uniform(40.0, 130.0, rows // 120 + 1), 120)[:rows]
    winding = _lagged(level, 60.0) + rng.normal(0, 0.2, rows)
    yoke_true = _lagged(0.6 * level + 15.0, 400.0)
    sensor = _lagged(winding + gradient * (winding - yoke_true), TAU_S) + OFFSET_K
    columns = {"speed_rpm": np.full(rows, 3000.0), "winding_C": np.round(winding, 2),
               "ntc_C": np.round(sensor + rng.normal(0, NOISE_K, rows), 1)}
    if yoke:
        columns["yoke_C"] = np.round(yoke_true + rng.normal(0, 0.15, rows), 2)
    return _Data(columns, f"synthetic_{seed}.csv")


def test_the_estimate_recovers_a_known_lag_gradient_and_offset_pooled_over_files():
    """Two files of their own length and start, each lag settled at its first step: τ within 0.5 %, the gradient
    within 0.003 and the offset within 0.03 K (measured over five seeds: 24.99-25.02 s, -0.1204..-0.1197,
    0.794-0.811 K), the residual the sensor's noise and rounding (0.2 K, 0.03 K)."""
    fit = fit_sensor([_file(3000, 1), _file(2200, 2)], 1.0, "ntc_C")
    assert fit.lag_s == pytest.approx(TAU_S, rel=0.005)
    assert fit.gradient == pytest.approx(GRADIENT, abs=0.003) and fit.offset_C == pytest.approx(OFFSET_K, abs=0.03)
    assert fit.residual_rms_K == pytest.approx(math.hypot(NOISE_K, 0.1 / math.sqrt(12)), rel=0.1)
    assert (fit.steps, fit.files, fit.estimated, fit.notes, fit.warnings) == (
        5200, 2, ("lag", "gradient", "offset"), (), ())


def test_a_given_value_is_held_and_the_others_estimated():
    fit = fit_sensor([_file(3000, 1)], 1.0, "ntc_C", lag_s=10.0)
    assert fit.lag_s == 10.0 and fit.estimated == ("gradient", "offset")
    # the wrong lag leaves a larger residual than the sensor's noise
    assert fit.residual_rms_K > 2 * NOISE_K


def test_no_yoke_reference_holds_the_gradient_at_0_and_says_so():
    fit = fit_sensor([_file(3000, 1, yoke=False, gradient=0.0)], 1.0, "ntc_C")
    assert fit.gradient == 0.0 and fit.estimated == ("lag", "offset")
    assert fit.notes == ("the gradient is held at 0: not every training file has the yoke reference yoke_C",)
    assert fit.lag_s == pytest.approx(TAU_S, rel=0.005) and fit.offset_C == pytest.approx(OFFSET_K, abs=0.03)


def test_a_sensor_without_lag_is_estimated_as_none():
    data = _file(3000, 3)
    data.columns["ntc_C"] = np.round(data.columns["winding_C"] + 0.5, 1)
    fit = fit_sensor([data], 1.0, "ntc_C")
    assert fit.lag_s < 0.2 and fit.gradient == pytest.approx(0.0, abs=0.01)
    assert fit.offset_C == pytest.approx(0.5, abs=0.02)


def test_a_lag_at_the_search_limit_is_a_warning():
    """A sensor far slower than any stator NTC (2000 s) ends the search at its upper limit, and says so."""
    data = _file(3000, 4)
    data.columns["ntc_C"] = np.round(_lagged(data.columns["winding_C"], 2000.0), 1)
    fit = fit_sensor([data], 1.0, "ntc_C", gradient=0.0, offset_C=0.0)
    assert fit.lag_s == pytest.approx(sensor_fit.LAG_MAX_S, rel=0.05)
    assert fit.warnings == (f"the estimate of ntc_C's lag ended at {fit.lag_s:.0f} s, near its upper limit 600 s: the "
                            "sensor does not follow winding_C as a first-order lag, so its estimate and the observer "
                            "built on it are doubtful",)


def test_a_file_without_the_node_reference_is_one_sentence_exit_2():
    data = _file(600, 1)
    del data.columns["winding_C"]
    with pytest.raises(UsageError) as info:
        fit_sensor([data], 1.0, "ntc_C")
    assert str(info.value) == ("synthetic_1.csv has no column 'winding_C' (the node's reference), which estimating "
                               "the sensor's lag, gradient or offset ('auto') needs; map it with --mapping or give "
                               "the values")
    assert info.value.exit_status == 2


def test_bench_observer_builds_the_sensor_from_auto():
    """The lagged-sensor kind's options: `auto` asks for the estimate, which the sensor carries as its calibration
    (and its text); numbers are taken as they are."""
    kind = LAB_MEASUREMENT_KINDS["lagged-sensor"]
    parser = argparse.ArgumentParser()
    kind.add_arguments(parser)
    artifact = argparse.Namespace(dt=1.0)
    data = [_file(3000, 1)]
    sensor = kind.from_arguments(parser.parse_args(["--measure", "ntc_C", "--lag", "auto", "--gradient", "auto",
                                                    "--offset", "auto"]), artifact, data)
    assert sensor.lag_s == pytest.approx(TAU_S, rel=0.005) and sensor.calibration["estimated"] == [
        "lag", "gradient", "offset"]
    assert sensor.calibration_text().startswith("sensor ntc_C: lag 25")
    given = kind.from_arguments(parser.parse_args(["--measure", "ntc_C", "--lag", "25", "--offset", "0.8"]),
                                artifact, data)
    assert (given.lag_s, given.gradient, given.offset_C, given.calibration) == (25.0, 0.0, 0.8, {})
    with pytest.raises(SystemExit):
        parser.parse_args(["--lag", "soon"])
