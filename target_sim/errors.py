"""The base of the target node's errors (`ArtifactError`, `FirmwareError`, `FirmwareFault`, `JournalError`).

One base per layer (`dbc.errors.CanLinkError`, `host.errors.HostError`, `bench.errors.BenchError`): a command-line
tool catches it once and prints its message, one sentence.
"""


class TargetError(Exception):
    """A problem of the target node: its model artifact, its firmware image or core, its files; one sentence."""
