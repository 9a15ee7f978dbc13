"""Errors a user can cause. The CLI prints their message as one sentence and exits non-zero.

`BenchError` is the base of the bench layer's errors, as `dbc.errors.CanLinkError`, `target_sim.errors.TargetError`
and `host.errors.HostError` are of the layers below; `bench.cli` catches the four once. An error of a lower layer
reaches the user as it is, unless the bench adds something to it (the file, the option, the target's own reason).
"""


class BenchError(Exception):
    """A problem with the user's input or environment, stated with what to do about it."""

    exit_status = 1


class UsageError(BenchError):
    """A bad command-line argument."""

    exit_status = 2
