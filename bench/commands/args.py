"""Argument types and bus options the subcommands share (as python-can's command-line tools share one module).

argparse types raise `UsageError` (one sentence, exit status 2); `bus_from_args` turns the bus options
(`dbc.transport.add_bus_arguments`) into the bus of a run.
"""

from __future__ import annotations

import argparse
import sys
import time

from bench.errors import UsageError
from dbc.database import contract
from dbc.transport import BusConfig, config_from_args, logger_command, resolve


def positive_float(text: str) -> float:
    """An argparse type: a positive, finite number."""
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{text!r} is not a number") from None
    if not value > 0 or value != value or value == float("inf"):
        raise UsageError(f"{text!r} must be a positive number")
    return value


def positive_int(text: str) -> int:
    """An argparse type: a positive whole number."""
    try:
        value = int(text)
    except ValueError:
        raise UsageError(f"{text!r} is not a whole number") from None
    if value <= 0:
        raise UsageError(f"{text!r} must be a positive whole number")
    return value


def non_negative_int(text: str) -> int:
    """An argparse type: a whole number, 0 or more."""
    try:
        value = int(text)
    except ValueError:
        raise UsageError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise UsageError(f"{text!r} must be a whole number, 0 or more")
    return value


def bus_from_args(args: argparse.Namespace) -> BusConfig:
    """The bus the command-line options describe, `auto` resolved: udp_multicast on the bench's own group gets a
    run-unique port, on a channel the user chose python-can's default port unless one is given (`resolve`); the
    CAN contract is read first: a broken DBC is one sentence before anything starts."""
    contract()
    config = resolve(config_from_args(args), session_unique=True)
    if config.interface == "virtual":  # python-can's virtual bus lives inside one process; the target is another
        raise UsageError("the 'virtual' interface does not cross processes; use udp_multicast, socketcan or auto")
    return config


def add_listener_argument(parser: argparse.ArgumentParser) -> None:
    """--wait-for-listener SECONDS: the logger line first, then a pause before anything is sent on the bus."""
    parser.add_argument("--wait-for-listener", type=positive_float, default=None, metavar="SECONDS",
                        help="print the 'python -m can.logger ...' line first (with --quiet too), then wait SECONDS "
                             "before anything is sent on the bus (a target is started, the host sends): the run's udp "
                             "port exists only for this run, so a logger started from that line during the wait "
                             "records all of it (or fix the bus beforehand: -c GROUP --bus-kwargs port=N)")


def announce_logger(bus: BusConfig, quiet: bool, prefix: str = "bench: ", wait_s: float | None = None) -> None:
    """On stderr (unless `quiet`), the line that records this bus with python-can's logger, ready to paste; with
    `wait_s` (--wait-for-listener) always, then the wait: nothing is on the bus yet, a listener started now misses
    nothing."""
    if not quiet or wait_s:
        print(f"{prefix}to record this bus with python-can: {logger_command(bus)}", file=sys.stderr, flush=True)
    if wait_s:
        print(f"{prefix}waiting {wait_s:g} s for a listener (e.g. the logger line above) before anything is sent "
              "on the bus", file=sys.stderr, flush=True)
        time.sleep(wait_s)
