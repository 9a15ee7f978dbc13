"""The XCP slave's command processor: one CTO in, one RES or ERR packet out (or none: a command while disconnected,
as the standard has it), and the DAQ packets of an event.

    slave = XcpSlave(memory, identification="...", a2l_name="...")
    reply = slave.command(bytes(frame.data))     # bytes of the RES/ERR packet, or None
    packets = slave.event(EVENT_MODEL_STEP)      # DAQ packets

Commands: CONNECT, DISCONNECT, GET_STATUS, SYNCH, GET_COMM_MODE_INFO, GET_ID (ASCII text and the A2L's name, uploaded
from the MTA), SET_MTA, UPLOAD, SHORT_UPLOAD, DOWNLOAD (`target_sim.xcp.memory`: whole calibratable cells within
their limits), BUILD_CHECKSUM (XCP_CRC_32), and the dynamic DAQ commands (`target_sim.xcp.daq`), with
GET_DAQ_PROCESSOR_INFO and GET_DAQ_RESOLUTION_INFO. Anything else is ERR_CMD_UNKNOWN; a packet shorter than its
command's layout is ERR_CMD_SYNTAX. Every command and error is counted (`stats`), with the handler's time.
"""

from __future__ import annotations

import struct
import time
import zlib
from collections import Counter, deque

from target_sim.xcp.codes import (
    CHECKSUM_CRC_32,
    COMM_MODE_BASIC,
    DAQ_KEY_BYTE,
    DAQ_PROPERTIES,
    DRIVER_VERSION,
    ID_A2L_NAME,
    ID_ASCII,
    MAX_CTO,
    MAX_DTO,
    PID_ERR,
    PID_RES,
    PROTOCOL_LAYER_VERSION,
    RESOURCE_CAL_PAG,
    RESOURCE_DAQ,
    SESSION_DAQ_RUNNING,
    TRANSPORT_LAYER_VERSION,
    Cmd,
    Err,
)
from target_sim.xcp.daq import DAQ_QUEUE, EVENTS, MAX_ODT_ENTRIES, ODT_PAYLOAD, Daq, DaqError
from target_sim.xcp.memory import AccessRefused, AddressSpace

# the shortest CTO of each command (its code included)
MIN_LENGTH = {Cmd.CONNECT: 1, Cmd.GET_ID: 2, Cmd.SET_MTA: 8, Cmd.UPLOAD: 2, Cmd.SHORT_UPLOAD: 8,
              Cmd.BUILD_CHECKSUM: 8, Cmd.DOWNLOAD: 2, Cmd.SET_DAQ_PTR: 6, Cmd.WRITE_DAQ: 8,
              Cmd.SET_DAQ_LIST_MODE: 8, Cmd.START_STOP_DAQ_LIST: 4, Cmd.START_STOP_SYNCH: 2, Cmd.ALLOC_DAQ: 4,
              Cmd.ALLOC_ODT: 5, Cmd.ALLOC_ODT_ENTRY: 6}
MAX_BLOCK = 0x10000      # BUILD_CHECKSUM's largest block (the address space is a few KiB)
HISTORY = 100_000        # handler and sampling times kept (the latest)
U16 = struct.Struct("<H")
U32 = struct.Struct("<I")


class _Refused(Exception):
    def __init__(self, code: Err, why: str = ""):
        super().__init__(why)
        self.code = code


