"""The base of the CAN link layer's errors (`DbcError`, `FrameError`, `BusUnavailable`, `OtherSender`).

Each layer has one: `dbc.errors.CanLinkError`, `target_sim.errors.TargetError`, `host.errors.HostError` and
`bench.errors.BenchError`. A command-line tool catches the bases once and prints the message, which is one
sentence saying what is wrong and what to do.
"""


class CanLinkError(Exception):
    """A problem of the CAN link layer: the contract (.dbc), a frame, or the bus; one sentence."""
