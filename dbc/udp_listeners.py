"""What the listeners of a udp_multicast bus lost while a run sent: the kernel's own counts.

A listener that reads slower than a run sends (python-can's logger on a busy machine: a lockstep run sends several
thousand frames a second) loses datagrams at its full receive buffer, and nothing on the bus tells the sender. The
kernel counts them twice: per socket (`/proc/net/udp6` and `/proc/net/udp`, the `drops` column, which also counts
what a socket's filter discarded, as the target's own copies: `dbc.loopback_filter`) and per machine
(`RcvbufErrors` in `/proc/net/snmp6` and `/proc/net/snmp`: full buffers only, on any port). `ListenerDrops` takes
both before and after a run; the frames listeners lost are the smaller rise: the per-socket drops on the run's port
(the run's own processes' sockets left out) bounded by the machine's full-buffer count. With one listener that is
exactly the frames missing from its copy. Linux only; elsewhere the count is unknown (None).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

PROC_NET = Path("/proc/net")
UDP_TABLES = ("udp6", "udp")
BUFFER_COUNTERS = (("snmp6", "Udp6RcvbufErrors"), ("snmp", "RcvbufErrors"))


@dataclass(frozen=True)
class UdpSocket:
    """One UDP socket of this network namespace: its inode, the bytes waiting in it, the datagrams it dropped."""

    inode: int
    waiting_bytes: int
    drops: int


def udp_sockets(port: int) -> list[UdpSocket] | None:
    """The UDP sockets bound to local `port` (IPv6 and IPv4), or None where the kernel does not list them."""
    found: list[UdpSocket] = []
    listed = False
    for table in UDP_TABLES:
        try:
            lines = (PROC_NET / table).read_text().splitlines()[1:]
        except OSError:
            continue
        listed = True
        for line in lines:
            # sl local_address rem_address st tx_queue:rx_queue tr:tm->when retrnsmt uid timeout inode ref pointer drops
            fields = line.split()
            if len(fields) < 13 or int(fields[1].rsplit(":", 1)[1], 16) != port:
                continue
            found.append(UdpSocket(inode=int(fields[9]), waiting_bytes=int(fields[4].split(":")[1], 16),
                                   drops=int(fields[12])))
    return found if listed else None


def buffer_errors() -> int | None:
    """Datagrams this network namespace dropped at full receive buffers so far (IPv6 and IPv4), None if unknown."""
    total, known = 0, False
    for table, counter in BUFFER_COUNTERS:
        try:
            text = (PROC_NET / table).read_text()
        except OSError:
            continue
        if table == "snmp6":
            values = dict(line.split()[:2] for line in text.splitlines() if line.strip())
        else:   # "Udp: Name Name ..." then "Udp: value value ..."
            rows = [line.split()[1:] for line in text.splitlines() if line.startswith("Udp:")]
            values = dict(zip(rows[0], rows[1], strict=False)) if len(rows) >= 2 else {}
        if counter in values:
            total, known = total + int(values[counter]), True
    return total if known else None


def socket_inodes(pid: int) -> set[int]:
    """The inodes of the sockets process `pid` holds open (empty when its descriptors cannot be read)."""
    inodes: set[int] = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    try:
        links = [os.readlink(fd_dir / name) for name in os.listdir(fd_dir)]
    except OSError:
        return inodes
    for link in links:
        if link.startswith("socket:["):
            inodes.add(int(link[len("socket:["):-1]))
    return inodes


class ListenerDrops:
    """The frames other listeners on udp `port` dropped between construction and `count()`."""

    def __init__(self, port: int) -> None:
        self.port = port
        self._sockets = {s.inode: s.drops for s in udp_sockets(port) or ()}
        self._buffer_errors = buffer_errors()

    def count(self, own_pids: Iterable[int] = ()) -> int | None:
        """Datagrams the sockets on the port dropped since the start, the sockets of `own_pids` (the run's own
        processes, this one always) left out, at most what the machine dropped at full buffers; None if unknown."""
        sockets, errors = udp_sockets(self.port), buffer_errors()
        if sockets is None or errors is None or self._buffer_errors is None:
            return None
        own = socket_inodes(os.getpid()).union(*(socket_inodes(pid) for pid in own_pids))
        dropped = sum(s.drops - self._sockets.get(s.inode, 0) for s in sockets if s.inode not in own)
        return max(0, min(dropped, errors - self._buffer_errors))
