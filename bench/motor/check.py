"""Typed look-ups in a motor file (or a table of it) that fail with one sentence naming the file and the key.

Shared by the motor description (bench.motor.description) and the virtual plant's table
(bench.drive.virtual.schema), so a number, a range or an unknown key is checked and worded the same way in both.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any, NoReturn

from bench.motor.errors import MotorFileError

TEMPLATE_HINT = "see 'bench motor template'"


def is_number(value: Any) -> bool:
    """A finite int or float; bool is not a number here (JSON's true would pass as 1)."""
    return not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)


class Checker:
    """One file's checks: `where` names the file, `prefix` the table every key is in ("" for the top level).

    error: the exception raised (a MotorFileError). hint: what to look at, added where a key or table is
    missing. terse: the virtual plant's wording, which adds no hint to a missing number and no "here" to an
    unknown key (kept so its sentences stay as they were).
    """

    def __init__(self, where: str, error: type[MotorFileError] = MotorFileError, *, prefix: str = "",
                 hint: str = TEMPLATE_HINT, terse: bool = False):
        self.where = where
        self.error = error
        self.prefix = prefix
        self.hint = hint
        self.terse = terse

    def fail(self, key: str, what: str) -> NoReturn:
        raise self.error(f"{self.where}: {self.prefix}{key} {what}")

    def table(self, content: dict, key: str) -> dict:
        value = content.get(key)
        if not isinstance(value, dict):
            # a top-level table by its TOML header ([limits]), a nested one by its dotted path
            self.fail(key if self.prefix else f"[{key}]", f"is missing or not a table; {self.hint}")
        return value

    def text(self, content: dict, key: str, prefix: str = "") -> str:
        """Non-blank text; key may be a dotted path (its last part is looked up)."""
        value = content.get(key.rpartition(".")[2])
        if not isinstance(value, str) or not value.strip():
            self.fail(prefix + key, f"is missing or not text; {self.hint}")
        return value

    def number(self, content: dict, key: str, prefix: str = "", *, positive: bool = False,
               low: float | None = None, high: float | None = None, default: float | None = None) -> float:
        """A finite number as float, > 0 if positive, within [low, high]; key may be a dotted path."""
        value = content.get(key.rpartition(".")[2], default)
        name = prefix + key
        if value is None:
            self.fail(name, "is missing" if self.terse else f"is missing; {self.hint}")
        if not is_number(value):
            self.fail(name, f"must be a finite number, not {value!r}")
        value = float(value)
        if positive and value <= 0:
            self.fail(name, f"must be positive, not {value:g}")
        if (low is not None and value < low) or (high is not None and value > high):
            span = (f"from {low:g} to {high:g}" if high is not None and low is not None
                    else f"at least {low:g}" if low is not None else f"at most {high:g}")
            self.fail(name, f"= {value:g} must be {span}")
        return value

    def whole(self, content: dict, key: str, prefix: str = "", *, low: int, high: int | None = None,
              default: int | None = None) -> int:
        """A whole number (not a bool, not 2.0) from low to high (no upper end if high is None)."""
        value = content.get(key, default)
        if type(value) is not int or value < low or (high is not None and value > high):
            span = f"from {low} to {high}" if high is not None else "non-negative" if low == 0 else f"at least {low}"
            what = f"a whole number {span}" if high is not None else f"a {span} whole number"
            self.fail(prefix + key, f"must be {what}, not {value!r}")
        return value

    def version(self, content: dict, supported: int) -> None:
        """schema_version, if given, must be the one this bench reads."""
        version = content.get("schema_version", supported)
        if type(version) is not int or version != supported:
            self.fail("schema_version", f"{version!r} is not supported (this bench reads {supported})")

    def only(self, table: dict, name: str, keys: Iterable[str]) -> None:
        """No key in table but keys; name is the table's path below prefix ("" for the prefix's table itself)."""
        keys = tuple(keys)
        unknown = [k for k in table if k not in keys]
        if unknown:
            known = "is not a known key" if self.terse else "is not a known key here"
            self.fail(f"{name}.{unknown[0]}" if name else unknown[0], f"{known} (known: {', '.join(keys)})")
