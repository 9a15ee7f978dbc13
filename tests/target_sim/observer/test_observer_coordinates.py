"""The observer's node coordinates (target_sim.observer.coordinates): the fixed-order float64 inverse and the
transforms the filter's constants come from."""

from __future__ import annotations

import numpy as np
import pytest

from target_sim.observer.coordinates import NodeCoordinates, inverse


def test_the_inverse_is_the_inverse_and_the_same_bits_every_time():
    rng = np.random.default_rng(4)
    m = rng.standard_normal((4, 4)) + 4 * np.eye(4)
    inv = inverse(m)
    assert np.allclose(inv @ m, np.eye(4), atol=1e-13)
    assert np.array_equal(inv, inverse(m.copy()))


def test_a_singular_output_matrix_is_refused_in_one_sentence():
    with pytest.raises(ValueError, match="the output matrix C is singular"):
        inverse(np.array([[1.0, 2.0], [2.0, 4.0]]))


def test_the_transforms_keep_the_extra_states_and_invert_each_other():
    rng = np.random.default_rng(7)
    c = rng.standard_normal((4, 4)) + 3 * np.eye(4)
    coords = NodeCoordinates(c, 6)
    m = rng.standard_normal((6, 6))
    p = m @ m.T
    node = coords.covariance(p, np.float64)
    assert np.array_equal(node, node.T)
    assert np.allclose(node[4:, 4:], p[4:, 4:])                   # the extra states are not transformed
    assert np.allclose(coords.state_covariance(node), p, atol=1e-12)
    q_nodes = np.array([1e-3, 2e-4, 3e-4, 4e-4, 1e-4, 5e-2])
    q_state = coords.state_covariance(np.diag(q_nodes))
    assert coords.process_noise_error(q_state, q_nodes) < 1e-12
    assert coords.process_noise_error(np.diag(q_nodes), q_nodes) > 1e-3
    a = rng.standard_normal((4, 4))
    assert np.allclose(coords.similar(a, np.float64) @ c, c @ a)
