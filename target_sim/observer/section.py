"""The artifact's observer section as the target reads it: whether a model has one, its measurements (version 2
entries, `target_sim.observer.measurements`), its bias input and its state count.
"""

from __future__ import annotations

import numpy as np

from target_sim.artifact import (
    BIAS_KINDS,
    OUTPUTS,
    ModelArtifact,
    encode_array,
    observer_state_count,
    section_version,
)
from target_sim.errors import TargetError
from target_sim.model import F32
from target_sim.observer.measurements import MEASUREMENT_KINDS


class ObserverError(TargetError):
    """An observer that cannot run on this artifact; the message says why."""


def has_observer(artifact: ModelArtifact) -> bool:
    return isinstance(artifact.content.get("observer"), dict)


def measurement_entries(section: dict) -> list[dict]:
    """The section's measurements as version 2 entries (a version 1 section: its one sensor, without lag)."""
    if section_version(section) >= 2:
        return list(section["measurements"])
    sees = np.zeros(len(OUTPUTS))
    sees[OUTPUTS.index(section["node"])] = 1.0
    return [{"kind": "lagged-sensor", "name": section["column"], "columns": [section["column"]],
             "node": section["node"],
             "arrays": {"sees": encode_array(sees), "lag_pole": encode_array(0.0), "offset_C": section["offset_C"],
                        "R": section["R"]}}]


def load_measurements(section: dict, f=F32) -> list:
    """The target measurements of the section, in order (`target_sim.observer.measurements`)."""
    out = []
    for i, entry in enumerate(measurement_entries(section)):
        kind = MEASUREMENT_KINDS[entry["kind"]]
        out.append(kind.load(entry, f"observer.measurements[{i}]", f))
    return out


def bias_input(section: dict) -> int:
    """The loss input whose column of B the section's bias heats (`BIAS_KINDS`; without a bias: the winding's, as
    the filter has always computed it and never applies)."""
    return BIAS_KINDS[section.get("bias") or "winding-heat"]


def state_count(section: dict) -> int:
    """4 model states, one lag state per lagged measurement, one bias state if the section has one."""
    return observer_state_count(section)
