"""Where single precision costs: the float32 error budget of a model artifact over a whole run.

The model runs with float32 in one part at a time and float64 everywhere else, and each part's largest
contribution to the output error (|y_part - y_float64| per node over the run) is reported, beside the target's
own all-float32 run. The parts, in the order a step runs them:

- `inputs`: the float32 interval means of the drive samples (the accumulator) instead of float64 means;
- `lookup`: the loss look-up (bilinear tables, or the electrical loss formulas) in float32;
- `corrections`: the copper temperature correction and the stator split (eqs. 3-8) in float32;
- `sigmoid`: the Hammerstein input nonlinearity in float32, with the firmware's float32 exp;
- `sources`: the temperature sources (eqs. 9-18, with the convection exp) in float32;
- `coefficients`: A, B, C and C⁻¹ rounded to float32, the arithmetic in float64;
- `update`: every product and sum of x <- A x + B u rounded to float32 (coefficients in float64); for the delta
  realization those of the increment Δ·(A x + B ũ) and of ũ's sources relative to the reference;
- `state`: the state vector stored in float32 after each update (delta: the sum x + increment);
- `output`: every product and sum of y = C x (delta: + r) rounded to float32.

`update`, `state` and `output` round float64 results to float32 operation by operation, which is what float32
arithmetic on float32 operands gives (a product of two float32 values is exact in float64); so with every part in
float32 the run is the target's, up to the rare double rounding of a sum (`all` checks it against the target's own
code). The reference is the same code in float64 from the artifact's float64 coefficients.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from bench.thermal.excitation import interval_means
from target_sim.artifact import OUTPUTS as NODES
from target_sim.artifact import ModelArtifact
from target_sim.kinds import MODEL_KINDS
from target_sim.model import Float32Estimator, InputAccumulator, run_offline

PARTS = ("inputs", "lookup", "corrections", "sigmoid", "sources", "coefficients", "update", "state", "output")
F32, F64 = np.float32, np.float64


def rounded(values: np.ndarray) -> np.ndarray:
    """float64 values rounded to float32 and back."""
    return np.asarray(values, dtype=F64).astype(F32).astype(F64)


def matvec_rounded(matrix: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """M v in the target's order (fmath.matvec) with every product and partial sum rounded to float32."""
    products = rounded(matrix * vector)
    acc = products[:, 0]
    for j in range(1, products.shape[1]):
        acc = rounded(acc + products[:, j])
    return acc


