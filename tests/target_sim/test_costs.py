"""The C28x cost estimate: the table applied to the operation counts, per kind and realization."""

from __future__ import annotations

import numpy as np
import pytest

from target_sim.artifact import load_artifact
from target_sim.costs import CPU_HZ, CYCLES, OPERATIONS, matvec, memory_estimate, step_cost
from target_sim.modelkinds.hammerstein import sigmoid_ops


def test_matvec_counts_nonzero_coefficients():
    m = np.array([[1.0, 0.0, 2.0], [0.0, 0.0, 0.0], [3.0, 4.0, 5.0]])
    ops = matvec(m)
    assert ops["multiply"] == 5
    assert ops["add"] == 1 + 2          # one add fewer than products per row; an empty row adds nothing
    assert ops["load_store"] == 2 * 5 + 3


def test_cycles_are_the_table_applied_to_the_counts(artifacts):
    cost = step_cost(load_artifact(artifacts["lti"]))
    assert set(cost.operations) == set(OPERATIONS)
    assert cost.cycles == sum(CYCLES[op] * n for op, n in cost.operations.items())
    assert cost.exec_time_us == pytest.approx(cost.cycles / CPU_HZ * 1e6)
    assert cost.cpu_load_percent(0.5) == pytest.approx(cost.exec_time_us / 5e5 * 100)
    # the balanced 4x4 / 4x8 / 4x4 block is dense: 64 products, plus the scalar formulas
    assert cost.blocks["linear"]["multiply"] == 16 + 32 + 16
    assert cost.operations["exp"] == 3                 # the three speed-dependent conductances
    assert cost.operations["table"] == 2               # one cell search per axis


def test_kinds_and_realizations_rank_as_their_structure(artifacts):
    costs = {name: step_cost(load_artifact(path)) for name, path in artifacts.items()}
    lti, ham = costs["lti"], costs["hammerstein"]
    sig = sigmoid_ops()
    for op in OPERATIONS:  # the Hammerstein model is the LTI model plus the four sigmoids
        assert ham.operations[op] == lti.operations[op] + sig.get(op, 0), op
    assert ham.operations["exp"] == lti.operations["exp"] + 4
    assert costs["modal"].blocks["linear"]["multiply"] < lti.blocks["linear"]["multiply"]  # diagonal A
    assert costs["pv"].blocks["linear"]["exp"] == 3 and "sources" not in costs["pv"].blocks
    assert 500 < lti.cycles < ham.cycles < 5000


def test_memory_estimate_counts_coefficients_and_states(artifacts):
    lti = load_artifact(artifacts["lti"])
    mem = memory_estimate(lti)
    tables = 5 * 21 * 16
    assert mem.coefficient_bytes >= 4 * (tables + 21 + 16 + 16 + 32 + 16 + 16)
    assert mem.flash_bytes == mem.coefficient_bytes + mem.code_bytes
    assert mem.ram_bytes == mem.state_bytes + mem.work_bytes + 512
    pv = memory_estimate(load_artifact(artifacts["pv"]))
    assert pv.work_bytes > mem.work_bytes           # the PV network is rebuilt in RAM every step
    assert pv.coefficient_bytes < mem.coefficient_bytes  # no A, B, C, C_inv constants
    assert mem.flash_bytes < 1 << 20 and mem.ram_bytes < 1 << 16  # fits TargetInfo's signals
