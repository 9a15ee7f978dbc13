"""The model artifacts shipped in the package, so `bench run` works on a fresh clone.

They are what `bench identify --all-kinds --out bench/data/default_model.json` writes on the default datasets
(`bench data`, default seed) with the default PSO seed; tests/bench/model/test_default_artifact.py regenerates them
and checks that the content is identical, bit for bit on any x86-64 CPU (bench.thermal.portable), except the
float32 figures in the metrics, which come from the target's float32 code and are compared within a tolerance.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

DEFAULT_ARTIFACT_NAME = "default_model.json"
DEFAULT_KIND = "hammerstein"


def default_artifact_path(kind: str = DEFAULT_KIND) -> Path:
    """The packaged artifact of a model kind (hammerstein, lti-lptn or pv-lptn)."""
    name = DEFAULT_ARTIFACT_NAME if kind == DEFAULT_KIND else f"default_model-{kind}.json"
    return Path(str(files("bench") / "data" / name))
