"""What the measurement kinds computed from the voltage vector and the currents share (the flux linkage, the winding
resistance): their raw channels, the decoding of their constants, the node they read and the C constants' table.
Not a kind itself (the registry loads no module whose name starts with "_")."""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from target_sim.artifact import OUTPUTS, decode_array

# raw channels in the order the filter reads them: the dataset's columns, and over CAN the host's measurement
# channels and the row's own values (`dbc.contract.MEASUREMENT_CHANNELS`, `ROW_CHANNELS`: DriveVoltages, DriveCurrents)
COLUMNS = ("u_d_V", "u_q_V", "i_d_A", "i_q_A")
CAN_CHANNELS = ("u_d", "u_q", "i_d", "i_q")
RAD_S_PER_RPM = 2.0 * math.pi / 60.0


class VoltageReading:
    """A reading of one node (`NODE`, no lag) from u_d, u_q, i_d, i_q and the speed. A subclass names its
    `PARAMETERS` (the entry's arrays, decoded in the filter's precision as attributes), its C (`C_READING`,
    `C_SCALARS`: (C name, attribute, comment)) and folds what its reading needs from the exact values (`fold`)."""

    PARAMETERS: ClassVar[tuple[str, ...]]
    C_READING: ClassVar[str]
    C_SCALARS: ClassVar[tuple[tuple[str, str, str], ...]]
    NODE: ClassVar[str]
    DEFAULT_NAME: ClassVar[str]

    def __init__(self, entry: dict, where: str, f):
        arrays = entry["arrays"]
        exact = {}
        for key in self.PARAMETERS:
            setattr(self, key, decode_array(arrays[key], f"{where}.arrays.{key}", f)[()])
            exact[key] = float(decode_array(arrays[key], f"{where}.arrays.{key}", np.float64)[()])
        self.name = str(entry.get("name", self.DEFAULT_NAME))
        self.columns = COLUMNS
        self.can_channels = CAN_CHANNELS
        self.sees = np.zeros(len(OUTPUTS), dtype=f)
        self.sees[OUTPUTS.index(self.NODE)] = f(1.0)
        self.lag_pole = f(0.0)
        self.one = f(1.0)
        self.fold(exact, f)

    def fold(self, exact: dict[str, float], f) -> None:
        """Set the constants the reading uses beside its parameters (`exact`: the parameters in float64)."""

    @property
    def width(self) -> int:
        return len(COLUMNS)

    @property
    def c_reading(self) -> str:
        return self.C_READING

    def c_scalars(self) -> list[tuple[str, np.floating, str]]:
        """(C name, float32 value, comment) of the constants `C_READING` names (the generator suffixes them)."""
        return [(name, getattr(self, attribute), comment) for name, attribute, comment in self.C_SCALARS]
