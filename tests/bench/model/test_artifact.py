import json

import numpy as np
import pytest

from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps
from bench.model.builder import ModelSpec, SigmoidInputs, artifact_content, build_artifact
from bench.thermal.parameters import TABLE1_REFINED
from target_sim.artifact import ArtifactError, dumps, load_artifact, seal, verify


@pytest.fixture(scope="module")
def spec():
    return ModelSpec("hammerstein", TABLE1_REFINED, 0.5, "zoh", "balanced", nominal_loss_maps(), VIRTUAL_MOTOR,
                     sigmoid=SigmoidInputs.identity([500.0, 3000.0, 500.0, 100.0]))


def test_artifact_round_trips_and_carries_exact_float32_values(tmp_path, spec):
    path = tmp_path / "m.json"
    path.write_text(dumps(artifact_content(spec)))
    art = load_artifact(path)
    a64 = art.array("linear_block", "A", dtype=np.float64)
    a32 = art.array("linear_block", "A")
    assert a32.dtype == np.float32
    assert np.array_equal(a32, a64.astype(np.float32))
    entry = art.content["linear_block"]["A"]
    assert entry["f32_hex"][0] == float(np.float32(entry["f64"][0])).hex()
    assert art.kind == "hammerstein" and art.realization == "balanced" and art.dt == 0.5
    assert art.model_id == int(art.sha256[:8], 16)


def test_building_twice_gives_the_same_content(spec):
    assert build_artifact(spec) == build_artifact(spec)


def _write(tmp_path, text):
    path = tmp_path / "bad.json"
    path.write_text(text)
    return path


def test_corrupted_artifact_is_refused(tmp_path, spec):
    content = build_artifact(spec)
    content["linear_block"]["A"]["f64"][0] *= 1.0001
    with pytest.raises(ArtifactError, match="checksum does not match"):
        load_artifact(_write(tmp_path, json.dumps(content)))


def test_truncated_artifact_is_refused(tmp_path, spec):
    text = dumps(artifact_content(spec))
    with pytest.raises(ArtifactError, match="not valid JSON"):
        load_artifact(_write(tmp_path, text[: len(text) // 2]))


@pytest.mark.parametrize("text,fragment", [("", "is empty"), ("[1, 2]", "not a JSON object"),
                                           ('{"schema": "x"}', "not a model artifact")])
def test_other_bad_files_are_refused_in_one_sentence(tmp_path, text, fragment):
    with pytest.raises(ArtifactError, match=fragment) as info:
        load_artifact(_write(tmp_path, text))
    assert "\n" not in str(info.value)


def test_missing_file_names_the_fix(tmp_path):
    with pytest.raises(ArtifactError, match="does not exist; pass an existing file with --model"):
        load_artifact(tmp_path / "nope.json")


def test_mismatched_schema_version_and_float32_values_are_refused(spec):
    content = build_artifact(spec)
    content["schema_version"] = 99
    with pytest.raises(ArtifactError, match="schema version 99"):
        verify(seal(content))
    content = build_artifact(spec)
    content["linear_block"]["B"]["f32_hex"][3] = 1.0.hex()
    with pytest.raises(ArtifactError, match="not the rounding of the float64"):
        verify(seal(content))
    content = build_artifact(spec)
    del content["input_nonlinearity"]
    with pytest.raises(ArtifactError, match="missing the field input_nonlinearity"):
        verify(seal(content))