class XcpSlave:
    """An XCP slave over an address space; transport-free (the node moves its packets over CAN)."""

    def __init__(self, memory: AddressSpace, *, identification: str, a2l_name: str, identification_address: int):
        self.memory = memory
        self.daq = Daq(memory)
        self.ids = {ID_ASCII: identification.encode("ascii"), ID_A2L_NAME: a2l_name.encode("ascii")}
        self.id_address = identification_address
        self.connected = False
        self.mta = 0
        self.commands: Counter[str] = Counter()
        self.errors: Counter[str] = Counter()
        self.ignored = 0                  # commands while disconnected (no answer)
        self.daq_dropped = 0              # DAQ packets sampled past a call's queue (DAQ_QUEUE), never sent
        self.calibrations: list[tuple[str, float]] = []   # (cell, value) of every accepted DOWNLOAD, in order
        self.handler_ns: deque[int] = deque(maxlen=HISTORY)   # each command's handling time
        self.sample_ns: deque[int] = deque(maxlen=HISTORY)    # each DAQ event sampled (a packet at least)
        self._handlers = {Cmd.CONNECT: self._connect, Cmd.DISCONNECT: self._disconnect,
                          Cmd.GET_STATUS: self._get_status, Cmd.SYNCH: self._synch,
                          Cmd.GET_COMM_MODE_INFO: self._comm_mode_info, Cmd.GET_ID: self._get_id,
                          Cmd.SET_MTA: self._set_mta, Cmd.UPLOAD: self._upload, Cmd.SHORT_UPLOAD: self._short_upload,
                          Cmd.BUILD_CHECKSUM: self._build_checksum, Cmd.DOWNLOAD: self._download,
                          Cmd.SET_DAQ_PTR: self._set_daq_ptr, Cmd.WRITE_DAQ: self._write_daq,
                          Cmd.SET_DAQ_LIST_MODE: self._set_daq_list_mode,
                          Cmd.START_STOP_DAQ_LIST: self._start_stop_daq_list,
                          Cmd.START_STOP_SYNCH: self._start_stop_synch,
                          Cmd.GET_DAQ_PROCESSOR_INFO: self._daq_processor_info,
                          Cmd.GET_DAQ_RESOLUTION_INFO: self._daq_resolution_info,
                          Cmd.FREE_DAQ: self._free_daq, Cmd.ALLOC_DAQ: self._alloc_daq, Cmd.ALLOC_ODT: self._alloc_odt,
                          Cmd.ALLOC_ODT_ENTRY: self._alloc_odt_entry}

    # ------------------------------------------------------------------ entry points
    def command(self, cto: bytes) -> bytes | None:
        """The reply to one command packet (None: no reply, a command other than CONNECT while disconnected)."""
        started = time.perf_counter_ns()
        reply = self._command(bytes(cto))
        self.handler_ns.append(time.perf_counter_ns() - started)
        return reply

    def event(self, event: int) -> list[bytes]:
        """The DAQ packets of `event` (none while disconnected or no list runs)."""
        if not self.connected or not self.daq.running:
            return []
        started = time.perf_counter_ns()
        packets = self.daq.sample(event)
        if packets:
            self.sample_ns.append(time.perf_counter_ns() - started)
        return packets

    def queued(self, packets: list[bytes]) -> list[bytes]:
        """The DAQ packets of one call of the node that it sends: the first DAQ_QUEUE (the C node's queue); the
        rest are dropped and counted (`daq_dropped`)."""
        self.daq_dropped += max(0, len(packets) - DAQ_QUEUE)
        return packets[:DAQ_QUEUE]

    def stats(self) -> dict:
        def us(times) -> dict:
            ordered = sorted(times)
            return {"p50": ordered[len(ordered) // 2] / 1000.0, "max": ordered[-1] / 1000.0} if ordered else {}

        return {"commands": dict(self.commands), "errors": dict(self.errors), "ignored": self.ignored,
                "daq_packets": self.daq.packets, "daq_dropped": self.daq_dropped,
                "calibrations": len(self.calibrations),
                "handler_us": us(self.handler_ns), "daq_sample_us": us(self.sample_ns)}

    # ------------------------------------------------------------------ dispatch
    def _command(self, cto: bytes) -> bytes | None:
        if not cto:
            return self._error(Err.CMD_SYNTAX, "empty")
        code = cto[0]
        if not self.connected and code != Cmd.CONNECT:
            self.ignored += 1
            return None
        try:
            cmd = Cmd(code)
        except ValueError:
            return self._error(Err.CMD_UNKNOWN, f"0x{code:02X}")
        self.commands[cmd.name] += 1
        if len(cto) < MIN_LENGTH.get(cmd, 1):
            return self._error(Err.CMD_SYNTAX, cmd.name)
        try:
            return bytes((PID_RES,)) + self._handlers[cmd](cto)
        except (_Refused, DaqError, AccessRefused) as exc:
            return self._error(exc.code, cmd.name)

    def _error(self, code: Err, what: str) -> bytes:
        self.errors[code.name] += 1
        return bytes((PID_ERR, code))

    # ------------------------------------------------------------------ session
    def _connect(self, cto: bytes) -> bytes:
        self.connected = True
        return bytes((RESOURCE_CAL_PAG | RESOURCE_DAQ, COMM_MODE_BASIC, MAX_CTO)) + U16.pack(MAX_DTO) + bytes(
            (PROTOCOL_LAYER_VERSION, TRANSPORT_LAYER_VERSION))

    def _disconnect(self, cto: bytes) -> bytes:
        self.daq.stop_all()               # a master that leaves stops its measurement
        self.connected = False
        return b""

    def _get_status(self, cto: bytes) -> bytes:
        session = SESSION_DAQ_RUNNING if self.daq.running else 0
        return bytes((session, 0, 0)) + U16.pack(0)        # no resource is protected; session configuration id 0

    def _synch(self, cto: bytes) -> bytes:
        raise _Refused(Err.CMD_SYNCH)

    def _comm_mode_info(self, cto: bytes) -> bytes:
        return bytes((0, 0, 0, 0, 0, 0, DRIVER_VERSION))    # no master block mode, no interleaving

    def _get_id(self, cto: bytes) -> bytes:
        text = self.ids.get(cto[1])
        if text is None:
            raise _Refused(Err.OUT_OF_RANGE, f"GET_ID type {cto[1]}")
        offset = 0 if cto[1] == ID_ASCII else len(self.ids[ID_ASCII])
        self.mta = self.id_address + offset                 # the master uploads it from the MTA (mode 0)
        return bytes((0, 0, 0)) + U32.pack(len(text))

    # ------------------------------------------------------------------ memory
    def _set_mta(self, cto: bytes) -> bytes:
        self.mta = U32.unpack_from(cto, 4)[0]
        return b""

    def _upload(self, cto: bytes) -> bytes:
        size = cto[1]
        if not 1 <= size <= MAX_CTO - 1:
            raise _Refused(Err.OUT_OF_RANGE, f"UPLOAD of {size} bytes (block mode is not offered)")
        data = self.memory.read(self.mta, size)
        self.mta += size
        return data

    def _short_upload(self, cto: bytes) -> bytes:
        size = cto[1]
        if not 1 <= size <= MAX_CTO - 1:
            raise _Refused(Err.OUT_OF_RANGE, f"SHORT_UPLOAD of {size} bytes")
        address = U32.unpack_from(cto, 4)[0]
        data = self.memory.read(address, size)
        self.mta = address + size
        return data

    def _download(self, cto: bytes) -> bytes:
        size = cto[1]
        if not 1 <= size <= MAX_CTO - 2 or len(cto) < 2 + size:
            raise _Refused(Err.OUT_OF_RANGE if size > MAX_CTO - 2 else Err.CMD_SYNTAX, f"DOWNLOAD of {size} bytes")
        data = cto[2: 2 + size]
        written = self.memory.write(self.mta, data)
        for offset, cell in zip(range(0, size, 4), written, strict=True):
            self.calibrations.append((cell.name, struct.unpack_from("<f", data, offset)[0]))
        self.mta += size
        return b""

    def _build_checksum(self, cto: bytes) -> bytes:
        size = U32.unpack_from(cto, 4)[0]
        if not 1 <= size <= MAX_BLOCK:
            raise _Refused(Err.OUT_OF_RANGE, f"BUILD_CHECKSUM of {size} bytes")
        crc = zlib.crc32(self.memory.read(self.mta, size))
        self.mta += size
        return bytes((CHECKSUM_CRC_32, 0, 0)) + U32.pack(crc)

    # ------------------------------------------------------------------ DAQ
    def _free_daq(self, cto: bytes) -> bytes:
        self.daq.free()
        return b""

    def _alloc_daq(self, cto: bytes) -> bytes:
        self.daq.alloc_daq(U16.unpack_from(cto, 2)[0])
        return b""

    def _alloc_odt(self, cto: bytes) -> bytes:
        self.daq.alloc_odt(U16.unpack_from(cto, 2)[0], cto[4])
        return b""

    def _alloc_odt_entry(self, cto: bytes) -> bytes:
        self.daq.alloc_odt_entry(U16.unpack_from(cto, 2)[0], cto[4], cto[5])
        return b""

    def _set_daq_ptr(self, cto: bytes) -> bytes:
        self.daq.set_pointer(U16.unpack_from(cto, 2)[0], cto[4], cto[5])
        return b""

    def _write_daq(self, cto: bytes) -> bytes:
        if cto[1] != 0xFF:
            raise _Refused(Err.OUT_OF_RANGE, "bit-wise DAQ entries are not offered")
        self.daq.write_entry(cto[2], U32.unpack_from(cto, 4)[0])
        return b""

    def _set_daq_list_mode(self, cto: bytes) -> bytes:
        self.daq.set_mode(U16.unpack_from(cto, 2)[0], cto[1], U16.unpack_from(cto, 4)[0], cto[6])
        return b""

    def _start_stop_daq_list(self, cto: bytes) -> bytes:
        return bytes((self.daq.start_stop_list(cto[1], U16.unpack_from(cto, 2)[0]),))

    def _start_stop_synch(self, cto: bytes) -> bytes:
        self.daq.start_stop_synch(cto[1])
        return b""

    def _daq_processor_info(self, cto: bytes) -> bytes:
        return (bytes((DAQ_PROPERTIES,)) + U16.pack(MAX_ODT_ENTRIES) + U16.pack(len(EVENTS))
                + bytes((0, DAQ_KEY_BYTE)))

    def _daq_resolution_info(self, cto: bytes) -> bytes:
        return bytes((1, ODT_PAYLOAD, 1, 0, 0)) + U16.pack(0)     # byte granularity, no STIM, no time stamps
