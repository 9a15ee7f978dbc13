"""The bench: the engineering library and the orchestrator of the two CAN nodes."""

from __future__ import annotations

DISTRIBUTION = "pmsm-thermal-bench"   # the name pip knows the project by


def package_version(unknown: str = "0+unknown") -> str:
    """The installed distribution's version; `unknown` for a source tree that was never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:
        return unknown
