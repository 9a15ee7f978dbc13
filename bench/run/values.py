"""One-line parsers of a run option's value, both ways it arrives: from the command line (an argparse type, a
string) and from a TOML file (a campaign spec, a pytest profile: a typed value). Each raises one sentence:
`UsageError` for the command line (exit status 2), `ValueError` for a TOML value (its reader names the file and
the key)."""

from __future__ import annotations

import math
from typing import Any

from bench.errors import UsageError
from bench.tomlspec import choice, flag, number, path, whole, whole_at_least  # noqa: F401 - run options name them here


def positive_float(text: str) -> float:
    """An argparse type: a positive, finite number."""
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{text!r} is not a number") from None
    if not value > 0 or value != value or value == float("inf"):
        raise UsageError(f"{text!r} must be a positive number")
    return value


def positive_int(text: str) -> int:
    """An argparse type: a positive whole number."""
    try:
        value = int(text)
    except ValueError:
        raise UsageError(f"{text!r} is not a whole number") from None
    if value <= 0:
        raise UsageError(f"{text!r} must be a positive whole number")
    return value


def non_negative_int(text: str) -> int:
    """An argparse type: a whole number, 0 or more."""
    try:
        value = int(text)
    except ValueError:
        raise UsageError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise UsageError(f"{text!r} must be a whole number, 0 or more")
    return value


def sample_period(text: str) -> float | None:
    """'--sample-period' value: a positive number of seconds, or 'auto' (None: inferred from the time column)."""
    if str(text).strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"--sample-period {text!r} is neither a number of seconds nor 'auto'; "
                         "e.g. --sample-period 1") from None
    if not math.isfinite(value) or value <= 0:
        raise UsageError(f"--sample-period {text!r} must be a positive number of seconds (or 'auto')")
    return value


# ---------------------------------------------------------------- TOML values (ValueError: one clause)
# the general checks are the TOML files' own (bench.tomlspec); the run's own follow them


def rows(value: Any) -> int | None:
    if value == "all":
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ValueError('must be a positive whole number of rows or "all"')
    return value


def period(value: Any) -> float | str:
    return "auto" if value == "auto" else number(value)


def faults(value: Any) -> str:
    """The fault spec as `--faults` takes it ('' for none); a TOML table becomes 'kind=value,...'."""
    if value is False or value in ("", "none"):
        return ""
    if isinstance(value, dict):
        parts = []
        for kind, amount in value.items():
            if isinstance(amount, bool) or not isinstance(amount, int | float):
                raise ValueError(f"{kind} = {amount!r} must be a number (a probability, or a count for kill/freeze)")
            parts.append(f"{kind}={amount!r}")
        value = ",".join(parts)
    if not isinstance(value, str):
        raise ValueError('must be a fault spec such as "drop=0.01,kill=1", a table {drop = 0.01}, or "" for none')
    from host.faults.spec import parse_faults

    parse_faults([value])   # FaultSpecError is a ValueError: the reader names the option
    return ",".join(p.strip() for p in value.split(",") if p.strip())
