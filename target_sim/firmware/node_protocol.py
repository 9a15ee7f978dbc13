"""What the firmware node (bench/firmware/node.c) and its shell (`target_sim.firmware.node_engine`) agree on
beyond the DBC: the layout of the node's output block in RAM, the kinds and reason codes of its journal records,
the sentences the shell writes for them, and the loss models the firmware can run. The generator
(`bench.firmware.nodegen`) writes the codes into fw_node_config.h from here, so each is defined once.

The sentences of the data-row sequence errors name the row's messages as the Python node does
(`target_sim.node.TargetNode._row_frame`): a record carries the index of the missing message in the row
(`dbc.contract.row_messages`, DriveInputs, DriveTemps, DriveCurrents) and the frame it judged, whose id names the
other one.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from dbc.contract import (
    CURRENT_SIGNALS,
    DRIVE_SIGNALS,
    MEASUREMENT_MESSAGE,
    RX_ERROR_KINDS,
    VOLTAGE_MESSAGE,
    TargetState,
    row_messages,
)
from dbc.database import contract
from target_sim.artifact import ModelArtifact
from target_sim.losses import LOSS_KINDS
from target_sim.observer import has_observer
from target_sim.observer.node import can_refusal
from target_sim.xcp.daq import MAX_ODTS


def firmware_loss_models() -> tuple[str, ...]:
    """The loss models the firmware's generated C has (each kind of `target_sim.losses` with its C fragment). A
    model whose loss model reads no current takes a data row as DriveInputs + DriveTemps and validates and ignores
    DriveCurrents; one that reads the currents takes DriveInputs + DriveTemps + DriveCurrents."""
    return tuple(name for name, kind in LOSS_KINDS.items() if kind.firmware)


# the covariance forms the generated C has: Bierman-Thornton (the deployed one) and the steady-state gain
FIRMWARE_OBSERVER_FORMS = ("ud", "steady")


def firmware_refusal(artifact: ModelArtifact) -> str | None:
    """Why the firmware engine cannot run `artifact` (one sentence), or None when it can: a loss model its generated
    C lacks, or an observer it cannot run: one the CAN frames cannot carry (the Python node's sentence,
    `target_sim.observer.node.can_refusal`: the flux linkage on a loss-map model, two measurements in one slot) or
    one whose covariance form is not one its generated C has (UD, steady-state gain). Every measurement kind has its
    C (the flux linkage, lagged sensors), several per row, in either form."""
    name = f"model {artifact.model_id:08x}" + (f" ({artifact.path})" if artifact.path is not None else "")
    if has_observer(artifact):
        refusal = can_refusal(artifact)
        if refusal is not None:
            return refusal
        form = artifact.content["observer"].get("form")
        if form not in FIRMWARE_OBSERVER_FORMS:
            return (f"the firmware engine runs an observer in the ud form (Bierman-Thornton) or the steady form "
                    f"(the steady-state gain), and {name} deploys the {form} form: rebuild it with 'bench observer "
                    "--form ud' or use --engine python")
    if LOSS_KINDS[artifact.loss_model].firmware:
        return None
    return (f"the firmware engine runs the loss models {', '.join(firmware_loss_models())}; {name} has an "
            f"{artifact.loss_model} loss model: use --engine python")


# the messages of the longest data row, in order: a journal record's row-message index is into this
ROW_MESSAGES: tuple[str, ...] = row_messages(len(DRIVE_SIGNALS) + len(CURRENT_SIGNALS))

# the journal's kinds: the RxErrors kinds (1-based, their order), then two that only name the last error
KINDS: tuple[str, ...] = (*RX_ERROR_KINDS, "incomplete", "internal")
KIND_CODES: dict[str, int] = {kind: index + 1 for index, kind in enumerate(KINDS)}

# reason code -> sentence template over the record's numbers a, b (and the frame's id, dlc)
WHY: dict[str, str] = {
    "ERROR_FRAME": "an error frame is not a frame of the contract.",
    "REMOTE_FRAME": "remote frame 0x{a:X} is not a frame of the contract.",
    "EXTENDED_FRAME": "extended frame 0x{a:08X} is not a frame of the contract.",
    "FD_FRAME": "CAN FD frame 0x{a:03X} is not a frame of the classic-CAN contract.",
    "NOT_IN_DBC": "frame 0x{a:03X} is not in the DBC.",
    "NOT_RECEIVED": "frame 0x{a:03X} is sent by the target and not received here.",
    "LENGTH": "frame 0x{id:03X} has DLC {a} instead of 8.",
    "CRC": "frame 0x{id:03X} has CRC 0x{a:02X} instead of 0x{b:02X}.",
    "RANGE": "frame 0x{id:03X} carries signal #{a} outside its range.",
    "COUNTER": "frame 0x{id:03X} has alive counter {a} after {b}.",
    "ROW_STATE": "drive frames of step {a} in state {state_b}",
    "ROW_BACK": "step {a} repeats or goes back (expected {b})",
    "ROWS_LOST": "steps {a}..{b} never arrived",
    "ROW_UNFINISHED": "{first} of step {a} had no {row_b}",          # a: the pending row's step, b: what it lacked
    "ROW_WITHOUT": "{name} of step {a} without its {row_b}",            # a: the frame's step, b: what came not first
    "ROW_STEPS": "{first} step {a} paired with {name} step {b}",
    "START_STATE": "START in state {state_a} (needs READY after a RESET)",
    "RESET_INCOMPLETE": "RESET of step {a} without ResetTemps1 and ResetTemps2 of that step",
    "RESTORE_INCOMPLETE": "RESTORE of step {a} without the 4 RestoreState elements of that step",
    "CORE_FAULT": "the emulated core faulted",
    # an observer's measurement frame of another Step than the row it precedes (TargetNode._measured), per message
    "MEASUREMENT_STEP": MEASUREMENT_MESSAGE + " of step {a} before the row of step {b}",
    "VOLTAGES_STEP": VOLTAGE_MESSAGE + " of step {a} before the row of step {b}",
}
WHY_CODES: dict[str, int] = {name: index + 1 for index, name in enumerate(WHY)}
_WHY_NAMES = {code: name for name, code in WHY_CODES.items()}

# node.h's structs, little-endian
FRAME = struct.Struct("<II8s")                      # struct node_frame
EVENT = struct.Struct("<BBBBI8sii")                 # struct node_event
OUTPUT_HEADER = struct.Struct("<10I")               # struct node_output up to tx[]
COUNTERS = struct.Struct("<11I")                    # struct node_counters up to last_error
REPLY_CAPACITY = 40                                 # the node's own replies of one call (open loop)
TX_CAPACITY = REPLY_CAPACITY + MAX_ODTS             # NODE_TX_CAPACITY (nodegen), open loop: + the XCP DAQ packets
EVENT_CAPACITY = 8                                  # NODE_EVENT_CAPACITY
TX_OFFSET = OUTPUT_HEADER.size
EVENTS_OFFSET = TX_OFFSET + TX_CAPACITY * FRAME.size
OUTPUT_SIZE = EVENTS_OFFSET + EVENT_CAPACITY * EVENT.size      # sizeof(struct node_output)


def tx_capacity(artifact: ModelArtifact) -> int:
    """NODE_TX_CAPACITY of the artifact's node: TX_CAPACITY, and for an observer its checkpoint's elements more (its
    ObserverCheckpoint frames follow a StateCheckpoint in the same call, after the row's replies; the Python node
    queues them all). The last MAX_ODTS frames are the XCP slave's DAQ packets' (`target_sim.xcp.daq`: one per ODT
    of a step), after the replies."""
    if not has_observer(artifact):
        return TX_CAPACITY
    from target_sim.observer import Float32Observer

    return TX_CAPACITY + Float32Observer(artifact).checkpoint_size()


def output_layout(capacity: int) -> tuple[int, int]:
    """(offset of events[], sizeof(struct node_output)) of a node whose tx[] holds `capacity` frames."""
    events = TX_OFFSET + capacity * FRAME.size
    return events, events + EVENT_CAPACITY * EVENT.size
COUNTERS_SIZE = COUNTERS.size + EVENT.size                     # sizeof(struct node_counters)

# node.h's flags on the id of a received frame
ID_EXTENDED, ID_REMOTE, ID_ERROR, ID_FD = 0x8000_0000, 0x4000_0000, 0x2000_0000, 0x1000_0000


@dataclass(frozen=True)
class Event:
    """One journal record of the firmware node."""

    kind: str
    why: str
    frame_id: int
    dlc: int
    data: bytes
    a: int
    b: int

    @classmethod
    def unpack(cls, raw: bytes) -> Event:
        kind, code, dlc, _, frame_id, data, a, b = EVENT.unpack(raw)
        return cls(KINDS[kind - 1] if 0 < kind <= len(KINDS) else "internal", _WHY_NAMES.get(code, "CORE_FAULT"),
                   frame_id, dlc, data, a, b)

    @property
    def sentence(self) -> str:
        def state(value: int) -> str:
            try:
                return TargetState(value).name
            except ValueError:
                return str(value)

        def row(index: int) -> str:
            return ROW_MESSAGES[index] if 0 <= index < len(ROW_MESSAGES) else f"row message #{index}"

        layout = contract().by_id.get(self.frame_id & 0x7FF)
        return WHY[self.why].format(a=self.a, b=self.b, id=self.frame_id & 0x7FF, state_a=state(self.a),
                                    state_b=state(self.b), first=ROW_MESSAGES[0], row_b=row(self.b),
                                    name=layout.name if layout is not None else f"frame 0x{self.frame_id:03X}")
