"""The bus both nodes and `bench` open: python-can's own conventions plus `auto`.

Options as python-can's tools (`can.logger`, `can.player`): `-i/--interface`, `-c/--channel`, `-b/--bitrate`,
`--bus-kwargs KEY=VALUE ...`, and python-can's configuration sources through `can.util.load_config`: the
environment (`CAN_INTERFACE`, `CAN_CHANNEL`, `CAN_BITRATE`, `CAN_CONFIG`), a config file given with
`--can-config FILE` (section `[default]`) or the default files (`~/can.conf`, `~/.canrc`, ...). An explicit
option wins over the environment, which wins over files.

`auto` (the default when nothing is configured): SocketCAN on `vcan0` when the kernel has SocketCAN and the
interface exists; otherwise python-can's `udp_multicast`, a real bus between processes of this machine, on the
interface-local IPv6 group ff11:7079:7468:6f6e:6465:6d6f:6d63:6173 (python-can's default group with scope 1:
the kernel loops it back to the sockets of this machine and never puts it on a network link; python-can's
ff15:: default and the IPv4 groups would go out on eth0 with every frame). Only where IPv6 is off does `auto`
fall back to the IPv4 group 239.74.163.2 (TTL 1: the local link). A node started by hand uses port 43113, so two
hand-started nodes meet; the orchestrators (`bench run`, `bench compare`, `bench replay`) choose a port unique
to the run when the group is their own (no channel chosen) and hand the concrete options to every process they
start, so parallel runs never hear each other. A channel the user chose (`-c`, `CAN_CHANNEL`, a config file) is
python-can's world: it gets python-can's default port 43113 unless a port is given, so `python -m can.logger -i
udp_multicast -c CHANNEL` hears the run (`logger_command` spells the line that does).

udp_multicast delivers every frame to its own sender too (multicast loopback), so each node drops frames with
its own ids (`OwnFrameFilter`); with SocketCAN a node does not hear itself. A host's bus is wrapped in
`SenderGuard`, which tells its own frames from another host's and stops the host when one appears. Only the standard
library and python-can are used here: both nodes stand on this module.
"""

from __future__ import annotations

import argparse
import os
import shlex
import socket
import time
from dataclasses import dataclass, field, replace
from typing import Any

import can
from can.util import cast_from_string, load_environment_config, load_file_config

from dbc.errors import CanLinkError
from dbc.loopback_filter import UnechoedSender

AUTO = "auto"
AUTO_SOCKETCAN_CHANNEL = "vcan0"
UDP_INTERFACE = "udp_multicast"
UDP_LOCAL_GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"  # interface-local scope: never leaves the machine
UDP_IPV4_GROUP = "239.74.163.2"      # python-can's UdpMulticastBus.DEFAULT_GROUP_IPv4 (fallback without IPv6)
UDP_DEFAULT_PORT = 43113             # python-can's default port
NOMINAL_BITRATE = 500_000            # the vehicle bus the report's bus load refers to
LEAN_UDP_RECEIVE = True              # udp_multicast opens as `dbc.udp_bus.LeanUdpMulticastBus` (False: python-can's)


class BusUnavailable(CanLinkError):
    """The configured bus cannot be opened; the message names it and what to do."""


