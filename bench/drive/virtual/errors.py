"""The virtual plant's error: a motor file's virtual_plant table that bench data cannot simulate."""

from __future__ import annotations

from bench.motor.errors import MotorFileError


class VirtualPlantError(MotorFileError):
    """A motor file's virtual_plant table that bench data cannot simulate."""
