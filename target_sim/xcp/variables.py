"""What the Python node shows a calibration engineer: its measurements and its calibratable parameters, each a
float32 cell bound to the engine's own variable, with the C node's symbol where the C has one.

Measurements (read-only):

| name           | C symbol         | what                                                        |
|----------------|------------------|-------------------------------------------------------------|
| x_state_<i>    | x_state          | the model's state vector x (the realization's coordinates)  |
| y_est_<i>      | y_est            | the model's temperatures y = C x: yoke, winding, tooth, PM  |
|                |                  | (without an observer's output bias)                         |
| estimate_<i>   | estimate         | the node's latest reported estimate, what Temperatures1/2   |
|                |                  | carry: y, with an observer's output bias added to its node  |
|                |                  | (`AugmentedLayout.reported`); DAQ this to see the reply     |
| obs_extra_<i>  | obs_extra[4 + i] | an observer's extra states: each lag state, then the bias   |
| obs_sigma_<i>  | obs_sigma        | each node's 1-σ (°C) as Uncertainty1/2 carry it             |
| obs_innov_<k>  | obs_innovation   | each measurement's innovation of the last step (NaN: none)  |

Calibration (DOWNLOAD; each value finite and within its limits, checked before it is written):

| name                | limits          | C symbol         | what                                            |
|---------------------|-----------------|------------------|-------------------------------------------------|
| cal_alpha_cu        | 0 .. 0.01 1/K   | fw_cal_alpha_cu  | copper temperature coefficient of the loss      |
|                     |                 |                  | correction (eq. 3)                              |
| cal_sensor<k>_offset| -20 .. 20 °C    | obs_offset_<k>   | measurement k's sensor offset (a lagged         |
|                     |                 |                  | sensor's offset_C)                              |
| cal_sensor<k>_lag   | 0 .. 0.9999     | obs_lag_pole_<k> | its lag pole a = exp(-Δt/τ) (only a sensor with |
|                     |                 |                  | a lag)                                          |
| cal_sensor<k>_r     | 1e-6 .. 1e4 °C² | obs_r_<k>        | its measurement variance R                      |
| cal_q_<i>           | 1e-12 .. 1e4    | obs_q            | the observer's process noise Q (node            |
|                     |                 |                  | coordinates, diagonal); only an element that is |
|                     |                 |                  | not 0 (a zero is the filter's structure) and    |
|                     |                 |                  | not in the steady-state form (its gain is       |
|                     |                 |                  | fixed)                                          |

A cell calibrated during a run changes the next model step on; a RESET keeps it (the engine's own variables hold it).
Every cell has its C symbol: the generated observer C (bench/firmware/observergen.py) holds these variables in RAM
and reads the calibratable ones at every step, so both engines serve the same bytes at the A2L's addresses.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from target_sim.artifact import OUTPUTS

F32 = np.float32
ALPHA_CU_LIMITS = (0.0, 0.01)
OFFSET_LIMITS = (-20.0, 20.0)
LAG_LIMITS = (0.0, 0.9999)
R_LIMITS = (1e-6, 1e4)
Q_LIMITS = (1e-12, 1e4)
ALPHA_CU_SYMBOL = "fw_cal_alpha_cu"     # the generated model's calibratable alpha_cu (bench/firmware/codegen.py)
# the generated observer's variables (bench/firmware/observergen.py); a per-measurement scalar is <name>_<k>
EXTRA_SYMBOL = "obs_extra"              # the filter's states from index 4 on (the model's 4 are x_state)
SIGMA_SYMBOL = "obs_sigma"
INNOVATION_SYMBOL = "obs_innovation"
Q_SYMBOL = "obs_q"
OFFSET_SYMBOL = "obs_offset"
LAG_SYMBOL = "obs_lag_pole"
R_SYMBOL = "obs_r"


@dataclass(frozen=True)
class CellSpec:
    """A cell before it has an address: its name, the C symbol and element it mirrors (None: the slave's page)."""

    name: str
    read: Callable[[], float]
    write: Callable[[float], None] | None = None
    limits: tuple[float, float] = (float("-inf"), float("inf"))
    unit: str = ""
    comment: str = ""
    symbol: str | None = None
    index: int = 0


def _element(get: Callable[[], np.ndarray], i: int) -> Callable[[], float]:
    return lambda: float(get()[i])


def _measurements(node) -> list[CellSpec]:
    specs = []
    for symbol, get, what in (("x_state", lambda: node.model.x, "model state x"),
                              ("y_est", lambda: node.model.y, "model temperature (no output bias)"),
                              ("estimate", lambda: node.estimate, "reported estimate (the CAN reply's)")):
        for i in range(len(OUTPUTS)):
            unit = "" if symbol == "x_state" else "degC"
            comment = f"{what} [{i}]" if symbol == "x_state" else f"{what}: {OUTPUTS[i]}"
            specs.append(CellSpec(f"{symbol}_{i}", _element(get, i), unit=unit, comment=comment, symbol=symbol,
                                  index=i))
    observer = node.observer
    if observer is None:
        return specs
    filt = observer.filter
    for i in range(len(filt.extra)):
        specs.append(CellSpec(f"obs_extra_{i}", _element(lambda: filt.extra, i), unit="degC",
                              comment="observer extra state (lag states, then the bias)", symbol=EXTRA_SYMBOL,
                              index=len(OUTPUTS) + i))
    for i in range(len(OUTPUTS)):
        specs.append(CellSpec(f"obs_sigma_{i}", _element(filt.sigma, i), unit="degC",
                              comment=f"observer 1-sigma: {OUTPUTS[i]}", symbol=SIGMA_SYMBOL, index=i))
    for k in range(len(filt.measurements)):
        specs.append(CellSpec(f"obs_innov_{k}", _element(lambda: filt.innovations, k), unit="degC",
                              comment=f"innovation of measurement {k} ({filt.measurements[k].name})",
                              symbol=INNOVATION_SYMBOL, index=k))
    return specs


def _setter(obj, attribute: str) -> Callable[[float], None]:
    def write(value: float) -> None:
        setattr(obj, attribute, F32(value))
    return write


def _calibrations(node) -> list[CellSpec]:
    est = node.model
    specs = [CellSpec("cal_alpha_cu", lambda: float(est.alpha_cu), _setter(est, "alpha_cu"), ALPHA_CU_LIMITS,
                      "1/K", "copper temperature coefficient of the loss correction (eqs. 3-5)",
                      symbol=ALPHA_CU_SYMBOL)]
    if node.observer is None:
        return specs
    filt = node.observer.filter
    for k, m in enumerate(filt.measurements):
        if hasattr(m, "offset"):
            specs.append(CellSpec(f"cal_sensor{k}_offset", lambda m=m: float(m.offset), _setter(m, "offset"),
                                  OFFSET_LIMITS, "degC", f"sensor offset of measurement {k} ({m.name})",
                                  symbol=f"{OFFSET_SYMBOL}_{k}"))
        if float(getattr(m, "lag_pole", 0.0)) > 0:    # a lag of 0 has no lag state: the filter's structure
            specs.append(CellSpec(f"cal_sensor{k}_lag", lambda m=m: float(m.lag_pole), _setter(m, "lag_pole"),
                                  (float(np.nextafter(F32(0), F32(1))), LAG_LIMITS[1]), "",
                                  f"lag pole exp(-dt/tau) of measurement {k} ({m.name})", symbol=f"{LAG_SYMBOL}_{k}"))
        if hasattr(m, "r"):
            specs.append(CellSpec(f"cal_sensor{k}_r", lambda m=m: float(m.r), _setter(m, "r"), R_LIMITS, "degC^2",
                                  f"measurement variance R of measurement {k} ({m.name})", symbol=f"{R_SYMBOL}_{k}"))
    for i in range(filt.n):
        writable = filt.form != "steady" and float(filt.q_nodes[i]) != 0.0
        specs.append(CellSpec(f"cal_q_{i}", _element(lambda: filt.q_nodes, i),
                              (lambda v, i=i: filt.set_process_noise(i, v)) if writable else None,
                              Q_LIMITS if writable else (float("-inf"), float("inf")), "degC^2",
                              f"process noise Q[{i},{i}] (node coordinates)"
                              + ("" if writable else ", read-only"), symbol=Q_SYMBOL, index=i))
    return specs


def node_cells(node) -> tuple[list[CellSpec], list[CellSpec]]:
    """(measurements, calibrations) of a Python target node (`target_sim.node.TargetNode`)."""
    return _measurements(node), _calibrations(node)