@dataclass(frozen=True)
class BusConfig:
    """A bus as python-can opens it: can.Bus(interface=..., channel=..., bitrate=..., **kwargs)."""

    interface: str
    channel: str | int | None = None
    bitrate: int | None = None
    kwargs: dict[str, Any] = field(default_factory=dict)

    def describe(self) -> str:
        if self.interface == UDP_INTERFACE:
            return f"udp_multicast {self.channel or '(default group)'} port {self.kwargs.get('port', UDP_DEFAULT_PORT)}"
        channel = "" if self.channel is None else f" {self.channel}"
        return f"{self.interface}{channel}"

    def to_argv(self) -> list[str]:
        """The command-line options that open this same bus in another process."""
        argv = ["-i", self.interface]
        if self.channel is not None:
            argv += ["-c", str(self.channel)]
        if self.bitrate is not None:
            argv += ["-b", str(self.bitrate)]
        if self.kwargs:
            argv += ["--bus-kwargs", *(f"{k}={v}" for k, v in self.kwargs.items())]
        return argv

    def as_dict(self) -> dict[str, Any]:
        return {"interface": self.interface, "channel": self.channel, "bitrate": self.bitrate, **self.kwargs}

    @property
    def nominal_bitrate(self) -> int:
        return int(self.bitrate or NOMINAL_BITRATE)

    def open(self, lean: bool | None = None) -> can.BusABC:
        """Open the bus or raise BusUnavailable (one sentence). lean=False: python-can's own bus (`can.Bus`) for
        udp_multicast too, not `dbc.udp_bus.LeanUdpMulticastBus` (default: LEAN_UDP_RECEIVE)."""
        if self.interface == AUTO:
            raise BusUnavailable("resolve the 'auto' interface before opening it")
        config: dict[str, Any] = {"interface": self.interface, **self.kwargs}
        if self.channel is not None:
            config["channel"] = self.channel
        if self.bitrate is not None:
            config["bitrate"] = self.bitrate
        try:
            if self.interface == UDP_INTERFACE and (LEAN_UDP_RECEIVE if lean is None else lean):   # a leaner receive
                from dbc.udp_bus import LeanUdpMulticastBus, lean_receive_available

                if lean_receive_available():
                    config.pop("interface")
                    return LeanUdpMulticastBus(**config)
            return can.Bus(**config)
        except (can.CanError, OSError, ValueError, TypeError, ImportError) as exc:
            reason = str(exc).strip().rstrip(".") or exc.__class__.__name__
            hint = ("install python-can's multicast extra (msgpack)" if "msgpack" in reason
                    else "choose another with -i/--interface and -c/--channel")
            raise BusUnavailable(f"cannot open the CAN bus {self.describe()} ({reason}); {hint}") from None


class _KeyValueAction(argparse.Action):
    def __call__(self, parser, namespace, values, option_string=None):
        result = {}
        for item in values or []:
            key, sep, value = item.partition("=")
            if not sep or not key:
                parser.error(f"{option_string} takes KEY=VALUE items, not {item!r}")
            result[key.strip()] = cast_from_string(value.strip())
        setattr(namespace, self.dest, result)


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """-i/-c/-b/--bus-kwargs/--can-config, as python-can's command-line tools spell them (plus `auto`)."""
    group = parser.add_argument_group("bus (python-can)")
    group.add_argument("-i", "--interface", default=None, choices=bus_interfaces(),
                       metavar="INTERFACE",
                       help="python-can interface, e.g. socketcan, udp_multicast, virtual; 'auto' (default unless "
                            "CAN_INTERFACE or a python-can config file sets one): socketcan vcan0 if usable, else "
                            "udp_multicast")
    group.add_argument("-c", "--channel", default=None,
                       help="channel, e.g. vcan0 (socketcan) or a multicast group (udp_multicast; default: an "
                            "interface-local IPv6 group that never leaves the machine)")
    group.add_argument("-b", "--bitrate", type=int, default=None, help="bit rate (default: the interface's; the "
                       "report's bus load assumes 500 kbit/s unless given)")
    group.add_argument("--bus-kwargs", nargs="+", action=_KeyValueAction, default={}, metavar="KEY=VALUE",
                       help="more keyword arguments for can.Bus, e.g. port=43113 for udp_multicast")
    group.add_argument("--can-config", default=None, metavar="FILE",
                       help="python-can configuration file to read (section [default])")


def config_from_args(args: argparse.Namespace) -> BusConfig:
    """The bus the options, the environment and python-can's config files describe (possibly `auto`)."""
    explicit: dict[str, Any] = dict(getattr(args, "bus_kwargs", None) or {})
    for key in ("channel", "bitrate"):
        if getattr(args, key, None) is not None:
            explicit[key] = getattr(args, key)
    interface = getattr(args, "interface", None)
    if interface and interface != AUTO:
        explicit["interface"] = interface
    if interface == AUTO:
        merged = explicit  # an explicit 'auto' ignores interfaces configured elsewhere
    else:
        merged = _merge_config_sources(explicit, getattr(args, "can_config", None))
        if merged.get("interface") not in (None, AUTO) and merged["interface"] not in can.VALID_INTERFACES:
            raise BusUnavailable(f"the python-can interface {merged['interface']!r} (from the environment or a "
                                 "config file) is unknown; pass -i with one python-can knows, or -i auto")
    kwargs = {k: v for k, v in merged.items() if k not in ("interface", "channel", "bitrate") and v is not None}
    kwargs.pop("auto_reset", None)
    bitrate = merged.get("bitrate")
    return BusConfig(interface=merged.get("interface") or AUTO, channel=merged.get("channel"),
                     bitrate=int(bitrate) if bitrate is not None else None, kwargs=kwargs)


