"""The pages that list the dataset columns a user's file may carry (the own-motor tutorial, the mapping file's
reference) name every column of the schema: the loader reads no other, so a column missing from the list is one a
user cannot know to map onto (ntc_C was)."""

from __future__ import annotations

from pathlib import Path

import bench.drive.mapping
from bench.drive.dataset import BY_NAME

ROOT = Path(__file__).resolve().parents[2]


def _section(text: str, heading: str) -> str:
    start = text.index(heading)
    end = text.find("\n## ", start + len(heading))
    return text[start:end if end > 0 else None]


def test_the_own_motor_tutorial_lists_every_dataset_column():
    text = _section((ROOT / "docs" / "tutorials" / "own-motor.md").read_text(encoding="utf-8"),
                    "## Datasets and data files")
    assert [c for c in BY_NAME if c not in text] == []


def test_the_mapping_reference_lists_every_dataset_column():
    assert [c for c in BY_NAME if c not in bench.drive.mapping.__doc__] == []
