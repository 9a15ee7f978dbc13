"""The target's two engines behind one constructor: the Python reference node or the node as firmware.

    node = make_node(artifact, engine="firmware", firmware="model.elf", journal=...)

"python" is `target_sim.node.TargetNode` (the reference implementation of the protocol, the float32 model in
numpy); "firmware" is `target_sim.firmware.node_engine.FirmwareNode`: bench/firmware/node.c and the generated model,
compiled for a Cortex-M4F and run in the emulated core, the Python process only moving frames. Both have the same
interface (`startup_frames`, `handle`, `heartbeat_frames`, `stats`, `state`, `last_error`, `answered_again`,
`journal`), which `target_sim.node.serve` drives.

The firmware runs models with loss maps only (its generated C has no electrical loss model yet): an artifact with an
electrical loss model is refused for it in one sentence (`target_sim.firmware.node_protocol.firmware_refusal`),
wherever the firmware engine starts.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TYPE_CHECKING

from target_sim.artifact import ModelArtifact

if TYPE_CHECKING:
    from target_sim.firmware.node_engine import FirmwareNode
    from target_sim.node import TargetNode

ENGINES = ("python", "firmware")


def make_node(artifact: ModelArtifact, *, engine: str = "python", firmware: str | os.PathLike | bytes | None = None,
              journal: Callable[[dict], None] | None = None, isr_rate_hz: float = 0.0,
              xcp_elf: str | os.PathLike | None = None) -> TargetNode | FirmwareNode:
    """The node of `engine`; the firmware engine needs the model's node ELF (FirmwareError, one sentence, for an
    ELF of another core, another model, or without the node, and for a model the firmware cannot run). With
    `isr_rate_hz` the firmware node runs the current loop's interrupt of a timing image at that rate
    (`FirmwareNode`; ValueError for the Python engine, which has no interrupt). `xcp_elf` places the Python
    node's XCP cells at that firmware ELF's addresses (`target_sim.xcp.layout`; FirmwareError for a bad ELF)."""
    if engine not in ENGINES:
        raise ValueError(f"engine {engine!r} is not one of {', '.join(ENGINES)}")
    if engine == "python":
        if isr_rate_hz:
            raise ValueError("the motor-control interrupt (isr_rate_hz) runs in the firmware engine only")
        from target_sim.node import TargetNode  # here, not at the top: `bench` lists ENGINES without the node

        return TargetNode(artifact, journal=journal, xcp_elf=xcp_elf)
    from target_sim.firmware.elf import FirmwareError
    from target_sim.firmware.node_protocol import firmware_refusal

    refusal = firmware_refusal(artifact)
    if refusal is not None:
        raise FirmwareError(refusal)
    if firmware is None:
        raise ValueError("the firmware engine needs the model's firmware ELF ('bench firmware build')")
    from target_sim.firmware.node_engine import FirmwareNode  # unicorn loads only for this engine

    return FirmwareNode(artifact, firmware, journal=journal, isr_rate_hz=isr_rate_hz)
