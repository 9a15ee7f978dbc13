"""Preloaded into every worker process of a campaign's local cluster (`distributed.worker.preload`).

A Ctrl-C in a terminal reaches every process of its group: the campaign's driver handles it (it stops the runs and
closes the cluster, then says so in one sentence), so its workers ignore SIGINT rather than each printing a
KeyboardInterrupt traceback and dying under the driver's feet.
"""

from __future__ import annotations

import contextlib
import signal


def dask_setup(worker) -> None:  # noqa: ARG001 - distributed's preload API
    with contextlib.suppress(ValueError):     # not the main thread: nothing to do
        signal.signal(signal.SIGINT, signal.SIG_IGN)
