"""The compiled float64 kernel against the plain-numpy statement of the same estimator, and the target's code."""

import numpy as np

from bench.drive.baseline import lti_lptn_estimate
from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps
from bench.model.builder import ModelSpec, physical_block
from bench.model.identify import simulate_float64
from bench.model.runs import model_run
from bench.thermal.parameters import TABLE1_REFINED


def test_kernel_equals_the_numpy_reference(validation_dataset):
    maps = nominal_loss_maps()
    run = model_run(validation_dataset, maps, VIRTUAL_MOTOR, 1.0)
    block = physical_block(ModelSpec("lti-lptn", TABLE1_REFINED, 1.0, "zoh", "physical", maps, VIRTUAL_MOTOR))
    kernel = simulate_float64(block, TABLE1_REFINED, None, run)
    reference = lti_lptn_estimate(validation_dataset, TABLE1_REFINED, maps, VIRTUAL_MOTOR, dt=1.0,
                                  initial=run.initial)
    assert kernel.shape == reference.shape == (7274, 4)
    np.testing.assert_allclose(kernel, reference, rtol=0, atol=1e-9)
