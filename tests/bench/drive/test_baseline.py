from __future__ import annotations

import numpy as np

from bench.drive.baseline import baseline_rmse, compared_samples, lti_lptn_estimate
from bench.drive.dataset import load_dataset, write_dataset
from bench.drive.generate import generate
from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps
from bench.drive.plant import NO_EFFECTS
from bench.thermal.excitation import model_step_of_sample
from bench.thermal.parameters import TABLE1_REFINED

MAPS = nominal_loss_maps()


def test_compared_samples_are_the_ones_at_the_end_of_each_step(datasets):
    d = datasets[40]
    k, n = compared_samples(d, 14548, 0.5)
    assert len(k) == 7274 and k[0] == 1 and n[0] == 5        # t = 1.0 s
    np.testing.assert_array_equal(d.time_s[n], (k + 1) * 0.5)
    np.testing.assert_array_equal(model_step_of_sample(n, 0.2, 0.5) - 1, k)


def test_lti_lptn_with_nominal_maps_is_visibly_wrong_but_not_absurd(datasets):
    d = datasets[40]
    est = lti_lptn_estimate(d, TABLE1_REFINED, MAPS, VIRTUAL_MOTOR)
    assert est.shape == (14548, 4)
    r = baseline_rmse(d, est)
    assert 2.5 < r["winding_rmse_C"] < 16.0       # 13.4 °C with the default effects (README)
    assert 0.6 < r["pm_rmse_C"] < 5.0             # 3.9 °C with the default effects
    assert r["winding_max_abs_C"] > 5.0            # visibly wrong somewhere: the hot preheat
    assert r["winding_mean_error_C"] < -1.0        # it misses losses, so it runs cold


def test_without_the_true_effects_the_same_estimator_is_close(tmp_path):
    g = generate(40.0, seed=5, effects=NO_EFFECTS)
    path = tmp_path / "nominal.csv"
    write_dataset(path, g.columns, {"seed": 5, "coolant_setpoint_C": 40.0})
    d = load_dataset(path)
    r = baseline_rmse(d, lti_lptn_estimate(d, TABLE1_REFINED, MAPS, VIRTUAL_MOTOR))
    assert r["winding_rmse_C"] < 1.0 and r["pm_rmse_C"] < 0.5
