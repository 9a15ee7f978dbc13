"""The Table 5 analogue: LTI LPTN vs Hammerstein at several Δt on the 40 °C run, in float64 and float32.

At the artifact's own Δt its Hammerstein model is used as is; at every other Δt the Hammerstein model is
refitted (Levenberg-Marquardt on the 20/60 °C runs, poles of the artifact's LPTN discretized at that Δt), as the
paper did for its Table 5. Float32 numbers come from the target's own code on artifacts built in memory.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from bench.drive.dataset import Dataset
from bench.model.artifact_eval import ArtifactEvaluation, evaluate_artifact
from bench.model.artifact_values import artifact_loss_model, artifact_parameters, shift_form
from bench.model.builder import ModelSpec, SigmoidInputs, artifact_content, physical_block
from bench.model.hammerstein_fit import fit_hammerstein
from bench.model.identify import IDENTIFICATION_COOLANTS, VALIDATION_COOLANT, prepare_runs
from bench.thermal import portable
from bench.thermal.realizations import Realization
from target_sim.artifact import ModelArtifact, seal, verify
from target_sim.kinds import is_delta

METRIC_MODELS = ("lti-lptn", "hammerstein")


def physical_from_artifact(artifact: ModelArtifact) -> Realization:
    """The artifact's linear block brought back to nodal coordinates (x_physical = C z)."""
    a, b, c = shift_form(artifact)
    mm = portable.matmul
    return Realization("physical", mm(c, a, portable.inv(c)), mm(c, b), np.eye(4), np.zeros((4, 8)))


def sigmoid_from_artifact(artifact: ModelArtifact) -> SigmoidInputs:
    keys = ("scale_W", "weight", "bias", "gain", "linear", "offset")
    return SigmoidInputs(*(artifact.array("input_nonlinearity", k, dtype=np.float64) for k in keys))


@dataclass(frozen=True)
class Table5Row:
    model: str
    dt: float
    realization: str
    evaluation: ArtifactEvaluation

    def as_dict(self) -> dict:
        ev = self.evaluation
        return {"model": self.model, "dt": self.dt, "realization": self.realization,
                "float64": ev.metrics["float64"], "float32": ev.metrics["float32"],
                "max_abs_f32_minus_f64_C": ev.max_abs_f32_minus_f64}


def spec_at(artifact: ModelArtifact, kind: str, dt: float, realization: str, block: Realization | None = None,
            sigmoid: SigmoidInputs | None = None) -> ModelSpec:
    maps, motor = artifact_loss_model(artifact)
    return ModelSpec(kind, artifact_parameters(artifact), dt, "zoh", realization, maps, motor,
                     data_sample_period_s=artifact.data_sample_period, sigmoid=sigmoid, linear_block=block,
                     provenance={"derived_from": artifact.sha256}, reference_C=reference_of(artifact))


def reference_of(artifact: ModelArtifact) -> float:
    """The delta realization's reference temperature of the artifact (0 for another realization)."""
    if not is_delta(artifact.kind, artifact.realization):
        return 0.0
    return float(artifact.array("linear_block", "reference_C", dtype=np.float64))


def in_memory(spec: ModelSpec) -> ModelArtifact:
    return verify(seal(artifact_content(spec)))


def hammerstein_models(artifact: ModelArtifact, datasets: dict[int, Dataset], dts: Sequence[float],
                       progress: Callable[[str], None] | None = None) -> dict[float, tuple[Realization, SigmoidInputs]]:
    """The artifact's Hammerstein model at its own Δt, refitted by LM at every other Δt."""
    models = {}
    for dt in dts:
        if np.isclose(dt, artifact.dt):
            models[dt] = physical_from_artifact(artifact), sigmoid_from_artifact(artifact)
            continue
        if progress:
            progress(f"refitting the Hammerstein model at dt = {dt:g} s")
        maps, motor = artifact_loss_model(artifact)
        runs = prepare_runs([datasets[c] for c in IDENTIFICATION_COOLANTS], maps, motor, dt)
        base = physical_block(spec_at(artifact, "lti-lptn", dt, "physical"))
        fit = fit_hammerstein(base, artifact_parameters(artifact), runs)
        models[dt] = fit.model.block, fit.model.sigmoid
    return models


def table5(artifact: ModelArtifact, datasets: dict[int, Dataset], models: dict, realization: str) -> list[Table5Row]:
    """Rows for LTI LPTN and Hammerstein at each Δt of `models` (from `hammerstein_models`)."""
    validation = datasets[VALIDATION_COOLANT]
    rows = []
    for dt, (block, sigmoid) in models.items():
        lti = in_memory(spec_at(artifact, "lti-lptn", dt, realization))
        ham = in_memory(spec_at(artifact, "hammerstein", dt, realization, block, sigmoid))
        rows.append(Table5Row("lti-lptn", dt, realization, evaluate_artifact(lti, validation)))
        rows.append(Table5Row("hammerstein", dt, realization, evaluate_artifact(ham, validation)))
    return rows


def realization_comparison(artifact: ModelArtifact, dataset: Dataset, models: dict,
                           realizations: Sequence[str] = ("original", "balanced")) -> dict:
    """{(realization, dt): evaluation} of the Hammerstein models in each realization (Figs. 6 and 7)."""
    return {(name, dt): evaluate_artifact(in_memory(spec_at(artifact, "hammerstein", dt, name, block, sigmoid)),
                                          dataset)
            for dt, (block, sigmoid) in models.items() for name in realizations}
