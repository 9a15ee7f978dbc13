"""The A2L (ASAM MCD-2 MC 1.71) of a model's target: what an XCP master (pyxcp, CANape, INCA) needs to measure and
calibrate it over CAN.

It is written from the very address space the Python node's XCP slave serves (`target_sim.xcp`), placed by the
firmware ELF when one is given: a cell that mirrors a C symbol takes the symbol's address from the ELF's symbol table
(`target_sim.xcp.layout`), and the ELF's DWARF, where the image has it (a build with -g), must call that symbol a
float array (anything else is refused: the A2L would misread it); an image without DWARF (the packaged ones) leaves
the type to the node's catalogue, which says so in the file. Per cell: a MEASUREMENT (read-only) or a CHARACTERISTIC
VALUE (calibratable, with its limits), FLOAT32_IEEE, identity conversion with its unit; MOD_PAR's EPK is the GET_ID
text at its address; IF_DATA XCP has the protocol layer, the dynamic DAQ with its two events (the model step, the
heartbeat tick) and XCP_ON_CAN with the two ids of dbc/xcp.toml, and the A2ML block gives its grammar (the part of
ASAM's XCP AML it uses, the same structs and tags), so a tool without an XCP AML of its own reads it.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from bench.errors import BenchError
from dbc.database import heartbeat_period_s
from dbc.transport import NOMINAL_BITRATE
from dbc.xcp import cmd_id, res_id
from target_sim.artifact import ModelArtifact
from target_sim.node import TargetNode
from target_sim.xcp import identification
from target_sim.xcp.codes import MAX_CTO, MAX_DTO, Cmd
from target_sim.xcp.daq import EVENT_HEARTBEAT, EVENT_MODEL_STEP, EVENTS, MAX_ODT_ENTRIES, ODT_PAYLOAD
from target_sim.xcp.memory import Cell

A2L_LIMIT = 3.4e38      # a float32 cell without limits: the type's range
TIMEOUT_MS = 2000
# an EVENT's TIME_CYCLE is a uchar (XCP's AML) counted in its TIME_UNIT: 6 = 1 ms, 7 = 10 ms, 8 = 100 ms, 9 = 1 s
TIME_UNIT_1MS = 6
UCHAR_MAX = 255
# every command the slave answers that XCP 1.x calls optional (SET_MTA and UPLOAD are: a master may not use them
# unless they are listed); the mandatory ones (CONNECT ... DOWNLOAD, the DAQ list commands) are not listed
OPTIONAL_COMMANDS = ("GET_COMM_MODE_INFO", "GET_ID", "SET_MTA", "UPLOAD", "SHORT_UPLOAD", "BUILD_CHECKSUM",
                     "GET_DAQ_PROCESSOR_INFO", "GET_DAQ_RESOLUTION_INFO", "FREE_DAQ", "ALLOC_DAQ", "ALLOC_ODT",
                     "ALLOC_ODT_ENTRY")


class A2lError(BenchError):
    """The ELF's DWARF contradicts the node's catalogue; one sentence."""


def dwarf_float_arrays(elf: str | os.PathLike) -> dict[str, bool] | None:
    """{variable name: whether DWARF types it as float or an array of float} from the ELF's DWARF, None without
    DWARF."""
    from elftools.elf.elffile import ELFFile

    with open(elf, "rb") as handle:
        image = ELFFile(handle)
        if not image.has_dwarf_info():
            return None
        out: dict[str, bool] = {}
        for unit in image.get_dwarf_info().iter_CUs():
            for die in unit.iter_DIEs():
                if die.tag != "DW_TAG_variable" or "DW_AT_name" not in die.attributes:
                    continue
                kind = die
                while "DW_AT_type" in kind.attributes and kind.tag != "DW_TAG_base_type":
                    kind = kind.get_DIE_from_attribute("DW_AT_type")
                name = die.attributes["DW_AT_name"].value.decode()
                out[name] = (kind.tag == "DW_TAG_base_type" and kind.attributes["DW_AT_name"].value == b"float"
                             and kind.attributes["DW_AT_byte_size"].value == 4)
        return out


def _ident(name: str) -> str:
    return name.replace("[", "_").replace("]", "")


def _limit(value: float) -> str:
    if not math.isfinite(value):
        return f"{-A2L_LIMIT if value < 0 else A2L_LIMIT:g}"
    return repr(float(value))


def _text(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', "'") + '"'


def _compu_method(unit: str) -> str:
    return "CM_" + (_ident(unit.replace("^", "").replace("/", "_per_")) or "none")


def a2l_text(artifact: ModelArtifact, elf: str | os.PathLike | None = None) -> str:
    """The A2L of `artifact`'s target, its addresses from the firmware ELF `elf` (None: the slave's pages)."""
    node = TargetNode(artifact, xcp_elf=elf)
    cells = node.xcp.memory.cells
    types = dwarf_float_arrays(elf) if elf is not None else None
    if types is not None:
        for cell in cells:
            base = cell.symbol.split("[")[0] if cell.symbol else None
            if base is not None and types.get(base) is False:
                raise A2lError(f"{elf}'s DWARF does not type {base} as float; the node's XCP catalogue "
                               "(target_sim/xcp/variables.py) and the C disagree")
    source = ("no ELF: every cell in the slave's pages" if elf is None else
              f"addresses from {Path(elf).name}'s symbols; types "
              + ("checked against its DWARF" if types is not None else "from the node's catalogue (no DWARF)"))
    text, a2l_name = identification(artifact.model_id)
    units = sorted({c.unit for c in cells})
    lines = ["ASAP2_VERSION 1 71",
             f"/begin PROJECT thermal_bench {_text('pmsm-thermal-bench target, generated by bench firmware a2l')}",
             f"  /begin HEADER {_text(source)}", f"    VERSION {_text(text)}", "  /end HEADER",
             f"  /begin MODULE {a2l_name} {_text(f'model {artifact.model_id:08x} ({artifact.kind})')}",
             *a2ml_lines(),
             '    /begin MOD_PAR ""', f"      EPK {_text(text)}", f"      ADDR_EPK 0x{node.xcp.id_address:08X}",
             "    /end MOD_PAR",
             '    /begin MOD_COMMON ""', "      BYTE_ORDER MSB_LAST", "      ALIGNMENT_BYTE 1",
             "      ALIGNMENT_WORD 2", "      ALIGNMENT_LONG 4", "      ALIGNMENT_FLOAT32_IEEE 4",
             "    /end MOD_COMMON",
             *_if_data(artifact),
             "    /begin RECORD_LAYOUT RL_FLOAT32", "      FNC_VALUES 1 FLOAT32_IEEE COLUMN_DIR DIRECT",
             "    /end RECORD_LAYOUT"]
    for unit in units:
        lines += [f"    /begin COMPU_METHOD {_compu_method(unit)} {_text('identity, ' + (unit or 'no unit'))}",
                  f'      IDENTICAL "%.6g" {_text(unit)}', "    /end COMPU_METHOD"]
    for cell in cells:
        lines += _characteristic(cell) if cell.write is not None else _measurement(cell)
    lines += ["  /end MODULE", "/end PROJECT", ""]
    return "\n".join(lines)


def _measurement(cell: Cell) -> list[str]:
    comment = cell.comment + (f" (C: {cell.symbol})" if cell.symbol else "")
    return [f"    /begin MEASUREMENT {_ident(cell.name)} {_text(comment)}",
            f"      FLOAT32_IEEE {_compu_method(cell.unit)} 0 0 {_limit(-math.inf)} {_limit(math.inf)}",
            f"      ECU_ADDRESS 0x{cell.address:08X}", "    /end MEASUREMENT"]


def _characteristic(cell: Cell) -> list[str]:
    low, high = cell.limits
    return [f"    /begin CHARACTERISTIC {_ident(cell.name)} {_text(cell.comment)}",
            f"      VALUE 0x{cell.address:08X} RL_FLOAT32 0 {_compu_method(cell.unit)} {_limit(low)} {_limit(high)}",
            "    /end CHARACTERISTIC"]


def event_cycle(period_ms: float) -> tuple[int, int]:
    """(TIME_CYCLE, TIME_UNIT) of an event every `period_ms`: the finest unit whose count fits TIME_CYCLE's uchar
    (the model step's 500 ms is 50 x 10 ms; 500 x 1 ms overflowed it)."""
    for unit in range(TIME_UNIT_1MS, TIME_UNIT_1MS + 4):
        cycle = max(1, round(period_ms / 10 ** (unit - TIME_UNIT_1MS)))
        if cycle <= UCHAR_MAX:
            return cycle, unit
    raise A2lError(f"an event every {period_ms:g} ms is longer than XCP's longest cycle, "
                   f"{UCHAR_MAX} s; use a shorter model step")


# ASAM XCP 1.x's AML (the grammar of IF_DATA XCP), the part this A2L's IF_DATA uses: the same structs, tags and
# enumerations as ASAM's, so a tool reads our IF_DATA as it reads it by its own XCP AML
A2ML_TYPES = """\
      struct Protocol_Layer {
        uint;   /* XCP protocol layer version */
        uint; uint; uint; uint; uint; uint; uint;   /* T1 .. T7 [ms] */
        uchar;  /* MAX_CTO */
        uint;   /* MAX_DTO */
        enum { "BYTE_ORDER_MSB_LAST" = 0, "BYTE_ORDER_MSB_FIRST" = 1 };
        enum { "ADDRESS_GRANULARITY_BYTE" = 1, "ADDRESS_GRANULARITY_WORD" = 2, "ADDRESS_GRANULARITY_DWORD" = 4 };
        taggedstruct {
          ("OPTIONAL_CMD" enum {
{commands}
          })*;
        };
      };
      struct Daq {
        enum { "STATIC" = 0, "DYNAMIC" = 1 };
        uint;   /* MAX_DAQ */
        uint;   /* MAX_EVENT_CHANNEL */
        uchar;  /* MIN_DAQ */
        enum { "OPTIMISATION_TYPE_DEFAULT" = 0, "OPTIMISATION_TYPE_ODT_TYPE_16" = 1,
               "OPTIMISATION_TYPE_ODT_TYPE_32" = 2, "OPTIMISATION_TYPE_ODT_TYPE_64" = 3,
               "OPTIMISATION_TYPE_ODT_TYPE_ALIGNMENT" = 4, "OPTIMISATION_TYPE_MAX_ENTRY_SIZE" = 5 };
        enum { "ADDRESS_EXTENSION_FREE" = 0, "ADDRESS_EXTENSION_ODT" = 1, "ADDRESS_EXTENSION_DAQ" = 3 };
        enum { "IDENTIFICATION_FIELD_TYPE_ABSOLUTE" = 0, "IDENTIFICATION_FIELD_TYPE_RELATIVE_BYTE" = 1,
               "IDENTIFICATION_FIELD_TYPE_RELATIVE_WORD" = 2,
               "IDENTIFICATION_FIELD_TYPE_RELATIVE_WORD_ALIGNED" = 3 };
        enum { "GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE" = 1, "GRANULARITY_ODT_ENTRY_SIZE_DAQ_WORD" = 2,
               "GRANULARITY_ODT_ENTRY_SIZE_DAQ_DWORD" = 4, "GRANULARITY_ODT_ENTRY_SIZE_DAQ_DLONG" = 8 };
        uchar;  /* MAX_ODT_ENTRY_SIZE_DAQ */
        enum { "NO_OVERLOAD_INDICATION" = 0, "OVERLOAD_INDICATION_PID" = 1, "OVERLOAD_INDICATION_EVENT" = 2 };
        taggedstruct {
          (block "EVENT" struct {
            char[101];  /* EVENT_CHANNEL_NAME */
            char[9];    /* EVENT_CHANNEL_SHORT_NAME */
            uint;       /* EVENT_CHANNEL_NUMBER */
            enum { "DAQ" = 1, "STIM" = 2, "DAQ_STIM" = 3 };
            uchar;  /* MAX_DAQ_LIST */
            uchar;  /* TIME_CYCLE */
            uchar;  /* TIME_UNIT */
            uchar;  /* PRIORITY */
          })*;
        };
      };
      taggedstruct Common_Parameters {
        block "PROTOCOL_LAYER" struct Protocol_Layer;
        block "DAQ" struct Daq;
      };
      struct CAN_Parameters {
        uint;   /* XCP on CAN version */
        taggedstruct {
          "CAN_ID_MASTER" ulong;   /* CMD CAN-ID */
          "CAN_ID_SLAVE" ulong;    /* RES/ERR/DAQ CAN-ID */
          "BAUDRATE" ulong;        /* Hz */
        };
      };
      block "IF_DATA" taggedunion if_data {
        "XCP" struct {
          taggedstruct Common_Parameters;
          taggedstruct {
            block "XCP_ON_CAN" struct {
              struct CAN_Parameters;
              taggedstruct Common_Parameters;
            };
          };
        };
      };"""


def a2ml_lines() -> list[str]:
    """The A2L's A2ML block: the grammar of its IF_DATA XCP (`A2ML_TYPES`), its OPTIONAL_CMD enumeration the
    commands it lists with their XCP codes."""
    commands = ",\n".join(f'            "{name}" = 0x{Cmd[name]:02X}' for name in OPTIONAL_COMMANDS)
    return ["    /begin A2ML", *A2ML_TYPES.replace("{commands}", commands).splitlines(), "    /end A2ML"]


def _if_data(artifact: ModelArtifact) -> list[str]:
    """IF_DATA XCP: protocol layer, dynamic DAQ with the model step's event, XCP on CAN."""
    period_ms = {EVENT_MODEL_STEP: artifact.dt * 1000, EVENT_HEARTBEAT: heartbeat_period_s() * 1000}
    events = [f'          /begin EVENT {_text(name)} {_text(name.replace(" ", "_")[:8])} {number} DAQ 255 '
              f"{' '.join(map(str, event_cycle(period_ms[number])))} 0" + "\n          /end EVENT"
              for number, name in EVENTS.items()]
    return ["    /begin IF_DATA XCP",
            "      /begin PROTOCOL_LAYER",
            f"        0x0100 {' '.join([str(TIMEOUT_MS)] * 7)} {MAX_CTO} {MAX_DTO} BYTE_ORDER_MSB_LAST "
            "ADDRESS_GRANULARITY_BYTE",
            *(f"        OPTIONAL_CMD {name}" for name in OPTIONAL_COMMANDS),
            "      /end PROTOCOL_LAYER",
            "      /begin DAQ",
            f"        DYNAMIC {MAX_ODT_ENTRIES} {len(EVENTS)} 0 OPTIMISATION_TYPE_DEFAULT ADDRESS_EXTENSION_FREE "
            "IDENTIFICATION_FIELD_TYPE_ABSOLUTE GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE "
            f"{ODT_PAYLOAD} NO_OVERLOAD_INDICATION",
            *events,
            "      /end DAQ",
            "      /begin XCP_ON_CAN",
            f"        0x0100 CAN_ID_MASTER 0x{cmd_id():X} CAN_ID_SLAVE 0x{res_id():X} BAUDRATE {NOMINAL_BITRATE}",
            "      /end XCP_ON_CAN",
            "    /end IF_DATA"]
