"""What both C generators (the model's, `bench.firmware.codegen`, and the node's, `bench.firmware.nodegen`) need:
exact float32 literals and the one error they raise."""

from __future__ import annotations

import numpy as np

from bench.errors import BenchError


class FirmwareGenerationError(BenchError):
    """The artifact holds something the generator cannot express in C."""


def c_float(value: float | np.floating) -> str:
    """A float32 value as an exact C99 hex-float literal with the f suffix: 0x1.8p+3f, -0x0p+0f."""
    value = float(value)
    if not np.isfinite(value) or float(np.float32(value)) != value:
        raise FirmwareGenerationError(f"{value!r} is not a finite float32 value; rebuild the artifact with "
                                      "'bench identify'")
    sign, mantissa_exponent = ("-", value.hex()[1:]) if value.hex().startswith("-") else ("", value.hex())
    mantissa, exponent = mantissa_exponent.split("p")
    mantissa = mantissa.rstrip("0").rstrip(".")
    return f"{sign}{mantissa}p{exponent}f"
