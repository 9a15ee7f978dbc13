"""Data arguments on the command line: paths or globs expanded to dataset files, and loading several of them."""

from __future__ import annotations

import glob
from collections.abc import Sequence
from pathlib import Path

from bench.drive.dataset import ColumnMapping, Dataset, load_dataset
from bench.errors import BenchError

GLOB_CHARACTERS = frozenset("*?[")


def is_glob(text: str) -> bool:
    return any(c in GLOB_CHARACTERS for c in text)


def expand_data_paths(patterns: Sequence[str], option: str) -> list[Path]:
    """Each argument a file or a glob (`*`, `?`, `[...]`, `**` across directories), in the order given, a glob's
    matches sorted. An existing file is taken as it is even if its name has glob characters. A glob matching no
    file, a missing path, a directory, or the same file twice: BenchError naming `option` and the argument."""
    out: list[Path] = []
    seen: dict[Path, str] = {}
    for pattern in patterns:
        text = str(pattern)
        if not Path(text).exists() and is_glob(text):
            matches = sorted(m for m in glob.glob(text, recursive=True) if Path(m).is_file())
            if not matches:
                raise BenchError(f"{option} {text}: the pattern matches no file; check it (and quote it so the "
                                 "shell passes it on as it is)")
            paths = [Path(m) for m in matches]
        else:
            path = Path(text)
            if not path.exists():
                raise BenchError(f"{option} {text}: no such file; check the path")
            if path.is_dir():
                raise BenchError(f"{option} {text} is a directory; name the files, e.g. {option} "
                                 f"'{Path(text) / '*.csv'}'")
            paths = [path]
        for path in paths:
            key = path.resolve()
            if key in seen:
                same = "" if seen[key] == text else f" (already given by {seen[key]})"
                raise BenchError(f"{option} {text}: {path} is given twice{same}; name each file once")
            seen[key] = text
            out.append(path)
    return out


def load_datasets(paths: Sequence[Path], mapping: ColumnMapping | None,
                  sample_period_s: float | None) -> list[Dataset]:
    """Load each file through the same mapping; sample_period_s None: each file's own regular period (the mapping's
    if it gives one). The first problem raises the loader's DatasetError."""
    return [load_dataset(Path(p), mapping, sample_period_s) for p in paths]
