"""A TOML file of named tables, read and checked for what may stand at its top before anything else looks at it.

The campaign spec, the robustness study's spec and the acceptance criteria file share this opening (`spec_tables`;
all three also `read_spec`); each then reads its own tables. A problem is one sentence naming the file,
raised as the caller's error class.
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

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
