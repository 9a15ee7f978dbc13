"""The winding temperature from the stator resistance: calibration on training files and its readings per model step.

Calibration (`calibrate_resistance`): on every model step of the training files at or below the speed limit and
where |i_d| is at least the current limit, least squares of u_d = R_s0 (1 + α_cu (ϑ_w - ϑ_cu)) i_d - L_q ω_e i_q
against the measured winding (winding_C): linear in (R_s0, L_q). L_q is kept only where the data determine it
(relative standard error below `IDENTIFIABLE`, as the flux linkage's L_d), else fixed (0 or the given value); an
R_s0 the data do not determine, or too few valid steps, is one sentence ("where the data allow it"). The residual,
in kelvin of winding temperature (δu/(i_d R_s0 α_cu)), is the calibration's figure; its square is fitted as
R_floor + R_current·(i_min/i_d)² (the noise grows as |i_d| falls). A residual, or an R_s0 far from the model's
stator resistance, that makes the readings useless is refused (`judge_calibration`) unless --resistance-force is
given.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bench.errors import BenchError, UsageError
from bench.observer.measures import (
    FromVoltages,
    FromVoltagesKind,
    identifiable_fit,
    judge_calibration,
    loss_value,
    register,
    residual_figures,
    step_means,
    training_steps,
    variance_fit,
)
from bench.observer.measures.flux_linkage import IDENTIFIABLE, pole_pairs_of
from target_sim.observer.measurements.flux_linkage import COLUMNS, RAD_S_PER_RPM
from target_sim.observer.measurements.winding_resistance import PARAMETERS

DEFAULT_SPEED_MAX_RPM = 2000.0
DEFAULT_CURRENT_MIN_A = 50.0
MIN_STEPS = 20                # fewest valid training steps the calibration takes


@dataclass(frozen=True)
class WindingResistance(FromVoltages):
    R_s_ohm: float
    alpha_cu_per_K: float
    copper_reference_C: float
    L_q_H: float
    pole_pairs: float
    speed_max_rpm: float
    current_min_A: float
    R_floor_C2: float
    R_current_C2: float
    calibration: dict = field(default_factory=dict)
    kind: str = "winding-resistance"
    node: str = "winding"
    name: str = "resistance"
    warnings: tuple[str, ...] = field(default=(), compare=False)

    def valid(self, speed: np.ndarray, i_d: np.ndarray) -> np.ndarray:
        """The steps the reading is valid on (NaN fails both comparisons)."""
        return (np.abs(speed) <= self.speed_max_rpm) & (np.abs(i_d) >= self.current_min_A)

    def readings(self, dataset, dt: float, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        means = step_means(dataset, ("speed_rpm", *COLUMNS), dt, steps)
        speed, u_d, u_q, i_d, i_q = means.T
        valid = self.valid(speed, i_d) & np.isfinite(u_d) & np.isfinite(u_q) & np.isfinite(i_q)
        i_d_ok = np.where(valid, i_d, np.inf)
        r_s = (u_d + self.pole_pairs * RAD_S_PER_RPM * speed * self.L_q_H * i_q) / i_d_ok
        z0 = self.copper_reference_C + (r_s / self.R_s_ohm - 1.0) / self.alpha_cu_per_K
        ratio = self.current_min_A / i_d_ok
        rel = self.R_floor_C2 + self.R_current_C2 * ratio * ratio
        return np.where(valid, z0, np.nan), np.zeros_like(z0), np.where(valid, rel, 1.0)

    def entry(self, dt: float, r_scale: float) -> dict:
        values = {k: getattr(self, k) for k in PARAMETERS} | {"R_floor_C2": r_scale * self.R_floor_C2,
                                                              "R_current_C2": r_scale * self.R_current_C2}
        return self.voltage_entry(values)

    def describe(self) -> dict:
        return {"kind": self.kind, "node": self.node, "columns": list(self.columns), "R_s_ohm": self.R_s_ohm,
                "L_q_H": self.L_q_H, "speed_max_rpm": self.speed_max_rpm, "current_min_A": self.current_min_A,
                **self.calibration}

    def calibration_text(self) -> str | None:
        cal = self.calibration
        return (f"winding resistance: R_s {self.R_s_ohm:.5g} ohm, L_q {self.L_q_H:.4g} H (fitted "
                f"{', '.join(cal['fitted'])}) on {cal['steps']} steps at or below {self.speed_max_rpm:g} rpm with "
                f"|i_d| >= {self.current_min_A:g} A; residual RMS {cal['residual_rms_K']:.2f} K, max "
                f"{cal['residual_max_K']:.1f} K")


class LabWindingResistanceKind(FromVoltagesKind):
    name = "winding-resistance"
    measurement = WindingResistance      # R scales the calibrated R_floor + R_current (i_min/i_d)²
    arrays = PARAMETERS

    def add_arguments(self, parser) -> None:
        parser.add_argument("--resistance", action="store_true",
                            help="add the winding temperature from the stator resistance (columns u_d_V, u_q_V, i_d_A, "
                                 "i_q_A), calibrated on the training files")
        parser.add_argument("--resistance-max-speed", type=float, default=DEFAULT_SPEED_MAX_RPM, metavar="RPM",
                            help="the resistance reading is valid at or below this speed "
                                 f"(default {DEFAULT_SPEED_MAX_RPM:g} rpm)")
        parser.add_argument("--resistance-min-current", type=float, default=DEFAULT_CURRENT_MIN_A, metavar="A",
                            help="... and where |i_d| is at least this current "
                                 f"(default {DEFAULT_CURRENT_MIN_A:g} A)")
        parser.add_argument("--resistance-force", action="store_true",
                            help="use a winding-resistance calibration even where its residual or R_s says it is "
                                 "useless (a warning instead of the refusal)")

    def from_arguments(self, args, artifact, datasets: Sequence) -> WindingResistance | None:
        if not args.resistance:
            return None
        for option, value in (("--resistance-max-speed", args.resistance_max_speed),
                              ("--resistance-min-current", args.resistance_min_current)):
            if not (math.isfinite(value) and value > 0):
                raise UsageError(f"{option} must be a positive number")
        fit = calibrate_resistance(datasets, artifact.dt, pole_pairs_of(artifact, args.pole_pairs),
                                   loss_value(artifact, "alpha_cu_per_K"), loss_value(artifact, "copper_reference_C"),
                                   args.resistance_max_speed, args.resistance_min_current)
        r_s_model = loss_value(artifact, "stator_resistance_ohm")
        return replace(fit, warnings=judge_calibration(
            "winding-resistance", "winding", fit.calibration, fit.R_s_ohm, r_s_model,
            "check the voltage and current columns and --pole-pairs, or lower --resistance-max-speed or raise "
            "--resistance-min-current", "--resistance-force", args.resistance_force))


register(LabWindingResistanceKind())


def calibrate_resistance(datasets: Sequence, dt: float, pole_pairs: float, alpha_cu: float | None,
                         copper_reference: float | None, speed_max_rpm: float = DEFAULT_SPEED_MAX_RPM,
                         current_min_a: float = DEFAULT_CURRENT_MIN_A, l_q_fixed: float = 0.0) -> WindingResistance:
    """R_s0 (and L_q where the data allow) on the training files' steps at or below speed_max_rpm with
    |i_d| ≥ current_min_a, against the measured winding."""
    if alpha_cu is None or copper_reference is None:
        raise BenchError("the winding-resistance calibration needs the copper's temperature coefficient and reference "
                         "(alpha_cu_per_K, copper_reference_C), and the model's loss model has none; use a model with "
                         "an electrical loss model")
    rows = training_steps(datasets, ("speed_rpm", "u_d_V", "i_d_A", "i_q_A", "winding_C"), dt,
                          "the winding-resistance calibration", required=COLUMNS)
    speed, u_d, i_d, i_q, winding = rows.T
    keep = ((np.abs(speed) <= speed_max_rpm) & (np.abs(i_d) >= current_min_a)
            & np.all(np.isfinite(rows), axis=1))
    if keep.sum() < MIN_STEPS:
        raise UsageError(f"the training files have {int(keep.sum())} model steps at or below {speed_max_rpm:g} rpm "
                         f"with |i_d| of at least {current_min_a:g} A; the winding-resistance calibration needs at "
                         f"least {MIN_STEPS} (raise --resistance-max-speed or lower --resistance-min-current)")
    speed, u_d, i_d, i_q, winding = (v[keep] for v in (speed, u_d, i_d, i_q, winding))
    omega = pole_pairs * RAD_S_PER_RPM * speed
    columns = {"R_s0": i_d * (1.0 + alpha_cu * (winding - copper_reference)), "L_q": -omega * i_q}
    value, names, se, resid, fixed = identifiable_fit(u_d, columns, ("L_q",), IDENTIFIABLE, lambda _: l_q_fixed)
    r_s0 = float(value["R_s0"])
    r_se = float(se[names.index("R_s0")])
    if not (r_s0 > 0 and r_se < IDENTIFIABLE * r_s0):
        raise UsageError(f"the winding-resistance calibration found R_s0 = {r_s0:.4g} ± {r_se:.2g} ohm on "
                         f"{int(keep.sum())} steps; the voltage columns do not carry the winding's resistance")
    resid_k = resid / (i_d * r_s0 * alpha_cu)
    floor, per_current = variance_fit(resid_k, current_min_a / i_d)
    calibration = {"steps": int(keep.sum()), "files": len(datasets), "fitted": names,
                   "fixed": {k: float(v) for k, v in fixed.items()},
                   "standard_error": {n: float(s) for n, s in zip(names, se, strict=True)},
                   **residual_figures(resid_k)}
    return WindingResistance(r_s0, alpha_cu, copper_reference, float(value["L_q"]), float(pole_pairs),
                             speed_max_rpm, current_min_a, floor, per_current, calibration)
