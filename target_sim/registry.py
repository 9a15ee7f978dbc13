"""A table of kinds of one thing (loss models, model kinds, realizations), each found by its name.

As python-can's interface table: the rest of the tree looks a kind up here instead of comparing strings. A table
over a package loads every module of the package on first use (each module registers its kind on import; a kind's
module is its name with "_" for "-": `lti_lptn` for "lti-lptn"); an unknown name is one sentence naming the known
ones.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Iterator
from typing import Generic, TypeVar

from target_sim.errors import TargetError

T = TypeVar("T")


class UnknownKind(TargetError, ValueError, LookupError):
    """A name no kind of the table has; the message is one sentence naming the known ones (a ValueError, as a bad
    value given to a function, and a LookupError, as a missing key)."""


class Registry(Generic[T]):
    """Kinds by name, in registration order. `what` names the family in messages ("loss model")."""

    def __init__(self, what: str, package: str | None = None, first: tuple[str, ...] = ()):
        self.what = what
        self._package = package
        self._first = first          # kinds loaded first, in this order (the order messages list the kinds in)
        self._kinds: dict[str, T] = {}
        self._loaded = package is None

    def register(self, name: str, kind: T) -> T:
        self._kinds[name] = kind
        return kind

    def unregister(self, name: str) -> None:
        self._kinds.pop(name, None)

    def _load(self) -> None:
        if self._loaded:
            return
        self._loaded = True
        package = importlib.import_module(self._package)
        first = [name.replace("-", "_") for name in self._first]   # a module name cannot hold "-"
        found = sorted(m.name for m in pkgutil.iter_modules(package.__path__) if not m.name.startswith("_"))
        for name in [*first, *(n for n in found if n not in first)]:
            importlib.import_module(f"{self._package}.{name}")

    def names(self) -> tuple[str, ...]:
        """The kinds' names: `first` in its order, then the others as registered."""
        self._load()
        return tuple(sorted(self._kinds, key=lambda n: self._first.index(n) if n in self._first else len(self._first)))

    def __contains__(self, name: object) -> bool:
        self._load()
        return name in self._kinds

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __getitem__(self, name: str) -> T:
        self._load()
        try:
            return self._kinds[name]
        except (KeyError, TypeError):
            raise UnknownKind(f"{self.what} {name!r} is not one of {', '.join(self.names())}") from None

    def items(self) -> list[tuple[str, T]]:
        return [(name, self._kinds[name]) for name in self.names()]
