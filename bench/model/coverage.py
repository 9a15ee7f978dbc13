"""Before a fit: does each file cover the operating range its role needs? Cheap checks of speed, torque and the
measured temperatures.

Why: the network's convection paths winding-magnet, tooth-magnet and magnet-air (R_wm, R_tm, R_ma) fall with speed
(R0·exp(−(n/n_max)/b), eq. 15), and the iron and magnet losses grow with it. A file that stays near standstill
shows none of that: as a validation file its figures say nothing about those terms, as the only kind of training
file it leaves them to the prior. A validation file at a small part of the training files' load checks the model
only at light load. A validation file hotter than every training file checks an extrapolation: the temperature-
dependent terms (copper resistance, eq. 3; the magnet's losses) are fitted only up to the training files' highest
temperature (on the motor suite's air-cooled motor, a validation profile 30 K above the training files' winding
maximum had its error grow to a −6.6 K bias in its last quarter). The command says so before the fit, in one
sentence per finding.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# A file checks the speed-dependent terms only if it reaches this share of the motor's top speed (limits.speed_rpm):
# eq. 15's exponentials and the iron losses run over the speed ratio n/n_max from 0 to 1, and a file below a fifth
# of it checks them on a small corner of their range only (a judgment, not a fitted figure).
SPEED_SHARE = 0.2
# A sample below this share of the top speed is at standstill (issue 37's measured standstill run: at most 31 rpm) ...
STANDSTILL_SHARE = 0.01
# ... and a file with at least this share of its samples there sees the speed-dependent terms only in brief bursts.
STANDSTILL_FRACTION = 0.9
# A validation file whose largest |torque| is below this share of the training files' checks only light load: the
# copper losses, roughly ∝ torque², stay below a sixteenth of the training files' peak there.
TORQUE_SHARE = 0.25
# A validation file whose measured winding or magnet temperature rises this far above every training file's checks
# the model beyond the range it was fitted on (a few kelvin: a sensor's noise and the files' differing starts).
HOTTER_BY_K = 10.0
# the measured temperatures checked, by the name a sentence uses
TEMPERATURE_COLUMNS = {"winding": "winding_C", "magnet": "pm_C"}

SPEED_TERMS = "the speed-dependent convection (R_wm, R_tm, R_ma) or the speed-dependent iron and magnet losses"


@dataclass(frozen=True)
class SpeedCoverage:
    name: str
    max_rpm: float
    standstill: float     # share of the samples at standstill

    def phrase(self) -> str:
        return (f"{self.name} (at most {self.max_rpm:.0f} rpm, at standstill in {100 * self.standstill:.0f} % of its "
                "samples)")


def speed_coverage(dataset, max_speed_rpm: float) -> SpeedCoverage | None:
    """The file's speed coverage when it is too little to check the speed-dependent terms, else None."""
    speed = np.abs(np.asarray(dataset.speed_rpm, float))
    top = float(speed.max()) if speed.size else 0.0
    standstill = float(np.mean(speed < STANDSTILL_SHARE * max_speed_rpm)) if speed.size else 1.0
    if top < SPEED_SHARE * max_speed_rpm or standstill >= STANDSTILL_FRACTION:
        return SpeedCoverage(Path(dataset.path).name, top, standstill)
    return None


def coverage_warnings(train: Sequence, validate: Sequence, max_speed_rpm: float) -> list[str]:
    """One sentence per finding: the validation files (some or all) and the training files (all of them) that
    cannot check or determine the speed-dependent terms, and validation files far below the training files' load."""
    warnings = []
    slow = [c for c in (speed_coverage(d, max_speed_rpm) for d in validate) if c is not None]
    if slow and len(slow) == len(validate):
        warnings.append(f"every validation file stays below {_limit(max_speed_rpm, 'its')}: "
                        f"{', '.join(c.phrase() for c in slow)}; the validation figures cannot check {SPEED_TERMS}")
    elif slow:
        many = len(slow) > 1
        warnings.append(f"the validation file{'s' if many else ''} {', '.join(c.phrase() for c in slow)} "
                        f"{'stay' if many else 'stays'} below {_limit(max_speed_rpm, 'their' if many else 'its')}, "
                        f"so {'they' if many else 'it'} cannot check {SPEED_TERMS}; the other validation files can")
    slow_train = [c for c in (speed_coverage(d, max_speed_rpm) for d in train) if c is not None]
    if train and len(slow_train) == len(train):
        warnings.append(f"every training file stays below {_limit(max_speed_rpm, 'its')}: "
                        f"{', '.join(c.phrase() for c in slow_train)}; the fit cannot determine {SPEED_TERMS}, so "
                        "their values will be the prior's")
    warnings.extend(_light_load(train, validate))
    warnings.extend(_hotter(train, validate))
    return warnings


def _limit(max_speed_rpm: float, own: str) -> str:
    return (f"{100 * SPEED_SHARE:.0f} % of the motor's {max_speed_rpm:.0f} rpm (or at standstill in "
            f"{100 * STANDSTILL_FRACTION:.0f} % of {own} samples)")


def _light_load(train: Sequence, validate: Sequence) -> list[str]:
    trained = max((float(np.abs(np.asarray(d.torque_Nm, float)).max(initial=0.0)) for d in train), default=0.0)
    warnings = []
    for d in validate:
        top = float(np.abs(np.asarray(d.torque_Nm, float)).max(initial=0.0))
        if top < TORQUE_SHARE * trained:
            warnings.append(f"the validation file {Path(d.path).name} reaches at most {top:.0f} Nm, under "
                            f"{100 * TORQUE_SHARE:.0f} % of the training files' {trained:.0f} Nm, so it checks the "
                            "model only at light load, not the copper losses and loss split it was trained on")
    return warnings


def _hotter(train: Sequence, validate: Sequence) -> list[str]:
    """A sentence per validation file hotter than every training file by HOTTER_BY_K at a measured node."""
    warnings = []
    for node, column in TEMPERATURE_COLUMNS.items():
        trained = max((_top(d, column) for d in train), default=None)
        if trained is None:
            continue
        for d in validate:
            top = _top(d, column)
            if top is not None and top > trained + HOTTER_BY_K:
                warnings.append(f"the validation file {Path(d.path).name} reaches {top:.0f} °C at the {node}, "
                                f"{top - trained:.0f} K above the training files' {trained:.0f} °C, so its figures "
                                "check an extrapolation of the temperature-dependent terms; add a training file "
                                "that hot if the motor runs there")
    return warnings


def _top(dataset, column: str) -> float | None:
    """The file's highest value of `column` (None when it does not measure it)."""
    if not dataset.has(column):
        return None
    return float(np.max(np.asarray(dataset.column(column), float), initial=-np.inf))