def matvec64(matrix: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """M v in the target's order in float64."""
    products = matrix * vector
    acc = products[:, 0]
    for j in range(1, products.shape[1]):
        acc = acc + products[:, j]
    return acc


class MixedPrecisionEstimator:
    """The target's step with float32 in the given parts and float64 elsewhere (LTI LPTN and Hammerstein)."""

    def __init__(self, artifact: ModelArtifact, float32_parts: Sequence[str]):
        unknown = set(float32_parts) - set(PARTS)
        if unknown:
            raise ValueError(f"unknown parts {sorted(unknown)}; the parts are {', '.join(PARTS)}")
        if not MODEL_KINDS[artifact.kind].linear_block:
            raise ValueError("the error budget covers the LTI LPTN and Hammerstein kinds (the PV LPTN has no fixed "
                             "linear block)")
        self.parts = frozenset(float32_parts)
        self.models = {F32: Float32Estimator(artifact, F32), F64: Float32Estimator(artifact, F64)}
        source = self.models[F32 if "coefficients" in self.parts else F64].part   # the kind's linear block
        self.a, self.b, self.c, self.c_inv = (np.asarray(m, dtype=F64) for m in
                                              (source.a, source.b, source.c, source.c_inv))
        self.hammerstein = MODEL_KINDS[artifact.kind].input_nonlinearity
        self.delta = source.delta
        self.reference = float(source.reference)
        self.dt = float(self.models[F32 if "update" in self.parts else F64].dt)
        self.x = np.zeros(4)
        self.y = np.zeros(4)

    def _model(self, part: str) -> Float32Estimator:
        model = self.models[F32 if part in self.parts else F64]
        model.y = self.y.astype(model.f)      # the previous estimate, as that precision holds it
        return model

    def reset(self, temperatures: Sequence[float]) -> None:
        self.y = np.asarray(temperatures, dtype=F64).copy()
        self.x = matvec64(self.c_inv, self.y - self.reference)
        if "state" in self.parts:
            self.x = rounded(self.x)

    def step(self, torque, speed, coolant, ambient, i_d=0.0, i_q=0.0) -> np.ndarray:
        lookup = np.asarray(self._model("lookup").loss_lookup(torque, speed, i_d, i_q), dtype=F64)
        model = self._model("corrections")
        losses = np.asarray(model.corrected_losses(lookup.astype(model.f), speed), dtype=F64)
        if self.hammerstein:
            model = self._model("sigmoid")
            losses = np.asarray(model.part.input_nonlinearity(losses.astype(model.f)), dtype=F64)
        sources = np.asarray(self._model("sources").part.temperature_sources(speed, coolant, ambient), dtype=F64)
        update = "update" in self.parts
        keep = rounded if update else np.asarray
        product = matvec_rounded if update else matvec64
        if self.delta:   # x <- x + Δ·(A x + B ũ), the sources relative to r
            u = np.concatenate([losses, keep(sources - self.reference)])
            x = self.x + keep(self.dt * keep(product(self.a, self.x) + product(self.b, u)))
        else:
            x = keep(product(self.a, self.x) + product(self.b, np.concatenate([losses, sources])))
        self.x = rounded(x) if (update or "state" in self.parts) else x
        output = "output" in self.parts
        y = matvec_rounded(self.c, self.x) if output else matvec64(self.c, self.x)
        self.y = (rounded(y + self.reference) if output else y + self.reference) if self.delta else y
        return self.y.copy()


def step_inputs(artifact: ModelArtifact, drive: np.ndarray, float32_means: bool) -> np.ndarray:
    """The inputs of every model step: the target's float32 accumulator, or float64 interval means."""
    if not float32_means:
        return interval_means(drive, artifact.data_sample_period, artifact.dt)
    acc = InputAccumulator(artifact.data_sample_period, artifact.dt, drive.shape[1])
    out = [m for row, sample in enumerate(np.asarray(drive, dtype=F32)) if (m := acc.add(row, sample)) is not None]
    return np.asarray(out, dtype=F64)


def run_mixed(artifact: ModelArtifact, drive: np.ndarray, initial, float32_parts: Sequence[str]) -> np.ndarray:
    """(steps, 4) outputs with float32 in `float32_parts`."""
    model = MixedPrecisionEstimator(artifact, float32_parts)
    model.reset(initial)
    inputs = step_inputs(artifact, drive, "inputs" in float32_parts)
    return np.array([model.step(*row) for row in inputs])


@dataclass(frozen=True)
class BudgetRow:
    part: str
    max_abs_C: dict[str, float]      # per node, over the run

    @property
    def worst_C(self) -> float:
        return max(self.max_abs_C.values())


def error_budget(artifact: ModelArtifact, drive: np.ndarray, initial,
                 progress: Callable[[str], None] | None = None) -> tuple[list[BudgetRow], dict]:
    """(one row per part, then `all` and `target`), {"steps", "all_vs_target_max_abs_C"}."""
    reference = run_mixed(artifact, drive, initial, ())
    rows = []
    for part in (*PARTS, "all"):
        if part == "sigmoid" and not MODEL_KINDS[artifact.kind].input_nonlinearity:
            continue
        if progress:
            progress(part)
        parts = PARTS if part == "all" else (part,)
        out = run_mixed(artifact, drive, initial, parts)
        rows.append(BudgetRow(part, _max_abs(out, reference)))
        if part == "all":
            all_parts = out
    _, target = run_offline(artifact, drive, initial)
    target = target.astype(F64)
    rows.append(BudgetRow("target", _max_abs(target, reference)))
    return rows, {"steps": len(reference), "all_vs_target_max_abs_C": float(np.max(np.abs(all_parts - target)))}


def _max_abs(out: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    diff = np.abs(out - reference)
    return {node: float(np.max(diff[:, i])) if np.all(np.isfinite(diff[:, i])) else float("inf")
            for i, node in enumerate(NODES)}