def _merge_config_sources(explicit: dict[str, Any], path: str | None) -> dict[str, Any]:
    """python-can's load_config order (given > can.rc > environment > config file) without its check that an
    interface is set: none set anywhere means `auto` here."""
    merged: dict[str, Any] = {}
    try:
        sources = [explicit, dict(can.rc), load_environment_config(), load_file_config(path)]
    except Exception as exc:  # a malformed CAN_CONFIG (JSON) or config file
        raise BusUnavailable(f"the python-can configuration cannot be read ({exc}); fix it or pass -i") from None
    for source in sources:
        source = dict(source)
        if "bustype" in source:
            source.setdefault("interface", source.pop("bustype"))
        for key, value in source.items():
            if key not in merged:
                merged[key] = cast_from_string(value) if isinstance(value, str) else value
    return merged


def socketcan_usable(channel: str = AUTO_SOCKETCAN_CHANNEL) -> bool:
    """True when a SocketCAN bus on `channel` opens (kernel with AF_CAN and the interface up)."""
    if not hasattr(socket, "AF_CAN"):
        return False
    try:
        bus = can.Bus(interface="socketcan", channel=channel)
    except (can.CanError, OSError, ValueError, ImportError):
        return False
    bus.shutdown()
    return True


def free_udp_port() -> int:
    """A port no socket of this machine is bound to right now (the kernel's choice), for one run's bus."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("", 0))
        return int(sock.getsockname()[1])


def bus_interfaces() -> list[str]:
    """The interfaces a bus may be given: `auto` and python-can's own."""
    return [AUTO, *sorted(can.VALID_INTERFACES)]


def resolve(config: BusConfig, *, session_unique: bool = False) -> BusConfig:
    """Replace `auto` by a concrete interface and fill in udp_multicast's group and port.

    The port, unless given: unique to the run if `session_unique` and no channel was chosen (the group is then the
    bench's own, so only the bench's processes meet there); else python-can's default 43113, which python-can's
    tools use too (a channel the user chose, a node started by hand)."""
    if config.interface == AUTO:
        channel = config.channel
        if (channel is None or channel == AUTO_SOCKETCAN_CHANNEL) and socketcan_usable():
            return replace(config, interface="socketcan", channel=AUTO_SOCKETCAN_CHANNEL)
        if channel == AUTO_SOCKETCAN_CHANNEL:
            channel = None
        config = replace(config, interface=UDP_INTERFACE, channel=channel)
    if config.interface == UDP_INTERFACE:
        kwargs = dict(config.kwargs)
        if "port" not in kwargs:
            kwargs["port"] = free_udp_port() if session_unique and config.channel is None else UDP_DEFAULT_PORT
        channel = config.channel or (UDP_LOCAL_GROUP if ipv6_multicast_usable() else UDP_IPV4_GROUP)
        config = replace(config, channel=channel, kwargs=kwargs)
    return config


LOGGER_FILE = "bench-copy.blf"


def logger_command(config: BusConfig, file: str = LOGGER_FILE) -> str:
    """The shell line with which python-can's logger records the frames of bus `config` (resolved) into `file`:
    `python -m can.logger -i INTERFACE [-c CHANNEL] [-b BITRATE] -f FILE [--bus-kwargs K=V ...]`, python-can's
    default port left out; `-f` before `--bus-kwargs`, whose values would otherwise swallow it."""
    argv = ["python", "-m", "can.logger", "-i", config.interface]
    if config.channel is not None:
        argv += ["-c", str(config.channel)]
    if config.bitrate is not None:
        argv += ["-b", str(config.bitrate)]
    argv += ["-f", str(file)]
    kwargs = {k: v for k, v in config.kwargs.items()
              if not (config.interface == UDP_INTERFACE and k == "port" and v == UDP_DEFAULT_PORT)}
    if kwargs:
        argv += ["--bus-kwargs", *(f"{k}={v}" for k, v in kwargs.items())]
    return shlex.join(argv)


