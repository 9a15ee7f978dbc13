"""What the training data do not determine: the LPTN parameters the polish's standard errors call unidentifiable
(`polish.uncertainty`: a relative standard error above `polish.UNIDENTIFIED_LOG_SE`, a factor of 2, or above half
the search range, or an uninformative direction) and the pairs so correlated that only their combination is
determined, grouped by the side of the network they belong to, with what that means for the estimate.

Why grouped: a user reads "C_m, R_tm0, a_tm, R_ma0, a_ma" as five numbers; "the magnet side" says that the magnet
estimate rests on the prior there, and which training data would determine it.
"""

from __future__ import annotations

from dataclasses import dataclass

from bench.model.polish import UNIDENTIFIED_LOG_SE, UNIDENTIFIED_RANGE_SHARE
from bench.thermal.parameters import LptnParameters

# |r| at or above which two parameters are one direction for the data: at 0.999 (equal standard errors) their sum
# or difference is known about 20 times better than either of them, so the data fix only the combination
COMBINATION_CORRELATION = 0.999


@dataclass(frozen=True)
class Side:
    """A part of the network: its parameters, what an undetermined one means and which data would determine it."""

    label: str
    parameters: tuple[str, ...]
    consequence: str
    remedy: str


SIDES = {
    "magnet": Side("on the magnet side", ("C_m", "R_wm0", "a_wm", "b_wm", "R_tm0", "a_tm", "b_tm", "R_ma0", "a_ma",
                                          "b_ma"),
                   "the magnet estimate rests on the prior",
                   "add training profiles that heat the magnet differently from the winding: high speed at low "
                   "torque"),
    "stator": Side("on the stator side", ("C_y", "C_w", "C_t", "R_yw", "R_yt", "R_wt", "R_cy0", "alpha_cy"),
                   "the winding estimate rests on the prior",
                   "add training profiles with load steps and cool-downs at several coolant temperatures"),
    "loss_split": Side("in the stator iron-loss split", ("k_0", "k_1", "k_2", "k_3"),
                       "how the iron loss divides between yoke and tooth rests on the prior",
                       "add training profiles across the current and speed range"),
}


def undetermined(record: dict | None) -> dict | None:
    """{parameters, correlated_pairs, sides, sentence} from an `uncertainty` record, None when the data determine
    every parameter (or there is no record: no polish)."""
    if not record:
        return None
    names, corr = record["names"], record["correlation"]
    pairs = [{"parameters": [names[i], names[j]], "r": corr[i][j]}
             for i in range(len(names)) for j in range(i + 1, len(names))
             if abs(corr[i][j]) >= COMBINATION_CORRELATION]
    flagged = set(record["unidentifiable"]) | {n for p in pairs for n in p["parameters"]}
    parameters = [n for n in LptnParameters.names() if n in flagged]
    if not parameters:
        return None
    sides = {key: [n for n in side.parameters if n in flagged] for key, side in SIDES.items()}
    sides = {key: names for key, names in sides.items() if names}
    return {"parameters": parameters, "correlated_pairs": pairs, "sides": sides,
            "sentence": _sentence(parameters, pairs, sides),
            "rule": {"relative_se_above": UNIDENTIFIED_LOG_SE, "or_se_above_share_of_range": UNIDENTIFIED_RANGE_SHARE,
                     "correlation_at_least": COMBINATION_CORRELATION}}


def _sentence(parameters: list[str], pairs: list[dict], sides: dict[str, list[str]]) -> str:
    parts = [f"{SIDES[key].label} {', '.join(names)}, where {SIDES[key].consequence} ({SIDES[key].remedy})"
             for key, names in sides.items()]
    combined = [f"of {a} and {b} only their combination is determined (r = {p['r']:+.5f})"
                for p in pairs for a, b in [p["parameters"]]]
    return (f"the training data do not determine {len(parameters)} of the {len(LptnParameters.names())} LPTN "
            f"parameters: " + "; ".join(parts + combined))
