"""The artifact's `observer` section of a tuned fit (`observer_section`), and the artifact with it
(`with_observer`); what `bench observer` writes unless told otherwise is in `bench.observer.choices`.

Measurements (section version 2) are a list of `target_sim.observer.measurements` kinds, their lab side in
`bench.observer.measures`: a lagged sensor (an NTC: its lag τ becomes a state of the filter, its offset is known from
the motor file and subtracted, its gradient says what it sees) and the flux-linkage magnet temperature
(calibrated on the training files). `bias` adds a heat-bias state of a kind of `target_sim.artifact.BIAS_KINDS`
(W into one node the loss model misses, a random walk): "winding-heat" (True: the winding, as before), so a
sensor's persistent disagreement with the winding model heats or cools the winding instead of pushing the magnet,
or "magnet-heat", so a persistent magnet-side model error (a magnet loss or coupling error) can be absorbed.
`consider` ("magnet", `target_sim.artifact.CONSIDER_KINDS`) makes the magnet node and a magnet bias consider states
(Schmidt-Kalman): a measurement that does not read the magnet never updates them, so a winding sensor cannot move
the magnet through a winding-magnet covariance the model has wrong; the filter's covariance is that of the gain
actually used, and K_ss, P_ss the consider filter's steady state (`bench.thermal.kalman.steady_state`). Each
measurement's R is a tuned scale of its per-step variance (1 for a sensor, the flux linkage's calibrated R_floor +
R_speed (n_min/n)²). The steady-state gain K_ss and covariance P_ss are the Riccati solution at the training runs'
median speed and mean coolant temperature (`nominal_transition`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bench.drive.dataset import Dataset
from bench.errors import BenchError
from bench.model.artifact_values import artifact_loss_model
from bench.model.runs import model_run
from bench.observer.choices import DEFAULT_BIAS, DEPLOYED_FORM
from bench.observer.reference import (
    BIAS_NAMES,
    BIAS_RULES,
    INITIAL_SIGMA_C,
    FilterModel,
    bias_kind,
    filter_data,
    initial_covariance,
    process_noise,
)
from bench.observer.tune import TUNING_REFERENCE, ObserverFit, listed
from bench.thermal.kalman import (
    augmented_transition,
    consider_projections,
    measurement_rows,
    source_jacobian,
    steady_state,
)
from target_sim.artifact import (
    BIAS_KINDS,
    CONSIDER_KINDS,
    OBSERVER_SECTION_VERSIONS,
    OUTPUTS,
    ModelArtifact,
    encode_array,
    schema_version_of,
    seal,
    verify,
)
from target_sim.network import COOLANT_REFERENCE_C


def nominal_transition(artifact: ModelArtifact, model: FilterModel, datasets: Sequence[Dataset]) -> tuple:
    """F (shift form) at the training runs' median speed ratio and mean coolant temperature, and that point."""
    loss_model, motor = artifact_loss_model(artifact)
    runs = [model_run(d, loss_model, motor, artifact.dt) for d in datasets]
    ratio = float(np.median(np.concatenate([r.inputs.speed_ratio for r in runs])))
    coolant = float(np.mean(np.concatenate([r.inputs.coolant for r in runs])))
    th = model.theta
    g_wm = th[4] * np.exp(-ratio / th[5]) / th[6]
    g_tm = th[7] * np.exp(-ratio / th[8]) / th[9]
    g_ma = th[10] * np.exp(-ratio / th[11]) / th[12]
    g_cy = th[13] * (coolant - COOLANT_REFERENCE_C)
    f = model.a + model.b[:, 4:] @ source_jacobian([g_tm, g_wm, g_ma, g_cy]) @ model.c
    return f, {"speed_ratio": ratio, "coolant_C": coolant}


def default_bias(measurements) -> str | None:
    """`DEFAULT_BIAS` when a measurement reads its node (an output bias nobody reads would never move), else None."""
    node = BIAS_KINDS[DEFAULT_BIAS]
    return DEFAULT_BIAS if any(m.sees[node] != 0 for m in measurements) else None


def state_names(fit: ObserverFit) -> list[str]:
    lags = [f"lag of {m.name}" for m in fit.measurements if m.lag_pole(1.0) > 0]
    bias = bias_kind(fit.bias)
    return [*OUTPUTS, *lags, *([BIAS_NAMES[bias]] if bias else [])]


