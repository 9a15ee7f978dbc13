"""The XCP-on-CAN identifiers, read once from ``dbc/xcp.toml`` (the file says why they are not in the DBC).

    cmd_id()   master -> slave (CMD)
    res_id()   slave -> master (RES, ERR, EV, DAQ)
    xcp_ids()  both

A frame with one of these ids is XCP traffic: the target's XCP slave answers the command id, the host logs both and
counts neither as a frame error of the contract.
"""

from __future__ import annotations

import tomllib
from functools import cache
from pathlib import Path

from dbc.database import frame_ids
from dbc.errors import CanLinkError

XCP_PATH = Path(__file__).with_name("xcp.toml")
MAX_STANDARD_ID = 0x7FF


class XcpIdError(CanLinkError):
    """dbc/xcp.toml is unreadable or names ids the bus cannot carry; one sentence."""


@cache
def _ids() -> tuple[int, int]:
    try:
        table = tomllib.loads(XCP_PATH.read_text(encoding="utf-8"))["can"]
        cmd, res = int(table["cmd_id"]), int(table["res_id"])
    except (OSError, KeyError, TypeError, ValueError, tomllib.TOMLDecodeError) as exc:
        raise XcpIdError(f"{XCP_PATH} does not name the XCP ids ([can] cmd_id, res_id): {exc}") from None
    taken = set(frame_ids().values())
    for name, value in (("cmd_id", cmd), ("res_id", res)):
        if not 0 <= value <= MAX_STANDARD_ID:
            raise XcpIdError(f"{XCP_PATH}: {name} 0x{value:X} is not an 11-bit CAN id")
        if value in taken:
            raise XcpIdError(f"{XCP_PATH}: {name} 0x{value:03X} is a frame of the DBC; choose a free id")
    if cmd == res:
        raise XcpIdError(f"{XCP_PATH}: cmd_id and res_id are both 0x{cmd:03X}; they must differ")
    return cmd, res


def cmd_id() -> int:
    """The XCP command id (master -> slave)."""
    return _ids()[0]


def res_id() -> int:
    """The XCP response and DAQ id (slave -> master)."""
    return _ids()[1]


def xcp_ids() -> frozenset[int]:
    """Both XCP ids."""
    return frozenset(_ids())
