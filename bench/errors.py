"""Errors a user can cause. The CLI prints their message as one sentence and exits non-zero."""


class BenchError(Exception):
    """A problem with the user's input or environment, stated with what to do about it."""

    exit_status = 1


class UsageError(BenchError):
    """A bad command-line argument."""

    exit_status = 2
