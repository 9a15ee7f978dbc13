"""Estimated cost of one model step on the TMS320F28069M (C28x CPU + FPU32 at 90 MHz), and its memory footprint.

The target process measures its own wall time per step, but a Python process says little about the C28x, so
the timing frames also carry an estimate: the operation count of one step (per model kind and realization,
counted from the code in `target_sim.model` and the kind's own module, `target_sim.modelkinds`) times a
per-operation cycle cost.

Per-operation cost table (CPU cycles, `CYCLES`), single-precision code compiled for FPU32, no TMU (the F28069M
has none):

| operation   | cycles | why                                                                                   |
|-------------|--------|---------------------------------------------------------------------------------------|
| multiply    | 2      | MPYF32: one cycle to issue, two pipeline cycles before the result can be used          |
| add         | 2      | ADDF32/SUBF32 (also compares, min/max and negation): same pipeline as the multiply     |
| divide      | 24     | no divide instruction: EINVF32 estimate + two Newton-Raphson steps + multiply, as TI's  |
|             |        | FPU fastRTS division, call included                                                   |
| exp         | 80     | range reduction + polynomial in FPU32 (fastRTS-style expf), call included               |
| table       | 20     | one axis of a table look-up: clamp, F32TOI32 conversion, index and address arithmetic  |
| load/store  | 1      | MOV32 between memory and an FPU register (coefficients, states, inputs, results)       |
| call        | 40     | function entry/exit and loop set-up, counted once per step and per block               |

Counting rules: a matrix-vector product counts one multiply, one add and two loads per *nonzero* float32 coefficient
(structure a code generator exploits: modal A is diagonal, physical C is the identity), minus one add per row; every
scalar of the formulas in `target_sim.model` and the kinds' modules counts as written; the loss look-up is two axis
searches plus 3 multiplies and 6 adds per table (bilinear); an electrical loss model (losses from the d/q currents
and the speed) counts its formulas as written, a square root as a divide (EISQRTF32 estimate + two Newton-Raphson
steps, as fastRTS's sqrtf), and reads two more interval means (i_d, i_q). The estimate is a model of the compiled
code, not a measurement: it ranks kinds and realizations and shows the order of magnitude (the paper's Table 6
measured 61-161 µs for Simulink-generated code, which adds its own overhead).

Memory: flash = every float32 constant the step needs (4 bytes each) + code (4 bytes per counted operation, a
C28x instruction being 2-4 bytes, plus 1.5 kB of run-time library: division, exp, look-up, CAN glue); RAM =
states, inputs, accumulator and work buffers (4 bytes each) + 512 bytes of stack.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from target_sim.artifact import LPTN_PARAMETERS, ModelArtifact
from target_sim.kinds import MODEL_KINDS
from target_sim.losses import LOSS_KINDS

CPU_HZ = 90e6
OPERATIONS = ("multiply", "add", "divide", "exp", "table", "load_store", "call")
CYCLES: dict[str, int] = {"multiply": 2, "add": 2, "divide": 24, "exp": 80, "table": 20, "load_store": 1,
                          "call": 40}
CODE_BYTES_PER_OPERATION = 4
LIBRARY_CODE_BYTES = 1536
STACK_BYTES = 512
FLOAT_BYTES = 4


@dataclass(frozen=True)
class StepCost:
    """Operation counts of one model step and what they cost on the C28x."""

    operations: dict[str, int]
    blocks: dict[str, dict[str, int]]

    @property
    def cycles(self) -> int:
        return int(sum(CYCLES[op] * n for op, n in self.operations.items()))

    @property
    def exec_time_us(self) -> float:
        """Estimated execution time at 90 MHz."""
        return self.cycles / CPU_HZ * 1e6

    def cpu_load_percent(self, dt_s: float) -> float:
        """Share of the model step Δt the estimated execution takes."""
        return self.exec_time_us / (dt_s * 1e6) * 100.0


@dataclass(frozen=True)
class MemoryEstimate:
    coefficient_bytes: int
    code_bytes: int
    state_bytes: int
    work_bytes: int

    @property
    def flash_bytes(self) -> int:
        return self.coefficient_bytes + self.code_bytes

    @property
    def ram_bytes(self) -> int:
        return self.state_bytes + self.work_bytes + STACK_BYTES


def op_counts(**counts: int) -> Counter:
    """A Counter of operations (`op_counts(multiply=2, add=1)`); an unknown operation is a ValueError."""
    unknown = set(counts) - set(OPERATIONS)
    if unknown:
        raise ValueError(f"unknown operations {sorted(unknown)}")
    return Counter({k: v for k, v in counts.items() if v})


def matvec(matrix: np.ndarray) -> Counter:
    """y = M v over the nonzero coefficients: one multiply-add and two loads each, one add fewer per row."""
    m = np.asarray(matrix)
    nonzero_per_row = np.count_nonzero(m, axis=1)
    nnz = int(nonzero_per_row.sum())
    adds = int(np.maximum(nonzero_per_row - 1, 0).sum())
    return op_counts(multiply=nnz, add=adds, load_store=2 * nnz + m.shape[0])


def loss_model_ops(artifact: ModelArtifact) -> Counter:
    """One evaluation of the artifact's loss model (its kind's own count, `target_sim.losses`)."""
    return LOSS_KINDS[artifact.loss_model].ops(op_counts)


def node_losses_ops() -> Counter:
    """Eqs. 3-8 after the look-up: copper temperature factor, ac/dc split, stator split k_s."""
    copper = op_counts(multiply=2, add=3, divide=1)   # factor = 1 + a(y_w - ref); p_w = dc·f + ac/f
    ratios = op_counts(divide=2)                      # I/I_max, n/n_max
    split = op_counts(multiply=4 + 2, add=3 + 1)      # k_s polynomial; k_s·P_s and (1 - k_s)·P_s
    return copper + ratios + split + op_counts(load_store=8 + 4)


def step_cost(artifact: ModelArtifact) -> StepCost:
    """Operation counts of one step of this artifact's model on the C28x."""
    blocks: dict[str, Counter] = {
        # step entry, read the interval-mean inputs (4, or 6 with the currents), write 4 outputs
        "call": op_counts(call=1, load_store=len(artifact.drive_signals) + 4),
        "losses": loss_model_ops(artifact) + node_losses_ops(),
    }
    blocks.update(MODEL_KINDS[artifact.kind].ops(artifact))   # its own blocks (target_sim.modelkinds)
    total: Counter = Counter()
    for ops in blocks.values():
        total += ops
    return StepCost(operations={op: int(total.get(op, 0)) for op in OPERATIONS},
                    blocks={name: dict(ops) for name, ops in blocks.items()})


