"""bus_load: the bench's share of the bus (%), at the data rate (default) or the replay's peak, at most `max`.

    [criteria.bus]
    kind = "bus_load"
    at = "data_rate"          # "data_rate": the frames of one data row per sample period; "replay_peak": the
    max = 30                  #  busiest window of this replay (lockstep runs faster than the data rate)
"""

from __future__ import annotations

from bench.acceptance.kinds import register
from bench.acceptance.kinds._base import Criterion, Kind, Subject, judged
from bench.analysis.results import CheckResult
from bench.tomlspec import choice


def judge(criterion: Criterion, subject: Subject) -> CheckResult:
    load = subject.results.bus_load
    at = criterion.params["at"]
    figure = load.data_rate_percent if at == "data_rate" else load.replay_peak_percent
    what = f"bus load at {load.bitrate / 1000:g} kbit/s ({at.replace('_', ' ')})"
    return judged(criterion, "%", what, figure, why_none="the log has too few frames to measure it")


KIND = Kind("bus_load", "the bench's share of the bus, at the data rate or the replay's peak", "%", judge,
            options={"at": choice("data_rate", "replay_peak")}, defaults={"at": "data_rate"})

register(KIND)
