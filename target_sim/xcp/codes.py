"""XCP's numbers (ASAM MCD-1 XCP 1.x): command codes, packet identifiers, error codes, the bits of the replies
this slave sets. The values are the standard's, as pyxcp spells them (`pyxcp.types.Command`, its error codes);
the target cannot import pyxcp (it knows the DBC, numpy and python-can only), so they are written here once."""

from __future__ import annotations

from enum import IntEnum


class Cmd(IntEnum):
    CONNECT = 0xFF
    DISCONNECT = 0xFE
    GET_STATUS = 0xFD
    SYNCH = 0xFC
    GET_COMM_MODE_INFO = 0xFB
    GET_ID = 0xFA
    SET_MTA = 0xF6
    UPLOAD = 0xF5
    SHORT_UPLOAD = 0xF4
    BUILD_CHECKSUM = 0xF3
    DOWNLOAD = 0xF0
    SET_DAQ_PTR = 0xE2
    WRITE_DAQ = 0xE1
    SET_DAQ_LIST_MODE = 0xE0
    START_STOP_DAQ_LIST = 0xDE
    START_STOP_SYNCH = 0xDD
    GET_DAQ_PROCESSOR_INFO = 0xDA
    GET_DAQ_RESOLUTION_INFO = 0xD9
    FREE_DAQ = 0xD6
    ALLOC_DAQ = 0xD5
    ALLOC_ODT = 0xD4
    ALLOC_ODT_ENTRY = 0xD3


class Err(IntEnum):
    CMD_SYNCH = 0x00
    DAQ_ACTIVE = 0x11
    CMD_UNKNOWN = 0x20
    CMD_SYNTAX = 0x21
    OUT_OF_RANGE = 0x22
    WRITE_PROTECTED = 0x23
    ACCESS_DENIED = 0x24
    MODE_NOT_VALID = 0x27
    SEQUENCE = 0x29
    DAQ_CONFIG = 0x2A
    MEMORY_OVERFLOW = 0x30
    GENERIC = 0x31


PID_RES = 0xFF
PID_ERR = 0xFE

# CONNECT's RESOURCE byte: calibration/paging and DAQ (no STIM, no programming)
RESOURCE_CAL_PAG = 0x01
RESOURCE_DAQ = 0x04
# COMM_MODE_BASIC: Intel byte order (bit 0 = 0), byte address granularity (bits 1-2 = 0), GET_COMM_MODE_INFO
# answered (OPTIONAL, bit 7); no slave block mode
COMM_MODE_BASIC = 0x80
PROTOCOL_LAYER_VERSION = 0x01
TRANSPORT_LAYER_VERSION = 0x01
DRIVER_VERSION = 0x10          # GET_COMM_MODE_INFO's XCP driver version (1.0)
SESSION_DAQ_RUNNING = 0x40      # GET_STATUS's SESSION_STATUS bit

# CAN: 8-byte CTOs and DTOs
MAX_CTO = 8
MAX_DTO = 8

# BUILD_CHECKSUM's type: XCP_CRC_32 (the IEEE 802.3 CRC, zlib.crc32)
CHECKSUM_CRC_32 = 0x09

# SET_DAQ_LIST_MODE's mode bits this slave refuses (ERR_MODE_NOT_VALID): it neither stimulates nor time-stamps
MODE_DIRECTION_STIM = 0x02
MODE_TIMESTAMP = 0x10
MODE_PID_OFF = 0x20
# GET_DAQ_LIST_MODE-style status bits of a list
LIST_SELECTED = 0x40
LIST_RUNNING = 0x80

# GET_DAQ_PROCESSOR_INFO: dynamic DAQ configuration (bit 0), prescaler supported (bit 1); DAQ_KEY_BYTE 0: absolute
# ODT numbers as the packet identifier, any address extension per entry
DAQ_PROPERTIES = 0x03
DAQ_KEY_BYTE = 0x00

# GET_ID types answered
ID_ASCII = 0x00
ID_A2L_NAME = 0x01
