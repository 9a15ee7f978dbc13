"""Progress of the long commands (identify, observer, run, replay, compare, campaign, robustness, firmware builds),
as pip and tqdm show it: one tqdm bar on stderr with a total, a percentage and an ETA, only for a person at a
terminal.

Into a pipe or a file (a CI log, `2> err`) a bar would be carriage-return states nobody reads, so there it is
off and stderr holds only final lines. A sentence while a bar is shown goes through `say`, which clears the bar's
line first and redraws the bar below the sentence."""

from __future__ import annotations

import os
import shutil
import sys
import threading

from tqdm import tqdm


def shows_bars(quiet: bool) -> bool:
    """Whether bars are drawn: not with --quiet (or --json), and only when stderr is a terminal."""
    return not quiet and sys.stderr.isatty()


def progress_bar(total: int | None, description: str, unit: str, quiet: bool, *, leave: bool = False,
                 bar_format: str | None = None) -> tqdm:
    """A tqdm bar on stderr counting `total` `unit`s (disabled, and silent, where `shows_bars` says no)."""
    size = _fixed_size()
    return tqdm(total=total, desc=description, unit=unit, file=sys.stderr, leave=leave,
                disable=not shows_bars(quiet), ncols=size and size.columns, nrows=size and size.lines,
                dynamic_ncols=size is None, bar_format=bar_format)


def _fixed_size() -> os.terminal_size | None:
    """None: the bar follows the terminal's size. A pseudo-terminal that reports no size (0 × 0: `script` started
    from a pipe, some CI runners) would get no bar at all from tqdm, so it gets shutil's fallback size."""
    try:
        if os.get_terminal_size(sys.stderr.fileno()).columns > 0:
            return None
    except (AttributeError, OSError, ValueError):    # not a real file (a test's capture): no bar is drawn anyway
        return None
    return shutil.get_terminal_size()


def say(text: str) -> None:
    """Print a sentence on stderr without writing it onto a bar (tqdm.write clears and redraws any bar shown)."""
    tqdm.write(text, file=sys.stderr)


class ProgressBar:
    """The bar of a replay (`bench run`, `bench replay`, `bench compare`): called with (rows done, rows)."""

    def __init__(self, total: int, description: str, quiet: bool) -> None:
        self._bar = progress_bar(total, description, "row", quiet)

    def __call__(self, done: int, total: int) -> None:
        if self._bar.total != total:
            self._bar.total = total
        self._bar.update(done - self._bar.n)   # update, not refresh: tqdm redraws at most every mininterval

    def close(self) -> None:
        self._bar.close()


class StageBars:
    """One bar per stage of a multi-stage search (called with stage label, steps done, steps at most, cost); the
    previous stage's bar ends when the next begins, and `close` ends the open one, also when the command is
    stopped, so its last redraw comes before the command's closing sentence, not after it."""

    def __init__(self, quiet: bool, unit: str = "it") -> None:
        self._quiet, self._unit = quiet, unit
        self._label: str | None = None
        self._bar: tqdm | None = None

    def __call__(self, label: str, done: int, total: int, cost: float) -> None:
        if label != self._label:
            self.close()
            self._label, self._bar = label, progress_bar(total, label, self._unit, self._quiet, leave=True)
        bar = self._bar
        bar.set_postfix(cost=f"{cost:.4g}", refresh=False)
        bar.update(done - bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


TICK_S = 0.5    # how often a step's bar is redrawn while the step runs: its elapsed time moves
# tqdm's own format without the rate (seconds per step says nothing of steps this unequal), so that the step's name
# fits an 80-column line
STEP_FORMAT = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}, {postfix}]"


class StepBar:
    """The bar of a job of a few steps of which none says how far it is (a compiler call, a link): the steps done of
    all of them, the step under way named beside them, and the elapsed time redrawn every TICK_S while a step runs
    (tqdm redraws only when it is updated). Called with (the step starting, steps done, steps in all); `close` ends
    it, and its redrawing thread, also when the job fails."""

    def __init__(self, description: str, quiet: bool) -> None:
        self._description, self._quiet = description, quiet
        self._bar: tqdm | None = None
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def __call__(self, step: str, done: int, total: int) -> None:
        if self._bar is None:
            self._bar = progress_bar(total, self._description, "step", self._quiet, bar_format=STEP_FORMAT)
            if not self._bar.disable:
                self._ticker = threading.Thread(target=self._tick, name="step-bar", daemon=True)
                self._ticker.start()
        self._bar.set_postfix_str(step, refresh=False)
        self._bar.update(done - self._bar.n)
        self._bar.refresh()

    def _tick(self) -> None:
        while not self._stop.wait(TICK_S):
            self._bar.refresh()

    def close(self) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
            self._ticker = None
        if self._bar is not None:
            self._bar.close()
            self._bar = None
