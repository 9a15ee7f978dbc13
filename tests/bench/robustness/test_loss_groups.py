"""Each loss kind owns the coefficient groups a robustness study perturbs (`robustness_groups` of
`bench.motor.losskinds`): every kind declares them, the `parameter` perturbation offers them as subjects, and a
group's perturbation scales exactly the entries it names, nothing else. `bench.robustness` names no loss kind."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.model.default import default_artifact_path
from bench.motor.losskinds import LAB_LOSS_KINDS
from bench.robustness.kinds import PERTURBATIONS
from bench.robustness.models import PARAMETER_GROUPS, SPLIT, perturbed_model
from target_sim.artifact import decode_array, load_artifact, verify

from helpers import electrical_artifact_text


def artifacts() -> dict:
    """An artifact of every loss kind the house ships: the packaged model (maps) and the tests' electrical one."""
    return {"maps": load_artifact(default_artifact_path()),
            "electrical": verify(json.loads(electrical_artifact_text()))}


def entry(artifact, key: tuple[str, ...]) -> np.ndarray:
    node = artifact.content["losses"]
    for part in key[:-1]:
        node = node[part]
    return decode_array(node[key[-1]], ".".join(key), np.float64)


def leaves(section, path=()) -> dict:
    """Every array entry under an artifact's `losses`, by its key path."""
    if isinstance(section, dict) and "data" not in section and "shape" not in section:
        return {k: v for name, value in section.items() for k, v in leaves(value, (*path, name)).items()}
    return {path: section}


@pytest.mark.parametrize("name", LAB_LOSS_KINDS.names())
def test_every_lab_loss_kind_declares_its_robustness_groups(name):
    groups = LAB_LOSS_KINDS[name].robustness_groups
    assert groups, f"the loss kind {name} declares no robustness groups"
    for group, keys in groups.items():
        assert group not in PARAMETER_GROUPS and group != SPLIT, group      # no clash with the LPTN's subjects
        assert keys and all(key and all(isinstance(part, str) for part in key) for key in keys), group


def test_robustness_covers_the_shipped_loss_kinds():
    """The study reaches each kind's groups, and +10 % of a group scales its entries by 1.1 and no other entry (a
    new kind's own test does the same on its artifact: `tests/bench/model/test_loss_kind_plugin.py`)."""
    found = artifacts()
    assert {"maps", "electrical"} == set(found) <= set(LAB_LOSS_KINDS.names())
    kind = PERTURBATIONS["parameter"]
    for name, artifact in found.items():
        groups = LAB_LOSS_KINDS[name].robustness_groups
        assert kind.subjects(artifact) == (*PARAMETER_GROUPS, SPLIT, *groups)
        for group, keys in groups.items():
            assert kind.unit(artifact, group) == "%"
            off = perturbed_model(artifact, group, 10.0)
            for key in leaves(artifact.content["losses"]):
                if key == ("model",):
                    continue
                expected = entry(artifact, key) * (1.1 if key in keys else 1.0)
                assert np.array_equal(entry(off, key), expected), (name, group, key)
