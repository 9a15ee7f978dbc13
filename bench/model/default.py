"""The model artifact shipped in the package, so `bench run` works on a fresh clone."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

DEFAULT_ARTIFACT_NAME = "default_model.json"


def default_artifact_path() -> Path:
    return Path(str(files("bench") / "data" / DEFAULT_ARTIFACT_NAME))
