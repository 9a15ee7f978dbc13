"""`bench observer` says when its tuning ended at a limit (`tuning_warnings`): a q or R within
`LIMIT_MARGIN_DECADES` of its search bound (the `nodes` criterion's R upper end: the filter switched off), or the
--evaluations cap reached before the search converged; a tuning inside its bounds says nothing."""

from __future__ import annotations

import numpy as np
import pytest

from bench.drive.dataset import load_dataset
from bench.model.default import default_artifact_path
from bench.observer.measures.lagged_sensor import Sensor
from bench.observer.tune import ObserverFit, tune_observer, tuning_warnings
from target_sim.artifact import load_artifact

SENSOR = Sensor("winding", "ntc_C", lag_s=25.0)


def _fit(q, r, criterion="nodes", **kw) -> ObserverFit:
    return ObserverFit((SENSOR,), np.array(q, dtype=float), np.array(r, dtype=float), None, criterion, 0.0,
                           0.0, 0, 166, **kw)


def test_a_tuning_inside_its_bounds_says_nothing():
    assert tuning_warnings(_fit([1e-8, 3e-8, 2e-8, 4e-10, 1e-3], [5.5e4])) == []
    assert tuning_warnings(_fit([1e-4] * 5, [100.0], "magnet")) == []


def test_the_filter_switched_off_is_said():
    """What a user found on the IPM example with --criterion nodes: R at its upper limit, every q at its lower one
    (the recorded run, docs/results/observer.json)."""
    assert tuning_warnings(_fit([1e-12] * 4 + [1e3], [1e6])) == [
        "the tuning ended at R scale 1e+06 for ntc_C, its upper limit: the filter barely uses ntc_C, so the observer "
        "is close to the open-loop model; the nodes criterion found no correction with it that helps",
        "the tuning ended at q 1e-12 °C² per step for every node, its lower limit: the filter takes the model as "
        "exact and corrects no node, so the observer is the open-loop model"]


@pytest.mark.parametrize(("q", "r", "criterion", "said"), [
    # the magnet criterion's R bound is LOG10_BOUNDS' (1e3), half a decade within it is at the limit
    ([1e-4] * 5, [400.0], "magnet", "the tuning ended at R scale 400 for ntc_C, its upper limit"),
    ([1e-4] * 5, [3e-12], "magnet", "the tuning ended at R scale 3e-12 for ntc_C, its lower limit: the filter takes "
                                    "ntc_C as exact"),
    ([1e-4, 1e-4, 2e-12, 1e-4, 1e-4], [0.1], "nodes", "the tuning ended at q 1e-12 °C² per step for the tooth node, "
                                                      "its lower limit: the filter takes its model as exact"),
    ([500.0, 1e-4, 1e-4, 900.0, 1e-4], [0.1], "nodes", "the tuning ended at q 1e+03 °C² per step for the yoke and "
                                                       "magnet nodes, its upper limit: the filter drops their model"),
])
def test_each_limit_is_one_sentence(q, r, criterion, said):
    (warning,) = tuning_warnings(_fit(q, r, criterion))
    assert warning.startswith(said) and "\n" not in warning


def test_the_evaluation_cap_is_said(small_dataset):
    """A search stopped by --evaluations before it converged is marked so, and said; one with room converges."""
    artifact = load_artifact(default_artifact_path("hammerstein"))
    dataset = load_dataset(small_dataset)
    fit = tune_observer(artifact, [dataset], [Sensor("winding", "winding_C")], "magnet", max_evaluations=4)
    assert not fit.converged
    assert tuning_warnings(fit)[-1] == (
        f"the tuning stopped after {fit.evaluations} filter runs, at its cap (--evaluations), before the search "
        "converged: the observer may be far from the criterion's best; raise --evaluations")
    assert _fit([1e-4] * 5, [0.1]).converged        # the default of a fit record: no cap reached
