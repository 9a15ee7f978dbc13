"""The base of the host node's errors (`DataRangeError`, `FaultSpecError`, `LogError`, `SessionError`).

One base per layer (`dbc.errors.CanLinkError`, `target_sim.errors.TargetError`, `bench.errors.BenchError`): a
command-line tool catches it once and prints its message, one sentence.
"""


class HostError(Exception):
    """A problem of the host node: its data, its fault options, its log, its session with the target; one sentence."""