def ipv6_multicast_usable() -> bool:
    """True when this machine can join the interface-local IPv6 group (IPv6 on)."""
    if not socket.has_ipv6:
        return False
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as sock:
            sock.bind(("", 0))
            request = socket.inet_pton(socket.AF_INET6, UDP_LOCAL_GROUP) + (0).to_bytes(4, "little")
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_JOIN_GROUP, request)
    except OSError:
        return False
    return True


class OwnFrameFilter:
    """Drops the frames a node sent itself (udp_multicast loopback): standard ids in `own_ids`."""

    def __init__(self, own_ids) -> None:
        self.own_ids = frozenset(own_ids)

    def is_own(self, msg: can.Message) -> bool:
        return not msg.is_extended_id and msg.arbitration_id in self.own_ids and not msg.is_error_frame


def runnable_tasks() -> int | None:
    """Tasks runnable on this machine right now (Linux: /proc/loadavg's fourth field), or None where unknown."""
    try:
        with open("/proc/loadavg", "rb") as file:
            return int(file.read().split()[3].split(b"/")[0])
    except (OSError, IndexError, ValueError):
        return None


def usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


class SpinPolicy:
    """How long a node busy-polls for the next frame before it blocks in `recv`: `spin_s` while polling pays, none
    while it does not.

    In lockstep the partner's frame is usually a few hundred µs away, and waking a sleeping process costs more
    than polling for it, when there is a core to spare. On a loaded machine (more runnable tasks than cores) a poll
    takes the CPU the partner needs to answer and makes the scheduler treat the poller as CPU-bound, so it loses
    the prompt wake-up a sleeper gets: the bench then ran 2-3 times slower than blocking. So the node polls only
    while (1) its recent waits were short, each finished wait (from the first empty poll to the frame) counting as
    a hit when it was at most `spin_s` long, spinning or blocked alike, the exponentially weighted share of hits
    (weight `1/window` for the newest) at least one half, and (2) the machine's runnable tasks, sampled every
    `SAMPLE_S` and averaged the same way, are no more than its cores."""

    SAMPLE_S = 0.05

    def __init__(self, spin_s: float, window: int = 16) -> None:
        self.spin_s = max(0.0, spin_s)
        self._weight = 1.0 / window
        self.hits = 1.0            # optimistic at the start: spin until the waits say otherwise
        self.spun = self.blocked = 0   # waits that ended while polling, and waits that had to block
        self._cpus = usable_cpus()
        self._runnable = 0.0
        self._sampled_at = -1.0

    def budget(self) -> float:
        """Seconds to poll before blocking in the next wait."""
        if self.spin_s <= 0 or self.hits < 0.5:
            return 0.0
        now = time.monotonic()
        if now - self._sampled_at >= self.SAMPLE_S:
            self._sampled_at = now
            runnable = runnable_tasks()
            if runnable is not None:
                self._runnable += 0.25 * (runnable - self._runnable)
        return self.spin_s if self._runnable <= self._cpus else 0.0

    def waited(self, seconds: float, *, blocked: bool) -> None:
        """A wait ended after `seconds` (with a frame), `blocked` if it had to sleep in `recv`."""
        self.hits += self._weight * ((seconds <= self.spin_s) - self.hits)
        if blocked:
            self.blocked += 1
        else:
            self.spun += 1


# How long a node listens, before it joins a channel, for another node of its kind already sending there. Status
# and RxErrors go out every 100 ms, so 0.3 s hears two or three; every start pays it, so it stays short.
IN_USE_LISTEN_S = 0.3


def first_heard(bus: can.BusABC, ids, listen_s: float = IN_USE_LISTEN_S, *, prefer: int | None = None) \
        -> can.Message | None:
    """The first standard frame with an id in `ids` heard on `bus` within `listen_s` (the frame with id `prefer`,
    if one comes in that time), or None. udp_multicast lets any number of processes share a group and port, so
    whether a channel is in use can only be heard."""
    ids = frozenset(ids)
    heard = None
    deadline = time.monotonic() + listen_s
    while (remaining := deadline - time.monotonic()) > 0:
        msg = bus.recv(remaining)
        if msg is None:
            break
        if msg.is_extended_id or msg.is_error_frame or msg.arbitration_id not in ids:
            continue
        heard = heard or msg
        if prefer is None or msg.arbitration_id == prefer:
            return msg
    return heard


