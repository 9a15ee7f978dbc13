"""The error of a motor description (or a file it names) that the bench cannot use."""

from bench.errors import BenchError


class MotorFileError(BenchError):
    """A motor description file, or the loss maps or prior it names, that the bench cannot use."""