def observer_section(artifact: ModelArtifact, fit: ObserverFit, datasets: Sequence[Dataset],
                     form: str = DEPLOYED_FORM, gate: tuple[float, int] | None = None) -> dict:
    """The artifact's `observer` section (version 2) for a tuned fit; node, column, offset_C, R and lag_s of the
    first measurement as a version 1 reader expects them."""
    model = FilterModel.of(artifact)
    layout = filter_data(artifact, datasets[0], fit.measurements, fit.bias, fit.consider).readings
    q = process_noise(model, fit.q_C2)
    f, nominal = nominal_transition(artifact, model, datasets)
    full = augmented_transition(f, model.b, model.c, layout)
    r_nominal = [float(s) * _rel(artifact, datasets[0], m)
                 for m, s in zip(fit.measurements, fit.r_scale, strict=True)]
    held = layout.held
    try:
        gain, p_steady = steady_state(full, measurement_rows(model.c, layout), q, r_nominal,
                                      consider_projections(model.c, held) if held.any() else None)
    except ValueError as exc:
        raise BenchError(f"the observer has no steady-state gain ({exc}); tune it without --consider") from None
    first, enc = fit.measurement, encode_array
    dt = artifact.dt
    names = state_names(fit)
    section = {
        "kind": "kalman-linear-block", "version": OBSERVER_SECTION_VERSIONS[-1], "node": first.node,
        "column": first.columns[0],
        "lag_s": float(getattr(first, "lag_s", 0.0)), "form": form,
        "measurements": [m.entry(dt, float(s)) for m, s in zip(fit.measurements, fit.r_scale, strict=True)],
        "states": names, "bias": bias_kind(fit.bias),
        "rule": f"after each model step: {BIAS_RULES[bias_kind(fit.bias) or 'winding-heat']}, "
                "each lag state follows what its "
                "sensor sees (s = a s + (1 - a) sees.y); F = A + B_s G C (delta: I + dt (A + B_s G C)), augmented; "
                "P- = F P F' + Q; per measurement with a valid reading z (variance R): nu = z - (s or sees.y), "
                "K = P- h' / (h P- h' + R), x += K nu, y = C x (+ r)",
        "Q": enc(q), "q_nodes_C2": enc(fit.q_C2), "R": enc(fit.r_C2), "P0": enc(initial_covariance(model, layout)),
        "offset_C": enc(float(getattr(first, "offset_C", 0.0))),
        "K_ss": enc(gain), "P_ss": enc(p_steady),
        "tuning": {"method": f"{fit.criterion} criterion (float64 filter, Nelder-Mead on log10 q and R)",
                   "criterion_value": fit.cost, "states": names,
                   "q_C2_per_step": dict(zip(OUTPUTS, (float(v) for v in fit.q_C2), strict=False)),
                   "q_per_step": dict(zip(names, (float(v) for v in fit.q_C2), strict=True)),
                   "R_C2": fit.r_C2, "R_scale": [float(v) for v in fit.r_scale],
                   "measurements": [m.describe() for m in fit.measurements],
                   "negative_log_likelihood": fit.nll, "updates": fit.updates,
                   "reference_while_tuning": None if fit.r_reference_C2 is None else
                   {"column": TUNING_REFERENCE.column, "R_C2": fit.r_reference_C2},
                   "evaluations": fit.evaluations, "files": [str(p) for p in fit.files],
                   "initial_sigma_C": INITIAL_SIGMA_C, "steady_state_at": nominal},
    }
    if fit.consider is not None:   # only then: a section without consider states is written as it always was
        section["consider"] = fit.consider
        section["rule"] += (f"; consider states ({fit.consider}): a measurement that does not read the "
                            f"{listed(CONSIDER_KINDS[fit.consider])} has the gain's rows of its held states zero "
                            "(node coordinates), P in Joseph's form of that gain")
    if fit.release_C2 is not None:   # only then: a section without it holds the magnet always, as before
        section["consider_release_C2"] = enc(float(fit.release_C2))
        section["rule"] += (f"; key-on release: while the magnet's variance (node coordinates, before an update) "
                            f"exceeds {fit.release_C2:g} °C² no measurement holds the magnet (nor a magnet bias)")
    if gate is not None:         # only then: a section without a gate is written as it always was
        section["gate"] = {"sigma": float(gate[0]), "flag_after": int(gate[1])}
        section["rule"] += (f"; innovation gate: a reading with nu^2 > {gate[0]:g}^2 (h P- h' + R) predicts only, "
                            f"counted; {gate[1]} in a row flag its sensor")
    return section


def _rel(artifact: ModelArtifact, dataset: Dataset, measurement) -> float:
    """The measurement's median per-step variance factor on a file (1 for a sensor)."""
    loss_model, motor = artifact_loss_model(artifact)
    steps = len(model_run(dataset, loss_model, motor, artifact.dt).step_time_s)
    z0, _, rel = measurement.readings(dataset, artifact.dt, steps)
    valid = np.isfinite(z0)
    return float(np.median(rel[valid])) if valid.any() else 1.0


def with_observer(artifact: ModelArtifact, section: dict) -> dict:
    """The artifact's content with `section` as its observer (schema version 3), sealed."""
    content = {k: v for k, v in artifact.content.items() if k != "sha256"}
    content["observer"] = section
    content["schema_version"] = schema_version_of(content)
    sealed = seal(content)
    verify(sealed)
    return sealed
