"""The filter's time update: F of the step just taken, in node coordinates and augmented (C: obs_predict).

The block's one-step map is x <- F x + (inputs), F = A + B_s G C in shift form and F = I + Δ·(A + B_s G C) in delta
form, G = d(sources)/d(estimate) at the step's speed and coolant (the temperature sources of eqs. 9-18 are linear in
the previous estimate; `LinearBlockPart.source_jacobian`). The losses' dependence on the winding estimate (eqs. 3-5)
is left out of F. In node coordinates (`target_sim.observer.coordinates`) the constants are hoisted once, and F is
formed over its structural nonzeros (-0 elsewhere), which the UD form's schedules are built for.
"""

from __future__ import annotations

import numpy as np

from target_sim.artifact import OUTPUTS
from target_sim.model import Float32Estimator
from target_sim.modelkinds.lti_lptn import SOURCE_JACOBIAN_NONZERO
from target_sim.observer.coordinates import NodeCoordinates
from target_sim.observer.layout import AugmentedLayout
from target_sim.observer.ud_structure import NEG_ZERO, masked_matmul, pattern_product, structural


class Transition:
    """F's constants in node coordinates, hoisted: C (I + Δ A) C⁻¹ and Δ C B_s (shift form: C A C⁻¹ and C B_s), the
    bias's column C Δ B; and F's structural nonzeros (`nonzero`): those of the first, of (C B_s) J from the
    Jacobian's pattern, the bias's column, each lag row's sees·F[:4]."""

    def __init__(self, est: Float32Estimator, coordinates: NodeCoordinates, layout: AugmentedLayout):
        part, k, n, f = est.part, len(OUTPUTS), layout.n, est.f
        self.part, self.layout, self.n, self.f = part, layout, n, f
        dt = float(est.dt)
        a64 = part.a.astype(np.float64)
        a_step = coordinates.similar(np.eye(k) + dt * a64 if part.delta else a64, f)
        self.b_sources = coordinates.outputs_of(part.b[:, 4:].astype(np.float64) * (dt if part.delta else 1.0), f)
        self.b_sources_nonzero = self.b_sources != 0
        self.jacobian_nonzero = np.zeros((4, 4), dtype=bool)
        for source, node in SOURCE_JACOBIAN_NONZERO:
            self.jacobian_nonzero[source, node] = True
        self.bj_nonzero = pattern_product(self.b_sources_nonzero, self.jacobian_nonzero)
        self.a_step = structural(a_step, a_step != 0)
        self.bias_node = coordinates.outputs_of(layout.bias_column.astype(np.float64)[:, None], f)[:, 0]
        nonzero = np.zeros((n, n), dtype=bool)
        nonzero[:k, :k] = (self.a_step != 0) | self.bj_nonzero
        if layout.bias_index >= 0:
            nonzero[:k, layout.bias_index] = self.bias_node != 0
            nonzero[layout.bias_index, layout.bias_index] = True
        for lag, sees_nonzero in zip(layout.lag_index, layout.sees_nonzero, strict=True):
            if lag >= 0:
                nonzero[lag] = pattern_product(sees_nonzero[None, :], nonzero[:k])[0]
                nonzero[lag, lag] = True
                if layout.bias_output >= 0 and sees_nonzero[layout.bias_output]:
                    nonzero[lag, layout.bias_index] = True
        self.nonzero = nonzero

    def matrix(self) -> np.ndarray:
        """F of the step just taken, over its structural nonzeros (-0 elsewhere): the block's C (I + Δ A) C⁻¹ +
        (Δ C B_s) J (shift form: C A C⁻¹ + (C B_s) J), J the sources' Jacobian at the step's gains; the bias's column
        C Δ B; each lag row (1 - a)·(sees·F[:4]) and a on its diagonal."""
        f, k, layout = self.f, len(OUTPUTS), self.layout
        bj, _ = masked_matmul(self.b_sources, self.part.source_jacobian(), self.b_sources_nonzero,
                              self.jacobian_nonzero)
        block = self.a_step + bj                    # A's structural zeros are -0: the sum is bj there
        if self.n == k:
            return block
        full = np.full((self.n, self.n), f(NEG_ZERO), dtype=f)
        full[:k, :k] = block
        if layout.bias_index >= 0:
            full[:k, layout.bias_index] = structural(self.bias_node, self.bias_node != 0)
            full[layout.bias_index, layout.bias_index] = f(1.0)
        for m, lag, sees_nonzero in zip(layout.measurements, layout.lag_index, layout.sees_nonzero, strict=True):
            if lag >= 0:
                row, _ = masked_matmul(m.sees[None, :], full[:k], sees_nonzero[None, :], self.nonzero[:k])
                full[lag] = (f(1.0) - m.lag_pole) * row[0]
                if layout.bias_output >= 0 and sees_nonzero[layout.bias_output]:   # it sees the output bias too
                    full[lag, layout.bias_index] = (f(1.0) - m.lag_pole) * m.sees[layout.bias_output]
                full[lag, lag] = m.lag_pole
        return full
