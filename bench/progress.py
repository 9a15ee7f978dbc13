"""The progress bar of a long replay (`bench run`, `bench replay`, `bench compare`)."""

from __future__ import annotations

import sys


class ProgressBar:
    """tqdm on stderr for a long replay; silent when `quiet`."""

    def __init__(self, total: int, description: str, quiet: bool) -> None:
        self._bar = None
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc=description, unit="row", file=sys.stderr, leave=False,
                             mininterval=0.5, smoothing=0.1)

    def __call__(self, done: int, total: int) -> None:
        if self._bar is not None:
            self._bar.n = done
            self._bar.refresh()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
