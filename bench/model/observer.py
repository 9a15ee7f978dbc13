"""The lab's side of the observer: tune its process and measurement noise on training files, and write it into a
model artifact (the optional `observer` section, schema version 3; `target_sim.observer` runs it).

Process noise Q is diagonal in the node temperatures (°C² per model step for yoke, winding, tooth, magnet) and
brought into the realization's coordinates, Q_x = C⁻¹ diag(q) C⁻ᵀ; R is the measurement's variance (°C²). Both are
tuned on the training files (float64 filter, `bench.thermal.kalman`; Nelder-Mead over log10 q and log10 R), every
file its own run from its own initial state, by one of two criteria (`TUNING_CRITERIA`):
- `magnet` (the default): the sum of log magnet MSE of the deployed filter (the sensor only) over every training
  file started with the magnet as measured, 30 K too warm and 30 K too cold: what the observer is for, scored by
  the lab's magnet reference (pm_C), which the deployed filter never sees;
- `likelihood`: the innovations' likelihood (Mehra), with the magnet reference as a second measurement while
  tuning (its variance a nuisance parameter), so the magnet's process noise is tuned where it is observable.
Measured on the built-in motor: the likelihood of the winding sensor's innovations alone is best when the magnet
state soaks up the winding model's errors (40 °C run: magnet RMSE 0.21 K open loop, 5.6 K with that filter), and
even with the reference while tuning, P0's magnet uncertainty lets the first minutes' winding innovations throw the
magnet 23 K off; hence the magnet criterion. The initial covariance says how
little is known at start: P0 = C⁻¹ diag(σ0²) C⁻ᵀ with σ0 = `INITIAL_SIGMA_C` (a magnet whose temperature at key-on
nobody measured). The steady-state gain K_ss and covariance P_ss are the Riccati solution at the training runs'
median speed and mean coolant temperature.

Measurements (section version 2) are a list of `target_sim.measurements` kinds, their lab side in
`bench.model.measures`: a lagged sensor (an NTC: its lag τ becomes a state of the filter, its offset is known from
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
R_speed (n_min/n)²).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bench.drive.dataset import Dataset
from bench.errors import BenchError
from bench.model.artifact_values import artifact_loss_model, artifact_parameters, shift_form
from bench.model.measures import LAB_MEASUREMENT_KINDS, kind_of
from bench.model.measures.lagged_sensor import Sensor
from bench.model.polish import in_threads
from bench.model.runs import ModelRun, model_run
from bench.thermal import portable
from bench.thermal.estimator import identity_sigmoid, loop_parameters
from bench.thermal.kalman import (
    FilterRuns,
    Readings,
    augmented_transition,
    consider_projections,
    measurement_rows,
    run_filters,
    source_jacobian,
    steady_state,
)
from target_sim.artifact import (
    BIAS_KINDS,
    CONSIDER_KINDS,
    OBSERVER_SECTION_VERSIONS,
    OUTPUTS,
    ModelArtifact,
    consider_release,
    encode_array,
    observer_gate,
    schema_version_of,
    seal,
    verify,
)
from target_sim.kinds import MODEL_KINDS
from target_sim.network import COOLANT_REFERENCE_C

# 1-σ of the initial state (°C): yoke and tooth start as the initial-state rule puts them (bench.model.runs: as
# measured, else at the coolant temperature), the winding as measured, the
# magnet as the host guesses it (the key-on problem: nobody measured it after a short stop)
INITIAL_SIGMA_C = {"yoke": 5.0, "winding": 2.0, "tooth": 5.0, "magnet": 15.0}
# the covariance form the target runs unless told otherwise (chosen from `bench numerics --observer`)
DEPLOYED_FORM = "ud"
# the consider kind `bench observer` builds unless told otherwise (--consider; "none": every state is updated).
# Chosen on the suite's validation profiles (2026-11-28; designer's Hammerstein models, the end-winding NTC with lag,
# gradient and offset estimated, magnet criterion, no bias, 150 filter runs; MSE K², open loop / --consider none /
# magnet): winding air-30kw 13.06 / 8.67 / 3.68, ipm-60kw-distributed 3.24 / 0.30 / 1.11, outrunner-200kw
# 12.55 / 8.08 / 10.95; magnet 3.31 / 4.87 / 2.70, 5.05 / 2.74 / 2.28, 7.74 / 7.09 / 7.64. Only "magnet" leaves
# the magnet no worse than the open loop on every motor (none: worse on air-30kw) with the winding still better.
DEFAULT_CONSIDER = "magnet"
# the key-on release `bench observer` writes unless told otherwise (--consider-release SIGMA, K; None: the consider
# states held always): a held magnet whose 1-σ exceeds it is updated by every measurement
DEFAULT_CONSIDER_RELEASE_C = None
# the innovation gate `bench observer` writes unless told otherwise (--gate, --gate-flag-after): a reading more than
# 3 sigma of its innovation off (ν²/S > 9, the 99.73 % quantile of chi-square with 1 degree of freedom) predicts only;
# 10 rejections in a row (5 s at 0.5 s steps) flag the sensor
DEFAULT_GATE = (3.0, 10)
SIGMOID_KEYS = ("scale_W", "weight", "bias", "gain", "linear", "offset")
START_Q_C2 = 1e-4       # the search starts here for every node (°C² per step), R where each kind says (start_r)
LOG10_BOUNDS = (-12.0, 3.0)
# a tuned log10 q or R this close to its bound ended at the limit, not at an optimum inside (a warning)
LIMIT_MARGIN_DECADES = 0.5
NELDER_MEAD_CAPPED = (1, 2)     # scipy's Nelder-Mead status: stopped at its cap of evaluations (1) or iterations (2)


# a temperature sensor column (the lab side of the lagged-sensor kind); the name the earlier interface used
Measurement = Sensor

# the lab's reference of the magnet in the training files, used while tuning only
TUNING_REFERENCE = Sensor("magnet", "pm_C")
# the bias state's initial 1-σ per kind (W into its node) and the lag states' (K, beyond what their sensor sees);
# the search's start of the bias's q (W² per step). The magnet's: of the order of a magnet loss (tens of W; 100s
# of W at most), so P0 does not let the first innovations throw the magnet far (see the module's note on P0)
BIAS_SIGMA_W = {"winding-heat": 50.0, "magnet-heat": 20.0}
LAG_SIGMA_C = 0.5
START_Q_BIAS = {"winding-heat": 10.0, "magnet-heat": 1.0}
BIAS_NAMES = {"winding-heat": "winding heat bias (W)", "magnet-heat": "magnet heat bias (W)"}
BIAS_NODES = {"winding-heat": "winding (x += b_w beta)", "magnet-heat": "magnet (x += b_m beta)"}   # the rule's


def bias_kind(bias) -> str | None:
    """The bias kind of a `bias` argument: a kind of `BIAS_KINDS`, True (the winding's, the one kind there was), or
    None/False (no bias)."""
    kind = "winding-heat" if bias is True else (bias or None)
    if kind is not None and kind not in BIAS_KINDS:
        raise BenchError(f"bias {kind!r} is not one of {', '.join(BIAS_KINDS)}")
    return kind


def consider_problem(consider: str | None, bias, measurements: Sequence) -> str | None:
    """Why the consider kind cannot go with this bias and these measurements (None: it can): a bias that every
    measurement holds is never corrected, a random walk whose variance grows without bound (and the steady-state
    gain does not exist)."""
    if consider is None:
        return None
    if consider not in CONSIDER_KINDS:
        return f"consider {consider!r} is not one of {', '.join(CONSIDER_KINDS)}"
    kind = bias_kind(bias)
    if kind is None:
        return None
    node = OUTPUTS[BIAS_KINDS[kind]]
    if node in CONSIDER_KINDS[consider] and all(m.sees[OUTPUTS.index(node)] == 0 for m in measurements):
        flag = "--flux" if node == "magnet" else "a sensor of it"
        return (f"--consider {consider} holds the {node} heat bias for every measurement (none reads the {node}), so "
                f"the bias would never move and its variance would grow without bound; add a measurement of the "
                f"{node} ({flag}), or use --consider none or another --bias")
    return None


@dataclass(frozen=True)
class ObserverFit:
    measurements: tuple
    q_C2: np.ndarray            # (n,) process noise per state: nodes °C², lag states °C², bias W², per step
    r_scale: np.ndarray         # (m,) each measurement's variance scale (a sensor's: its variance in °C²)
    r_reference_C2: float | None   # the magnet reference's variance while tuning (None: not used)
    criterion: str
    cost: float                 # the criterion's value at the optimum
    nll: float                  # the deployed filter's innovations' negative log-likelihood on the training files
    updates: int
    evaluations: int
    files: list[str] = field(default_factory=list)
    bias: str | None = None     # the heat-bias state's kind (`BIAS_KINDS`); True is read as "winding-heat"
    converged: bool = True      # False: the search stopped at its cap of filter runs (--evaluations)
    consider: str | None = None  # the consider kind (`CONSIDER_KINDS`): states a measurement not reading them holds
    release_C2: float | None = None  # the held magnet is updated while its variance exceeds this (None: always held)

    @property
    def measurement(self):
        return self.measurements[0]

    @property
    def r_C2(self) -> float:
        return float(self.r_scale[0])


@dataclass(frozen=True)
class FilterModel:
    """An artifact's float64 values as the reference filter takes them."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    theta: np.ndarray
    sigmoid: np.ndarray

    @classmethod
    def of(cls, artifact: ModelArtifact) -> FilterModel:
        if not MODEL_KINDS[artifact.kind].linear_block:
            raise BenchError(f"an observer needs a linear block; a {artifact.kind} artifact has none (use the "
                             "lti-lptn or hammerstein artifact)")
        a, b, c = shift_form(artifact)
        if MODEL_KINDS[artifact.kind].input_nonlinearity:
            sig = np.vstack([artifact.array("input_nonlinearity", k, dtype=np.float64) for k in SIGMOID_KEYS])
        else:
            sig = identity_sigmoid(np.ones(4))
        return cls(a, b, c, loop_parameters(artifact_parameters(artifact)), sig)

    def to_state(self, physical_diag) -> np.ndarray:
        """C⁻¹ diag(v) C⁻ᵀ: a diagonal covariance of the node temperatures in the state coordinates."""
        c_inv = portable.inv(self.c)
        return (c_inv * np.asarray(physical_diag, dtype=float)) @ c_inv.T


@dataclass(frozen=True)
class FilterData:
    """One file prepared for the filter: the model run and the readings per model step."""

    run: ModelRun
    readings: Readings
    measurements: tuple


def filter_data(artifact: ModelArtifact, dataset: Dataset, measurements: Sequence, bias=None,
                consider: str | None = None, release_C2: float | None = None) -> FilterData:
    for m in measurements:
        for column in m.columns:
            if not dataset.has(column):
                raise BenchError(f"{dataset.path} has no column {column!r}, the observer's measurement; map the "
                                 f"file's column of that sensor onto {column} with --mapping (a mapping file's "
                                 f"[columns] YOUR_COLUMN = \"{column}\") or choose another with --measure")
    loss_model, motor = artifact_loss_model(artifact)
    run = model_run(dataset, loss_model, motor, artifact.dt, name=dataset.name)
    steps = len(run.step_time_s)
    parts = [m.readings(dataset, artifact.dt, steps) for m in measurements]
    z0, z1, rel = (np.column_stack([p[i] for p in parts]) for i in range(3))
    readings = Readings(z0, z1, rel, np.array([m.sees for m in measurements]),
                        np.array([m.lag_pole(artifact.dt) for m in measurements]), bias_kind(bias), consider,
                        release_C2)
    return FilterData(run, readings, tuple(measurements))


def _run(model: FilterModel, data: FilterData, q, r, p0, keep=False, gate_sigma: float | None = None) -> FilterRuns:
    return run_filters(model.a, model.b, model.c, model.theta, model.sigmoid, data.run.inputs, data.run.initial,
                       data.readings, q, r, p0, keep, gate_sigma)


def initial_covariance(model: FilterModel, readings: Readings | None = None) -> np.ndarray:
    """P0: the nodes' `INITIAL_SIGMA_C` in the state coordinates; a lag state as its sensor's view of them plus
    `LAG_SIGMA_C`; the bias its kind's `BIAS_SIGMA_W`."""
    p = model.to_state([INITIAL_SIGMA_C[n] ** 2 for n in OUTPUTS])
    if readings is None or readings.states == 4:
        return p
    n = readings.states
    t = np.zeros((n, 4))
    t[:4] = np.eye(4)
    extra = np.zeros(n)
    for m, lag in enumerate(readings.lag_index):
        if lag >= 0:
            t[lag] = readings.sees[m] @ model.c
            extra[lag] = LAG_SIGMA_C ** 2
    if readings.bias:
        extra[n - 1] = BIAS_SIGMA_W[readings.bias] ** 2
    return t @ p @ t.T + np.diag(extra)


def process_noise(model: FilterModel, q: np.ndarray) -> np.ndarray:
    """Q: the nodes' diagonal in the state coordinates (C⁻¹ diag(q) C⁻ᵀ), the extra states' own diagonal."""
    out = np.diag(np.asarray(q, dtype=float))
    out[:4, :4] = model.to_state(q[:4])
    return out


TUNING_CRITERIA = ("magnet", "nodes", "likelihood")
# what each criterion scores (log MSE against the lab's reference, summed): "nodes" adds the winding to the magnet
SCORED_NODES = {"magnet": ("magnet",), "nodes": ("magnet", "winding")}
# "nodes": the filter must not make the magnet worse than the open loop on any training file started as measured;
# each unit of log MSE it does costs this much (the winding is then corrected only as far as the magnet allows)
MAGNET_GUARD_WEIGHT = 200.0
CAUTIOUS_DECADES = 4.0
# "nodes" lets R grow further than LOG10_BOUNDS (a measurement barely used: the open loop within reach of the search)
NODES_R_MAX_LOG10 = 6.0


def search_bounds(criterion: str) -> tuple[tuple[float, float], tuple[float, float]]:
    """The bounds of the tuning's search, log10 of (q, R), for a criterion."""
    low, high = LOG10_BOUNDS
    return (low, high), (low, NODES_R_MAX_LOG10 if criterion == "nodes" else high)
# the magnet criterion starts every training file with the magnet as measured and this much too warm and too cold
TUNING_START_OFFSETS_K = (0.0, 30.0, -30.0)


def tune_observer(artifact: ModelArtifact, datasets: Sequence[Dataset], measurements, criterion: str = "magnet",
                  max_evaluations: int = 800, progress: Callable[[int, int, float], None] | None = None,
                  bias=None, consider: str | None = None, release_C2: float | None = None) -> ObserverFit:
    """q (per state) and each measurement's R on the training files by Nelder-Mead over their log10 values,
    minimizing either
    - "magnet": the sum of log magnet MSE over every training file started with the magnet as measured and
      `TUNING_START_OFFSETS_K` off (the deployed filter; the reference only scores it),
    - "nodes": the same with the winding's log MSE added, and a steep penalty (`MAGNET_GUARD_WEIGHT`) on each file
      whose magnet, started as measured, the filter makes worse than the open loop: a winding sensor then corrects
      the winding only as far as that leaves the magnet (which it cannot see) no worse, or
    - "likelihood": the innovations' negative log-likelihood, with the magnet reference as one more measurement
      where every training file has it and no measurement already reads the magnet (its variance a nuisance)."""
    from scipy.optimize import minimize

    if criterion not in TUNING_CRITERIA:
        raise BenchError(f"tuning criterion {criterion!r} is not one of {', '.join(TUNING_CRITERIA)}")
    measurements = tuple(measurements) if isinstance(measurements, (list, tuple)) else (measurements,)
    bias = bias_kind(bias)
    model = FilterModel.of(artifact)
    problem = consider_problem(consider, bias, measurements)
    if problem:
        raise BenchError(problem)
    deployed = [filter_data(artifact, d, measurements, bias, consider, release_C2) for d in datasets]
    layout = deployed[0].readings
    p0 = initial_covariance(model, layout)
    n, m_count = layout.states, len(measurements)
    use_reference = False
    if criterion == "likelihood":
        use_reference = all(m.node != TUNING_REFERENCE.node for m in measurements) and all(
            d.has(TUNING_REFERENCE.column) for d in datasets)
        tuning = (*measurements, TUNING_REFERENCE) if use_reference else measurements
        data = [filter_data(artifact, d, tuning, bias, consider, release_C2) for d in datasets]
        p0_tuning = initial_covariance(model, data[0].readings)

        def score(q, r):
            return sum(in_threads(lambda d: float(_run(model, d, q, [r], p0_tuning).nll[0]), data))
    else:
        magnet = OUTPUTS.index("magnet")
        scored = [(OUTPUTS.index(node), "pm" if node == "magnet" else node) for node in SCORED_NODES[criterion]]
        guarded = criterion == "nodes"
        # the open loop's magnet log MSE per file from the measured start (the filter with no gain at all)
        open_loop = in_threads(lambda d: _log_mse(_run(model, d, process_noise(model, np.zeros(n))[None],
                                                       [np.full(m_count, 1e30)], p0, keep=True).estimates[0][:, magnet],
                                                  d.run.ref_pm), deployed) if guarded else []
        # every file from every start: independent filter runs, in threads (one per core)
        shifted = [(index, offset) for index in range(len(deployed)) for offset in TUNING_START_OFFSETS_K]

        def errors_of(q, r, index: int, offset: float) -> dict:
            d = deployed[index]
            start = d.run.initial.copy()
            start[magnet] += offset
            moved = FilterData(replace(d.run, initial=start), d.readings, d.measurements)
            estimates = _run(model, moved, q, [r], p0, keep=True).estimates[0]
            return {i: _log_mse(estimates[:, i], d.run.reference(ref)) for i, ref in scored}

        def score(q, r):
            total = 0.0    # summed in the files' and starts' order, whichever thread ran them
            for (index, offset), errors in zip(shifted, in_threads(lambda item: errors_of(q, r, *item), shifted),
                                               strict=True):
                total += sum(errors.values())
                if guarded and offset == 0.0:   # a magnet worse than the open loop's: a steep penalty
                    total += MAGNET_GUARD_WEIGHT * max(0.0, errors[magnet] - open_loop[index])
            return total

    calls = [0]
    q_bounds, r_bounds = search_bounds(criterion)

    def cost(v):
        v = np.concatenate([np.clip(v[:n], *q_bounds), np.clip(v[n:], *r_bounds)])
        total = score(process_noise(model, 10.0 ** v[:n])[None], 10.0 ** v[n:])
        calls[0] += 1
        if progress:
            progress(calls[0], most, total)
        return total if np.isfinite(total) else 1e300

    start_q = [START_Q_C2] * 4 + [START_Q_C2] * (n - 4 - int(bias is not None)) + (
        [START_Q_BIAS[bias]] if bias else [])
    start_r = [kind_of(m).start_r for m in measurements] + [kind_of(TUNING_REFERENCE).start_r] * int(use_reference)
    start = np.log10(start_q + start_r)
    # the search is local: with "nodes", begin where the guard is, of the default and a cautious start
    starts = _starts(start, n) if criterion == "nodes" else []
    most = len(starts) + max_evaluations     # the cost's calls at most (a progress bar's total)
    if starts:
        start = min(starts, key=cost)
    size = len(start)
    result = minimize(cost, start, method="Nelder-Mead",
                      options={"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-3,
                               "initial_simplex": start + np.vstack([np.zeros(size), np.eye(size)])})
    best = np.concatenate([np.clip(result.x[:n], *q_bounds), np.clip(result.x[n:], *r_bounds)])
    q, r = 10.0 ** best[:n], 10.0 ** best[n: n + m_count]
    runs = [_run(model, d, process_noise(model, q)[None], [r], p0) for d in deployed]
    return ObserverFit(measurements, q, r, float(10.0 ** best[n + m_count]) if use_reference else None, criterion,
                       float(cost(best)), sum(float(x.nll[0]) for x in runs), sum(int(x.updates[0]) for x in runs),
                       calls[0], [str(d.path) for d in datasets], bias,
                       converged=result.status not in NELDER_MEAD_CAPPED, consider=consider, release_C2=release_C2)


def _starts(start: np.ndarray, n: int) -> list[np.ndarray]:
    """Starting points of the search: the default, and one that trusts the measurements little (q / 10⁴, R · 10⁴,
    up to `NODES_R_MAX_LOG10`: near the open loop, where a measurement that cannot help the magnet should end)."""
    cautious = start.copy()
    cautious[:n] -= CAUTIOUS_DECADES
    cautious[n:] += CAUTIOUS_DECADES
    q_bounds, r_bounds = search_bounds("nodes")
    cautious[:n] = np.clip(cautious[:n], *q_bounds)
    cautious[n:] = np.clip(cautious[n:], *r_bounds)
    return [start, cautious]


def tuning_warnings(fit: ObserverFit) -> list[str]:
    """One sentence per way the tuning ended at a limit of its search (`search_bounds`, within
    `LIMIT_MARGIN_DECADES`) or of its filter runs: there the criterion found no optimum inside, and the observer is
    what the limit makes it."""
    (q_low, q_high), (r_low, r_high) = search_bounds(fit.criterion)
    out = []
    for m, r in zip(fit.measurements, np.log10(fit.r_scale), strict=True):
        if r >= r_high - LIMIT_MARGIN_DECADES:
            out.append(f"the tuning ended at R scale {10.0 ** r:.3g} for {m.name}, its upper limit: the filter barely "
                       f"uses {m.name}, so the observer is close to the open-loop model; the {fit.criterion} "
                       "criterion found no correction with it that helps")
        elif r <= r_low + LIMIT_MARGIN_DECADES:
            out.append(f"the tuning ended at R scale {10.0 ** r:.3g} for {m.name}, its lower limit: the filter takes "
                       f"{m.name} as exact and passes its noise on to the estimate")
    log_q = np.log10(fit.q_C2)
    nodes = log_q[:len(OUTPUTS)]
    for at, limit, bound, some, every in (
            (nodes <= q_low + LIMIT_MARGIN_DECADES, "lower", q_low,
             "the filter takes {} model as exact and corrects {} only through the model's coupling",
             "the filter takes the model as exact and corrects no node, so the observer is the open-loop model"),
            (nodes >= q_high - LIMIT_MARGIN_DECADES, "upper", q_high,
             "the filter drops {} model and follows the measurements for {}",
             "the filter drops the model and follows the measurements")):
        hit = [n for n, h in zip(OUTPUTS, at, strict=True) if h]
        if len(hit) == len(OUTPUTS):
            which, meaning = "every node", every
        elif hit:
            which = f"the {_listed(hit)} node{'s' * (len(hit) > 1)}"
            meaning = some.format(*(("its", "it") if len(hit) == 1 else ("their", "them")))
        if hit:
            out.append(f"the tuning ended at q {10.0 ** bound:.0e} °C² per step for {which}, its {limit} limit: "
                       f"{meaning}")
    if fit.bias and log_q[-1] <= q_low + LIMIT_MARGIN_DECADES:
        node = BIAS_NODES[bias_kind(fit.bias) or "winding-heat"].split()[0]
        out.append(f"the tuning ended at the lower limit of the {node} heat bias's q: the bias never moves, so --bias "
                   "adds nothing")
    if not fit.converged:
        out.append(f"the tuning stopped after {fit.evaluations} filter runs, at its cap (--evaluations), before the "
                   "search converged: the observer may be far from the criterion's best; raise --evaluations")
    return out


def _listed(names: Sequence[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def _log_mse(estimate: np.ndarray, reference: np.ndarray) -> float:
    return float(np.log(np.mean((estimate - reference) ** 2)))


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
        "rule": f"after each model step: the bias heats the {BIAS_NODES[bias_kind(fit.bias) or 'winding-heat']}, "
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
                            f"{_listed(CONSIDER_KINDS[fit.consider])} has the gain's rows of its held states zero "
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


def lab_measurements(artifact: ModelArtifact) -> tuple:
    """The lab side of the artifact's measurements (with their tuned variances folded in: R scale 1)."""
    from target_sim.observer import measurement_entries

    return tuple(LAB_MEASUREMENT_KINDS[e["kind"]].from_entry(e, artifact.dt)
                 for e in measurement_entries(artifact.content["observer"]))


def r_scales(artifact: ModelArtifact) -> list[float]:
    """Each measurement's variance scale as stored (a sensor's R; 1 for the flux linkage, its R in its arrays)."""
    from target_sim.observer import measurement_entries

    return [LAB_MEASUREMENT_KINDS[e["kind"]].stored_r(e) for e in measurement_entries(artifact.content["observer"])]


def reference_run(artifact: ModelArtifact, dataset: Dataset) -> tuple[FilterData, FilterRuns]:
    """The float64 reference of the artifact's observer on one file (estimate and 1-σ per step), with the section's
    innovation gate (`observer_gate`; its rejections counted in the runs' `rejections`)."""
    model = FilterModel.of(artifact)
    section = artifact.content["observer"]
    data = filter_data(artifact, dataset, lab_measurements(artifact), section.get("bias"), section.get("consider"),
                       consider_release(section))
    q = artifact.array("observer", "Q", dtype=np.float64)
    p0 = artifact.array("observer", "P0", dtype=np.float64)
    gate = observer_gate(section)
    return data, _run(model, data, q[None], [r_scales(artifact)], p0, keep=True,
                      gate_sigma=None if gate is None else gate[0])


def measurement_of(artifact: ModelArtifact):
    """The first measurement (lab side)."""
    return lab_measurements(artifact)[0]


def measurement_columns(artifact: ModelArtifact) -> list[str]:
    """The raw columns of every measurement, in the order the observer takes them per row."""
    return [c for m in lab_measurements(artifact) for c in m.columns]


def measured_nodes_of(artifact: ModelArtifact) -> list[str]:
    """The nodes the observer's measurements read (their errors are not estimates)."""
    return sorted({m.node for m in lab_measurements(artifact)}, key=OUTPUTS.index)
