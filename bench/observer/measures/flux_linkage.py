"""The flux-linkage magnet temperature: calibration on training files and its readings per model step.

Calibration (`calibrate_flux`): on every model step of the training files at or above the speed threshold, least
squares of u_q/ω_e = ψ_0 + ψ_0 α_B (ϑ_m - ϑ_0) + L_d i_d + R_s0 (1 + α_cu (ϑ_w - ϑ_cu)) i_q/ω_e against the measured
magnet (pm_C) and winding (winding_C): linear in (ψ_0, ψ_0 α_B, L_d, R_s0). L_d and R_s0 are kept only where the
data determine them (relative standard error below `IDENTIFIABLE`); otherwise L_d is fixed (0 or the given value)
and R_s0 to the artifact's stator resistance. The residual, in kelvin of magnet temperature, is the calibration's
figure; its square is fitted as R_floor + R_speed·(n_min/n)² (the noise grows as the speed falls). A residual or a
fitted R_s0 that makes the readings useless is refused (`judge_calibration`) unless --flux-force is given.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bench.errors import BenchError
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
from target_sim.observer.measurements.flux_linkage import COLUMNS, RAD_S_PER_RPM

IDENTIFIABLE = 0.25          # largest relative standard error of L_d or R_s0 that the calibration keeps
DEFAULT_SPEED_MIN_RPM = 1500.0


@dataclass(frozen=True)
class FluxLinkage(FromVoltages):
    psi_0_Vs: float
    alpha_B_per_K: float
    theta_0_C: float
    L_d_H: float
    R_s_ohm: float
    alpha_cu_per_K: float
    copper_reference_C: float
    pole_pairs: float
    speed_min_rpm: float
    R_floor_C2: float
    R_speed_C2: float
    calibration: dict = field(default_factory=dict)
    kind: str = "flux-linkage"
    node: str = "magnet"
    name: str = "flux"
    warnings: tuple[str, ...] = field(default=(), compare=False)

    def readings(self, dataset, dt: float, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        means = step_means(dataset, ("speed_rpm", *COLUMNS), dt, steps)
        speed, _, u_q, i_d, i_q = means.T
        valid = np.abs(speed) >= self.speed_min_rpm
        omega = np.where(valid, self.pole_pairs * RAD_S_PER_RPM * speed, np.nan)
        slope = self.psi_0_Vs * self.alpha_B_per_K
        r0 = self.R_s_ohm * (1.0 - self.alpha_cu_per_K * self.copper_reference_C)
        z0 = self.theta_0_C + ((u_q - r0 * i_q) / omega - self.L_d_H * i_d - self.psi_0_Vs) / slope
        z1 = -self.R_s_ohm * self.alpha_cu_per_K * i_q / (omega * slope)
        ratio = self.speed_min_rpm / np.where(valid, speed, np.inf)
        rel = self.R_floor_C2 + self.R_speed_C2 * ratio * ratio
        return np.where(valid, z0, np.nan), np.where(valid, z1, 0.0), np.where(valid, rel, 1.0)

    def entry(self, dt: float, r_scale: float) -> dict:
        values = {"psi_0_Vs": self.psi_0_Vs, "alpha_B_per_K": self.alpha_B_per_K, "theta_0_C": self.theta_0_C,
                  "L_d_H": self.L_d_H, "R_s_ohm": self.R_s_ohm, "alpha_cu_per_K": self.alpha_cu_per_K,
                  "copper_reference_C": self.copper_reference_C, "pole_pairs": self.pole_pairs,
                  "speed_min_rpm": self.speed_min_rpm, "R_floor_C2": r_scale * self.R_floor_C2,
                  "R_speed_C2": r_scale * self.R_speed_C2}
        return self.voltage_entry(values)

    def describe(self) -> dict:
        return {"kind": self.kind, "node": self.node, "columns": list(self.columns), "psi_0_Vs": self.psi_0_Vs,
                "alpha_B_per_K": self.alpha_B_per_K, "L_d_H": self.L_d_H, "R_s_ohm": self.R_s_ohm,
                "speed_min_rpm": self.speed_min_rpm, **self.calibration}

    def calibration_text(self) -> str | None:
        cal = self.calibration
        return (f"flux linkage: psi_0 {self.psi_0_Vs:.5g} Vs, alpha_B {self.alpha_B_per_K:.4g} /K, "
                f"L_d {self.L_d_H:.4g} H, R_s {self.R_s_ohm:.4g} ohm (fitted {', '.join(cal['fitted'])}) on "
                f"{cal['steps']} steps at or above {self.speed_min_rpm:g} rpm; residual RMS "
                f"{cal['residual_rms_K']:.2f} K, max {cal['residual_max_K']:.1f} K")


# the entry's arrays in the order of FluxLinkage's fields
ENTRY_ARRAYS = ("psi_0_Vs", "alpha_B_per_K", "theta_0_C", "L_d_H", "R_s_ohm", "alpha_cu_per_K", "copper_reference_C",
                "pole_pairs", "speed_min_rpm", "R_floor_C2", "R_speed_C2")


class LabFluxLinkageKind(FromVoltagesKind):
    name = "flux-linkage"
    measurement = FluxLinkage      # R scales the calibrated R_floor + R_speed (n_min/n)²
    arrays = ENTRY_ARRAYS

    def add_arguments(self, parser) -> None:
        parser.add_argument("--flux", action="store_true",
                            help="add the flux-linkage magnet temperature (columns u_d_V, u_q_V, i_d_A, i_q_A), "
                                 "calibrated on the training files")
        parser.add_argument("--flux-min-speed", type=float, default=DEFAULT_SPEED_MIN_RPM, metavar="RPM",
                            help=f"the flux linkage is valid at or above this speed (default {DEFAULT_SPEED_MIN_RPM:g} "
                                 "rpm)")
        parser.add_argument("--flux-force", action="store_true",
                            help="use a flux-linkage calibration even where its residual or fitted R_s says it is "
                                 "useless (a warning instead of the refusal)")

    def from_arguments(self, args, artifact, datasets: Sequence) -> FluxLinkage | None:
        """The flux linkage calibrated on `datasets`, with the artifact's copper coefficient and, for an electrical
        loss model, its pole pairs and stator resistance; judged by its residual and fitted R_s."""
        if not args.flux:
            return None
        r_s_model = loss_value(artifact, "stator_resistance_ohm")
        flux = calibrate_flux(datasets, artifact.dt, pole_pairs_of(artifact, args.pole_pairs),
                              loss_value(artifact, "alpha_cu_per_K"), loss_value(artifact, "copper_reference_C"),
                              r_s_model, speed_threshold_ok(args.flux_min_speed))
        fitted = flux.R_s_ohm if "R_s0" in flux.calibration["fitted"] else None
        return replace(flux, warnings=judge_calibration(
            "flux-linkage", "magnet", flux.calibration, fitted, r_s_model,
            "check the voltage and current columns and --pole-pairs, or raise --flux-min-speed", "--flux-force",
            args.flux_force))


register(LabFluxLinkageKind())


def calibrate_flux(datasets: Sequence, dt: float, pole_pairs: float, alpha_cu: float, copper_reference: float,
                   r_s_prior: float | None, speed_min_rpm: float = DEFAULT_SPEED_MIN_RPM, theta_0: float = 20.0,
                   l_d_fixed: float = 0.0) -> FluxLinkage:
    """ψ_0, α_B (and L_d, R_s0 where the data allow) on the training files' steps at or above speed_min_rpm."""
    rows = training_steps(datasets, ("speed_rpm", "u_q_V", "i_d_A", "i_q_A", "pm_C", "winding_C"), dt,
                          "the flux-linkage calibration", required=COLUMNS)
    speed, u_q, i_d, i_q, magnet, winding = rows.T
    keep = (np.abs(speed) >= speed_min_rpm) & np.all(np.isfinite(rows), axis=1)
    if keep.sum() < 20:
        raise BenchError(f"the training files have {int(keep.sum())} model steps at or above {speed_min_rpm:g} rpm; "
                         "the flux-linkage calibration needs at least 20 (lower --flux-min-speed)")
    speed, u_q, i_d, i_q, magnet, winding = (v[keep] for v in (speed, u_q, i_d, i_q, magnet, winding))
    omega = pole_pairs * RAD_S_PER_RPM * speed
    y = u_q / omega
    columns = {"psi_0": np.ones_like(y), "slope": magnet - theta_0, "L_d": i_d,
               "R_s0": i_q * (1.0 + alpha_cu * (winding - copper_reference)) / omega}
    value, names, se, resid, fixed = identifiable_fit(
        y, columns, ("L_d", "R_s0"), IDENTIFIABLE,
        lambda n: l_d_fixed if n == "L_d" else (r_s_prior if r_s_prior is not None else 0.0))
    psi_0, slope = float(value["psi_0"]), float(value["slope"])
    if not (psi_0 > 0 and slope != 0):
        raise BenchError(f"the flux-linkage calibration found ψ_0 = {psi_0:.4g} Vs and dψ/dϑ = {slope:.3g} Vs/K; the "
                         "voltage columns do not carry the magnet's temperature")
    resid_k = resid / slope
    floor, per_speed = variance_fit(resid_k, speed_min_rpm / speed)
    calibration = {"steps": int(keep.sum()), "files": len(datasets), "fitted": names,
                   "fixed": {k: float(v) for k, v in fixed.items()},
                   "standard_error": {n: float(s) for n, s in zip(names, se, strict=True)},
                   **residual_figures(resid_k)}
    return FluxLinkage(psi_0, slope / psi_0, theta_0, float(value["L_d"]), float(value["R_s0"]), alpha_cu,
                       copper_reference, float(pole_pairs), speed_min_rpm, floor, per_speed, calibration)


def pole_pairs_of(artifact, given: float | None) -> float:
    """The pole pairs given (--pole-pairs), else the artifact's electrical loss model's, else 1."""
    return given if given is not None else (loss_value(artifact, "pole_pairs") or 1.0)


def speed_threshold_ok(value: float) -> float:
    if not (math.isfinite(value) and value > 0):
        raise BenchError("--flux-min-speed must be a positive number of rpm")
    return value
