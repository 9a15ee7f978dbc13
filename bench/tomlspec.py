"""The TOML files a user writes (the campaign spec, the robustness spec, the acceptance criteria, the pytest
plugin's profile), read and checked by one mechanism before anything else looks at them.

- `read_spec`: the file's text, or one sentence when it is missing or unreadable;
- `spec_tables`: the document, checked for what may stand at its top;
- `TableSpec`: one table's keys, each with its check; `read` gives the checked values or one sentence naming the
  file, the table and the key ("spec.toml: [study] seeds must be a whole number from 1 to 1000");
- the checks: a value in, the value (converted) out, or ValueError with a clause ("must be a whole number").

A problem is raised as the caller's error class, so each file keeps its own exit status and advice.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

Check = Callable[[Any], Any]     # a TOML value -> the value to use, or ValueError("must be ...")

SPEC_UNKNOWN = "has an unknown section or key {key!r}; a spec has the tables {tables}"


def spec_tables(text: str, where: str, sections: Iterable[str], error: type[Exception], *,
                keys: Iterable[str] = (), fix: str = "fix the spec", unknown: str = SPEC_UNKNOWN) -> dict[str, Any]:
    """`text`'s TOML document, checked to hold only the tables `sections` (each a table where present) and the
    top-level `keys` whose values the caller checks (a scalar such as the criteria file's `baseline`, or a table of
    its own form). Anything else is one sentence starting with `where`, raised as `error`: not TOML ends with `fix`;
    an unknown key is told by `unknown`, a format of the key and the tables (`[a], [b]`)."""
    sections, allowed = tuple(sections), (*sections, *keys)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{where} is not valid TOML ({exc}); {fix}") from None
    extra = [k for k in doc if k not in allowed]
    if extra:
        tables = ", ".join(f"[{s}]" for s in sections)
        raise error(f"{where} " + unknown.format(key=extra[0], tables=tables))
    for section in sections:
        if not isinstance(doc.get(section, {}), dict):
            raise error(f"{where}: {section} must be a table, [{section}]")
    return doc


def read_spec(path: Path, what: str, advice: str, error: type[Exception]) -> str:
    """The text of the file `path`, `what` ("the campaign spec") in the sentence, raised as `error`, when it is
    missing (with `advice`: what to give instead) or cannot be read."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{what} {path} does not exist; {advice}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{what} {path} cannot be read ({exc})") from None


@dataclass(frozen=True)
class TableSpec:
    """One table of a TOML file: its keys, each with its check, the keys it must have, and what an unknown key's
    sentence advises (default: the table's keys)."""

    name: str                          # as a sentence shows it: "[study]", "[criteria.pm]"; "" for a file's top
    keys: Mapping[str, Check]
    required: tuple[str, ...] = ()
    advice: str | None = None

    def read(self, table: Any, where: str, error: type[Exception]) -> dict[str, Any]:
        """The checked values of the keys `table` gives (a key it leaves out is absent), or `error` with one
        sentence starting with `where` (the file)."""
        at = f"{where}: {self.name}" if self.name else where
        if not isinstance(table, dict):
            raise error(f"{at} must be a table")
        unknown = [key for key in table if key not in self.keys]
        if unknown:
            raise error(f"{at} has an unknown key {unknown[0]!r}; {self.advice or 'use ' + ', '.join(self.keys)}")
        missing = [key for key in self.required if key not in table]
        if missing:
            raise error(f"{at} has no {missing[0]}")
        values = {}
        for key, value in table.items():
            try:
                values[key] = self.keys[key](value)
            except ValueError as exc:
                raise error(f"{at} {key} {exc}") from None
        return values


# ---------------------------------------------------------------- checks (ValueError: one clause)


def number(value: Any, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError("must be a number")
    if positive and value <= 0:
        raise ValueError("must be a positive number")
    return float(value)


def whole(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError("must be a whole number")
    return value


def whole_at_least(low: int) -> Check:
    def check(value: Any) -> int:
        if whole(value) < low:
            raise ValueError(f"must be a whole number, {low} or more")
        return value
    return check


def whole_between(low: int, high: int) -> Check:
    def check(value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ValueError(f"must be a whole number from {low} to {high}")
        return value
    return check


def flag(value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError("must be true or false")
    return value


def string(value: Any) -> str:
    if not isinstance(value, str):
        raise ValueError("must be a string")
    return value


def choice(*choices: str) -> Check:
    def check(value: Any) -> str:
        if value not in choices:
            raise ValueError(f"must be one of {', '.join(choices)}")
        return value
    return check


def path(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError("must be a file path")
    return value


def numbers(value: Any) -> tuple[float, ...]:
    """A non-empty list of finite numbers."""
    if not isinstance(value, list) or not value:
        raise ValueError("must be a non-empty list of numbers, e.g. [1.0, 2.0]")
    if any(isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) for v in value):
        raise ValueError(f"must list finite numbers, not {value!r}")
    return tuple(float(v) for v in value)


def names(known: tuple[str, ...]) -> Check:
    """A non-empty list of names, each one of `known`."""
    def check(value: Any) -> tuple[str, ...]:
        if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
            raise ValueError(f"must be a non-empty list of names, e.g. [{', '.join(map(repr, known[:2]))}]")
        bad = [v for v in value if v not in known]
        if bad:
            raise ValueError(f"names {bad[0]!r}, which is not one of {', '.join(known)}")
        return tuple(value)
    return check
