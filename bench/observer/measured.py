"""The lab side of an artifact's observer measurements (`bench.observer.measures` kinds read back from the
section's entries): their columns, the nodes they read, their stored variance scales.
"""

from __future__ import annotations

from bench.observer.measures import LAB_MEASUREMENT_KINDS
from target_sim.artifact import OUTPUTS, ModelArtifact
from target_sim.observer import measurement_entries


def lab_measurements(artifact: ModelArtifact) -> tuple:
    """The lab side of the artifact's measurements (with their tuned variances folded in: R scale 1)."""
    return tuple(LAB_MEASUREMENT_KINDS[e["kind"]].from_entry(e, artifact.dt)
                 for e in measurement_entries(artifact.content["observer"]))


def r_scales(artifact: ModelArtifact) -> list[float]:
    """Each measurement's variance scale as stored (a sensor's R; 1 for the flux linkage, its R in its arrays)."""
    return [LAB_MEASUREMENT_KINDS[e["kind"]].stored_r(e) for e in measurement_entries(artifact.content["observer"])]


def measurement_of(artifact: ModelArtifact):
    """The first measurement (lab side)."""
    return lab_measurements(artifact)[0]


def measurement_columns(artifact: ModelArtifact) -> list[str]:
    """The raw columns of every measurement, in the order the observer takes them per row."""
    return [c for m in lab_measurements(artifact) for c in m.columns]


def measured_nodes_of(artifact: ModelArtifact) -> list[str]:
    """The nodes the observer's measurements read (their errors are not estimates)."""
    return sorted({m.node for m in lab_measurements(artifact)}, key=OUTPUTS.index)
