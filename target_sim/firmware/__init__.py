"""The firmware engine: generated C compiled for a Cortex-M4F, run in an emulated core with counted cycles.

`Firmware.load(elf)` checks and loads a bare-metal ELF into Unicorn; `Firmware.call(name, *args)` runs one of its
functions (AAPCS hard-float) and leaves the instructions and Cortex-M4 cycles it executed in `Firmware.last`;
`memory_from_elf(elf)` gives its flash and RAM figures; `FirmwareEstimator(artifact, elf)` is the model firmware
alone with the interface of the Python float32 reference (`bench firmware check`); `node_engine.FirmwareNode` is
the whole target node as firmware (what the target runs with `--engine firmware`). The compiler is not needed
here, only at build time.
"""

from target_sim.firmware.cycles import CYCLES, PIPELINE_REFILL, CycleModel, instruction_cost
from target_sim.firmware.elf import FirmwareError, memory_from_elf, read_elf
from target_sim.firmware.emulator import CallStats, Firmware, FirmwareFault
from target_sim.firmware.engine import FirmwareEstimator

__all__ = ["CYCLES", "PIPELINE_REFILL", "CallStats", "CycleModel", "Firmware", "FirmwareError",
           "FirmwareEstimator", "FirmwareFault", "instruction_cost", "memory_from_elf", "read_elf"]
