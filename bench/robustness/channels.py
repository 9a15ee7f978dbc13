"""The inputs a perturbation can act on: the drive channels the model reads (torque, speed, coolant, ambient, the
d/q currents of an electrical loss model) and the measurement channels of an observer (issue 25: a stator NTC, the
winding column, the voltages and currents of the flux linkage).

A lane's rows (`lane_columns`) are the model's drive columns, then the observer's raw measurement columns the drive
does not already carry (a flux linkage's i_d_A and i_q_A are the loss model's own currents: perturbing them moves
both). A measurement channel is named by its data column (`ntc_C`, `u_q_V`), so it never clashes with a node.
"""

from __future__ import annotations

from dataclasses import dataclass

from target_sim.artifact import ModelArtifact
from target_sim.observer import has_observer


@dataclass(frozen=True)
class Channel:
    """One input as a perturbation sees it: its name in a spec, the data column and its unit."""

    name: str
    column: str
    unit: str
    full_scale: float      # a traction drive's range of the signal: the scale of the default magnitudes
    measured: bool = False  # a measurement channel of the observer: a dropped sample is a missing reading


DRIVE_CHANNELS = {c.column: c for c in (
    Channel("torque", "torque_Nm", "Nm", 640.0),
    Channel("speed", "speed_rpm", "rpm", 9000.0),
    Channel("coolant", "coolant_C", "K", 100.0),
    Channel("ambient", "ambient_C", "K", 60.0),
    Channel("i_d", "i_d_A", "A", 800.0),
    Channel("i_q", "i_q_A", "A", 800.0),
)}
CHANNEL_NAMES = tuple(c.name for c in DRIVE_CHANNELS.values())
# a measurement column's unit and a traction drive's full scale of it, by the column's unit suffix
MEASUREMENT_UNITS = {"_C": ("K", 100.0), "_V": ("V", 400.0), "_A": ("A", 800.0)}


def measurement_columns(artifact: ModelArtifact) -> tuple[str, ...]:
    """The raw columns of the observer's measurements in the order it takes them (none without an observer)."""
    if not has_observer(artifact):
        return ()
    from bench.observer.measured import measurement_columns as columns

    return tuple(columns(artifact))


def _measurement_channel(column: str) -> Channel:
    unit, scale = next((v for suffix, v in MEASUREMENT_UNITS.items() if column.endswith(suffix)), ("", 1.0))
    return Channel(column, column, unit, scale, measured=True)


def observer_columns(artifact: ModelArtifact) -> tuple[str, ...]:
    """The observer's measurement columns the drive rows do not carry already."""
    return tuple(c for c in dict.fromkeys(measurement_columns(artifact)) if c not in artifact.drive_signals)


def observer_channels(artifact: ModelArtifact) -> tuple[Channel, ...]:
    """The measured channels an observer artifact corrects its estimate with (beyond the drive's own)."""
    return tuple(_measurement_channel(c) for c in observer_columns(artifact))


def lane_columns(artifact: ModelArtifact) -> tuple[str, ...]:
    """The data columns of a lane's rows: the drive's, then the observer's own measurement columns."""
    return (*artifact.drive_signals, *observer_columns(artifact))


def input_channels(artifact: ModelArtifact) -> tuple[Channel, ...]:
    """The channels of this model, in the order of its lane columns."""
    return (*(DRIVE_CHANNELS[column] for column in artifact.drive_signals), *observer_channels(artifact))


def channel_index(artifact: ModelArtifact, name: str) -> int:
    """The lane column of channel `name` for this model."""
    for index, channel in enumerate(input_channels(artifact)):
        if channel.name == name:
            return index
    raise KeyError(name)


def observer_description(artifact: ModelArtifact) -> dict | None:
    """What the artifact's observer measures, for the report: its form, each measurement (kind, columns, the node it
    reads) and the measured nodes (their errors are not estimates); None without an observer."""
    if not has_observer(artifact):
        return None
    from bench.observer.measured import measured_nodes_of
    from target_sim.observer import measurement_entries

    section = artifact.content["observer"]
    return {"form": section.get("form"), "measured_nodes": measured_nodes_of(artifact),
            "measurements": [{"kind": e["kind"], "columns": list(e["columns"]), "node": e.get("node")}
                             for e in measurement_entries(section)]}