class OtherSender(CanLinkError):
    """Another node of this node's kind sends on the channel; the message names the channel and the frame."""


# A copy of a sent frame not back after this long is taken as lost (udp_multicast drops some in bursts); the
# record of frames sent is pruned of those only when it grows past GUARD_PRUNE_AT entries.
GUARD_ECHO_HORIZON_S = 10.0
SEND_UNECHOED = True    # udp_multicast: the guard sends from its own socket, whose copies the kernel drops
GUARD_PRUNE_AT = 4096


class SenderGuard:
    """A node's bus that refuses to share its channel with another node of its kind.

    Wraps a python-can bus (`send`, `recv`, `shutdown` and every other attribute pass through). A received
    standard frame with one of `own_ids` that this node did not send makes `recv` raise `OtherSender`: two hosts
    on one channel would both drive the target. udp_multicast hands a node its own frames back; on Linux the guard
    sends from a socket of its own whose copies the bus's socket drops in the kernel (`dbc.loopback_filter.
    UnechoedSender`: a lockstep row costs the host two reads less), so, as on SocketCAN and real interfaces, any
    such frame is another node's. Where that cannot be set up (and for any interface opened with
    `receive_own_messages`), every frame sent with one of `own_ids` is counted by (id, bytes) until its copy comes
    back, so only a frame nobody here sent counts as another node's; a fault layer above this one (duplicates,
    corruption, delays) is seen as what it really transmits."""

    def __init__(self, bus: can.BusABC, config: BusConfig, own_ids, role: str = "host") -> None:
        self.inner = bus
        self.own_ids = frozenset(own_ids)
        self.role = role
        self.channel = config.describe()
        # udp_multicast: send from a socket whose copies the kernel drops (`UnechoedSender`) where it can be set up
        self.unechoed = UnechoedSender.attach(bus, config.channel, config.kwargs.get("port", UDP_DEFAULT_PORT),
                                              config.kwargs.get("hop_limit", 1)) \
            if config.interface == UDP_INTERFACE and SEND_UNECHOED else None
        self.echoes = (config.interface == UDP_INTERFACE and self.unechoed is None) \
            or bool(config.kwargs.get("receive_own_messages"))
        self._pending: dict[tuple[int, bytes], list] = {}   # (id, data) -> [copies still to come, last sent]

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.unechoed is not None:
            self.unechoed.send(msg)
            return
        if self.echoes and not msg.is_extended_id and msg.arbitration_id in self.own_ids:
            key = (msg.arbitration_id, bytes(msg.data))
            entry = self._pending.get(key)
            if entry is None:
                if len(self._pending) >= GUARD_PRUNE_AT:
                    self._prune()
                self._pending[key] = [1, time.monotonic()]
            else:
                entry[0] += 1
                entry[1] = time.monotonic()
        self.inner.send(msg, timeout)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        msg = self.inner.recv(timeout)
        if (msg is not None and not msg.is_extended_id and msg.arbitration_id in self.own_ids
                and not msg.is_error_frame and not self._own_copy(msg)):
            raise OtherSender(f"another {self.role} is sending on {self.channel} (frame id 0x{msg.arbitration_id:03x}, "
                              f"not sent by this {self.role}); stop it or pick another channel")
        return msg

    def _own_copy(self, msg: can.Message) -> bool:
        if not self.echoes:
            return False
        key = (msg.arbitration_id, bytes(msg.data))
        entry = self._pending.get(key)
        if entry is None:
            return False
        entry[0] -= 1
        if entry[0] == 0:
            del self._pending[key]
        return True

    def _prune(self) -> None:
        oldest = time.monotonic() - GUARD_ECHO_HORIZON_S
        for key in [key for key, (_, sent) in self._pending.items() if sent < oldest]:
            del self._pending[key]

    def shutdown(self) -> None:
        if self.unechoed is not None:
            self.unechoed.close()
        self.inner.shutdown()

    def __getattr__(self, name):  # channel_info, state, ... of the wrapped bus
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)
