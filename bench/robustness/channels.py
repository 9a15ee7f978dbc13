"""The inputs a perturbation can act on: the drive channels the model reads (torque, speed, coolant, ambient, the
d/q currents of an electrical loss model) and the measurement channels of an observer.

An observer (a Kalman filter correcting the model with a measured temperature, issue 25) is not built yet:
`observer_channels` is the hook that will name its measured channels and is empty today, so every input kind
already covers them the day an artifact carries them.
"""

from __future__ import annotations

from dataclasses import dataclass

from target_sim.artifact import ModelArtifact


@dataclass(frozen=True)
class Channel:
    """One input as a perturbation sees it: its name in a spec, the data column and its unit."""

    name: str
    column: str
    unit: str
    full_scale: float      # a traction drive's range of the signal: the scale of the default magnitudes


DRIVE_CHANNELS = {c.column: c for c in (
    Channel("torque", "torque_Nm", "Nm", 640.0),
    Channel("speed", "speed_rpm", "rpm", 9000.0),
    Channel("coolant", "coolant_C", "K", 100.0),
    Channel("ambient", "ambient_C", "K", 60.0),
    Channel("i_d", "i_d_A", "A", 800.0),
    Channel("i_q", "i_q_A", "A", 800.0),
)}
CHANNEL_NAMES = tuple(c.name for c in DRIVE_CHANNELS.values())


def observer_channels(artifact: ModelArtifact) -> tuple[Channel, ...]:
    """The measured channels an observer artifact corrects its estimate with (none until observers exist)."""
    return ()


def input_channels(artifact: ModelArtifact) -> tuple[Channel, ...]:
    """The channels of this model, in the order of its drive rows, then the observer's."""
    return (*(DRIVE_CHANNELS[column] for column in artifact.drive_signals), *observer_channels(artifact))


def channel_index(artifact: ModelArtifact, name: str) -> int:
    """The drive-row column of channel `name` for this model."""
    for index, column in enumerate(artifact.drive_signals):
        if DRIVE_CHANNELS[column].name == name:
            return index
    raise KeyError(name)
