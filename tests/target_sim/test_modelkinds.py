"""Model kinds are plug-ins (`target_sim.modelkinds`): the estimator, the artifact check, the costs and the
firmware generator ask the kind, so a kind registered from elsewhere runs without a change to any of them (only the
bus needs its code in the DBC)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from target_sim.artifact import load_artifact, seal, verify
from target_sim.costs import memory_estimate, step_cost
from target_sim.model import Float32Estimator
from target_sim.modelkinds import MODEL_KINDS, register
from target_sim.modelkinds.lti_lptn import LtiLptnKind


class _TwinKind(LtiLptnKind):
    name = "lti-twin"
    summary = "the LTI LPTN under another name"


@pytest.fixture
def twin_kind():
    kind = register(_TwinKind())
    yield kind
    MODEL_KINDS.unregister(kind.name)


def test_a_kind_registered_elsewhere_runs_and_costs_as_its_model(artifacts, twin_kind):
    base = load_artifact(artifacts["lti"])
    content = json.loads(artifacts["lti"].read_text())
    content["model_kind"] = twin_kind.name
    twin = verify(seal(content))
    outputs = []
    for artifact in (base, twin):
        model = Float32Estimator(artifact)
        model.reset([40.0, 50.0, 45.0, 48.0])
        outputs.append(np.array([model.step(200.0 + k, 4000.0, 40.0, 25.0) for k in range(50)]))
    assert outputs[0].tobytes() == outputs[1].tobytes() and np.all(outputs[0] > 20.0)
    assert step_cost(twin) == step_cost(base) and memory_estimate(twin) == memory_estimate(base)
    # its C (the node's config needs a DBC code for the kind, which a test kind has not)
    lti = MODEL_KINDS["lti-lptn"]
    assert twin_kind.c_step(twin) == lti.c_step(base) and twin_kind.c_arrays(twin) == lti.c_arrays(base)


def test_the_estimator_reads_the_kinds_part(artifacts):
    hammerstein = Float32Estimator(load_artifact(artifacts["hammerstein"]))
    assert hammerstein.part.a.shape == (4, 4) and hasattr(hammerstein.part, "input_nonlinearity")
    pv = Float32Estimator(load_artifact(artifacts["pv"]))
    a, b = pv.part.pv_network(4000.0, 40.0)
    assert a.shape == (4, 4) and b.shape == (4, 6) and a.dtype == np.float32
    assert not hasattr(pv.part, "c_inv")


def test_each_kind_counts_its_own_blocks(artifacts):
    blocks = {name: set(step_cost(load_artifact(artifacts[name])).blocks) for name in ("lti", "pv", "hammerstein")}
    assert blocks["lti"] == {"call", "losses", "sources", "linear"}
    assert blocks["hammerstein"] == blocks["lti"] | {"sigmoid"}
    assert blocks["pv"] == {"call", "losses", "linear"}