def coefficient_count(artifact: ModelArtifact) -> int:
    """float32 constants the step reads: look-up tables and axes (or the electrical loss model's coefficients),
    LPTN parameters, and the kind's own (linear block, sigmoid, 1/C_i)."""
    count = LOSS_KINDS[artifact.loss_model].coefficient_count(artifact)
    count += 3 + len(LPTN_PARAMETERS) + 1             # current_max, alpha_cu, copper reference; speed_max
    return count + MODEL_KINDS[artifact.kind].coefficient_count(artifact)


def memory_estimate(artifact: ModelArtifact, cost: StepCost | None = None) -> MemoryEstimate:
    """Flash (constants + code) and RAM (states + work buffers) of the model on the C28x."""
    cost = cost or step_cost(artifact)
    counted = sum(n for op, n in cost.operations.items() if op != "call")
    states = 4 + 4                                     # x and the previous estimate y
    accumulator = len(artifact.drive_signals) + 1     # interval sums (4, or 6 with the currents) and count
    work = 5 + 4 + 8 + 4                               # table outputs, node losses, input vector u, outputs
    work += MODEL_KINDS[artifact.kind].work_floats(artifact)
    return MemoryEstimate(coefficient_bytes=FLOAT_BYTES * coefficient_count(artifact),
                          code_bytes=CODE_BYTES_PER_OPERATION * counted + LIBRARY_CODE_BYTES,
                          state_bytes=FLOAT_BYTES * (states + accumulator), work_bytes=FLOAT_BYTES * work)
