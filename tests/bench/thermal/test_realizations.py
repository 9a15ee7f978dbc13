import numpy as np
import pytest

from bench.thermal.excitation import interval_means, synthetic_lti_inputs
from bench.thermal.parameters import TABLE1_REFINED
from bench.thermal.precision import analyse, discrete_lptn, output_error_f32
from bench.thermal.realizations import (
    REALIZATIONS,
    balance_by_eigendecomposition,
    condition_bound,
    condition_number,
    gramians,
    hankel_singular_values,
    realize,
)
from bench.thermal.simulate import simulate

DTS = [0.5, 1.0, 2.0, 4.0]
TABLE3_ORIGINAL = {"zoh": [32.6076, 32.7589, 33.3686, 35.8775], "tustin": [32.6076, 32.7595, 33.3773, 36.0291]}
PAPER_BALANCED_ZOH = [1.0711, 1.1457, 1.3133, 1.7202]


@pytest.fixture(scope="module")
def samples():
    return synthetic_lti_inputs()


@pytest.fixture(scope="module")
def rows(samples):
    out = {}
    for method in ("zoh", "tustin"):
        for dt in DTS:
            base = discrete_lptn(TABLE1_REFINED, dt, method)
            inputs = interval_means(samples, 0.2, dt)
            for name in REALIZATIONS:
                out[method, dt, name] = analyse(realize(base, name, dt), method, dt, inputs)
    return out


@pytest.mark.parametrize("method", ["zoh", "tustin"])
def test_original_condition_numbers_equal_table3(rows, method):
    for dt, expected in zip(DTS, TABLE3_ORIGINAL[method], strict=True):
        assert float(f"{rows[method, dt, 'original'].cond:.4g}") == float(f"{expected:.4g}")


@pytest.mark.parametrize("method", ["zoh", "tustin"])
def test_original_is_unstable_in_float32_at_half_a_second_and_its_error_grows(rows, samples, method):
    row = rows[method, 0.5, "original"]
    assert not row.stable_f32 and row.eig_f32_abs[0] > 1.0
    err = output_error_f32(realize(discrete_lptn(TABLE1_REFINED, 0.5, method), "original"),
                           interval_means(samples, 0.2, 0.5))
    quarters = [np.max(q) for q in np.array_split(err, 4)]
    assert quarters[0] < quarters[1] < quarters[2] <= quarters[3]
    assert quarters[3] > 1e6 * max(quarters[0], 1e-3)


@pytest.mark.parametrize("name", ["balanced", "modal", "delta"])
@pytest.mark.parametrize("method", ["zoh", "tustin"])
def test_well_conditioned_realizations_survive_float32(rows, method, name):
    for dt in DTS:
        row = rows[method, dt, name]
        np.testing.assert_allclose(row.eig_f32_abs, sorted(np.abs(row.eig_f64), reverse=True), atol=1e-6)
        assert row.stable_f32 and not row.diverged_f32
        assert row.max_output_error_f32_C < 0.005


def test_modal_attains_the_bound_and_balanced_beats_the_paper(rows):
    for method in ("zoh", "tustin"):
        for dt in DTS:
            base = discrete_lptn(TABLE1_REFINED, dt, method)
            bound = condition_bound(base.a)
            assert rows[method, dt, "modal"].cond == pytest.approx(bound, rel=1e-9)
            assert rows[method, dt, "physical"].cond >= bound * (1 - 1e-12)
    for dt, paper in zip(DTS, PAPER_BALANCED_ZOH, strict=True):
        assert rows["zoh", dt, "balanced"].cond <= paper
    modal_zoh = [rows["zoh", dt, "modal"].cond for dt in DTS]
    np.testing.assert_allclose(modal_zoh, [1.0658, 1.1360, 1.2905, 1.6653], atol=6e-5)


@pytest.mark.parametrize("method", ["zoh", "tustin"])
def test_every_realization_has_the_same_input_output_behaviour(samples, method):
    base = discrete_lptn(TABLE1_REFINED, 1.0, method)
    inputs = interval_means(samples, 0.2, 1.0)[:2000]
    reference = simulate(base, inputs)
    for name in REALIZATIONS:
        y = simulate(realize(base, name, 1.0), inputs)
        np.testing.assert_allclose(y, reference, rtol=1e-7, atol=1e-7 * np.abs(reference).max())


def test_balanced_gramians_are_equal_and_diagonal():
    bal = realize(discrete_lptn(TABLE1_REFINED, 0.5, "zoh"), "balanced")
    wc, wo = gramians(bal)
    hsv = hankel_singular_values(bal)
    np.testing.assert_allclose(wc, np.diag(hsv), atol=1e-9 * hsv[0])
    np.testing.assert_allclose(wo, np.diag(hsv), atol=1e-9 * hsv[0])


def test_paper_balancing_method_agrees_with_square_root_method():
    base = discrete_lptn(TABLE1_REFINED, 2.0, "zoh")
    sqrt_bal, eig_bal = realize(base, "balanced"), balance_by_eigendecomposition(base)
    wc, wo = gramians(eig_bal)
    np.testing.assert_allclose(np.diag(wc), np.diag(wo), rtol=1e-6)
    np.testing.assert_allclose(np.sort(np.diag(wc))[::-1], hankel_singular_values(base), rtol=1e-6)
    # Balanced realizations are unique up to signs of the states: A agrees entry by entry in magnitude.
    np.testing.assert_allclose(np.abs(eig_bal.a), np.abs(sqrt_bal.a), atol=1e-8)
    assert condition_number(eig_bal.a) == pytest.approx(condition_number(sqrt_bal.a), rel=1e-8)


def test_gramians_and_hankel_singular_values_agree_with_python_control():
    """python-control's discrete Gramians (slycot SB03MD) against ours; its hsvd/balred are continuous-only."""
    control = pytest.importorskip("control")
    pytest.importorskip("slycot")
    base = discrete_lptn(TABLE1_REFINED, 0.5, "zoh")
    sys = control.ss(base.a, base.b, base.c, base.d, 0.5)
    wc, wo = gramians(base)
    np.testing.assert_allclose(control.gram(sys, "c"), wc, rtol=1e-9, atol=1e-12 * np.abs(wc).max())
    np.testing.assert_allclose(control.gram(sys, "o"), wo, rtol=1e-9, atol=1e-12 * np.abs(wo).max())
    their_hsv = np.sort(np.sqrt(np.linalg.eigvals(control.gram(sys, "c") @ control.gram(sys, "o")).real))
    np.testing.assert_allclose(their_hsv[::-1], hankel_singular_values(realize(base, "balanced")), rtol=1e-8)


def test_the_delta_form_is_the_most_accurate_in_float32_at_every_step(rows):
    """Its coefficients carry A - I at full precision: at Δt 0.5 s the all-float32 error falls from 4.5e-4 °C
    (balanced) to 6.1e-5 °C on the synthetic excitation."""
    for method in ("zoh", "tustin"):
        for dt in DTS:
            others = min(rows[method, dt, name].max_output_error_f32_C for name in ("physical", "balanced", "modal"))
            assert rows[method, dt, "delta"].max_output_error_f32_C < others, (method, dt)
    assert rows["zoh", 0.5, "delta"].max_output_error_f32_C < 0.2 * rows["zoh", 0.5, "balanced"].max_output_error_f32_C
