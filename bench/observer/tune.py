"""Tune the observer's process and measurement noise on training files (`tune_observer`), and say where the tuning
ended at a limit of its search (`tuning_warnings`).

Process noise Q is diagonal in the node temperatures (°C² per model step for yoke, winding, tooth, magnet) and
brought into the realization's coordinates, Q_x = C⁻¹ diag(q) C⁻ᵀ; R is the measurement's variance (°C²). Both are
tuned on the training files (float64 filter, `bench.thermal.kalman`; Nelder-Mead over log10 q and log10 R), every
file its own run from its own initial state, by one of two criteria (`TUNING_CRITERIA`):
- `magnet` (the default): the sum of log magnet MSE of the deployed filter (the sensor only) over every training
  file started with the magnet as measured, 30 K too warm and 30 K too cold: what the observer is for, scored by
  the lab's magnet reference (pm_C), which the deployed filter never sees; the winding, yoke and tooth the
  training files measure are guarded (`GUARDED_NODES`: a filter that leaves one worse than the open loop pays);
- `likelihood`: the innovations' likelihood (Mehra), with the magnet reference as a second measurement while
  tuning (its variance a nuisance parameter), so the magnet's process noise is tuned where it is observable.
Measured on the built-in motor: the likelihood of the winding sensor's innovations alone is best when the magnet
state soaks up the winding model's errors (40 °C run: magnet RMSE 0.21 K open loop, 5.6 K with that filter), and
even with the reference while tuning, P0's magnet uncertainty lets the first minutes' winding innovations throw the
magnet 23 K off; hence the magnet criterion. The initial covariance P0 is `bench.observer.reference`'s; the
steady-state gain and covariance the section stores, `bench.observer.section`'s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bench.drive.dataset import Dataset
from bench.errors import BenchError
from bench.model.polish import in_threads
from bench.observer.choices import TUNING_CRITERIA
from bench.observer.measures import kind_of
from bench.observer.measures.lagged_sensor import Sensor
from bench.observer.reference import (
    BIAS_NAMES,
    FilterData,
    FilterModel,
    bias_kind,
    filter_data,
    initial_covariance,
    process_noise,
    run_filter,
)
from target_sim.artifact import BIAS_KINDS, CONSIDER_KINDS, OUTPUT_BIAS_KINDS, OUTPUTS, ModelArtifact

START_Q_C2 = 1e-4       # the search starts here for every node (°C² per step), R where each kind says (start_r)
LOG10_BOUNDS = (-12.0, 3.0)
# a tuned log10 q or R this close to its bound ended at the limit, not at an optimum inside (a warning)
LIMIT_MARGIN_DECADES = 0.5
NELDER_MEAD_CAPPED = (1, 2)     # scipy's Nelder-Mead status: stopped at its cap of evaluations (1) or iterations (2)

# the lab's reference of the magnet in the training files, used while tuning only
TUNING_REFERENCE = Sensor("magnet", "pm_C")
# the search's start of the bias's q (W² per step)
START_Q_BIAS = {"winding-heat": 10.0, "magnet-heat": 1.0, "winding-output": 1e-2}   # an output bias: °C²


def consider_problem(consider: str | None, bias, measurements: Sequence) -> str | None:
    """Why the consider kind cannot go with this bias and these measurements (None: it can): a bias that every
    measurement holds is never corrected, a random walk whose variance grows without bound (and the steady-state
    gain does not exist)."""
    kind = bias_kind(bias)
    if kind in OUTPUT_BIAS_KINDS:
        node = OUTPUTS[BIAS_KINDS[kind]]
        if all(m.sees[OUTPUTS.index(node)] == 0 for m in measurements):
            return (f"--bias {kind} adds to the {node}'s output, which no measurement reads, so the bias would never "
                    f"move; add a sensor of the {node}, or use another --bias")
    if consider is None:
        return None
    if consider not in CONSIDER_KINDS:
        return f"consider {consider!r} is not one of {', '.join(CONSIDER_KINDS)}"
    if kind is None or kind in OUTPUT_BIAS_KINDS:
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


# what each criterion scores (log MSE against the lab's reference, summed): "nodes" adds the winding to the magnet
SCORED_NODES = {"magnet": ("magnet",), "nodes": ("magnet", "winding")}
# "nodes": the filter must not make the magnet worse than the open loop on any training file started as measured;
# each unit of log MSE it does costs this much (the winding is then corrected only as far as the magnet allows)
MAGNET_GUARD_WEIGHT = 200.0
# Each criterion that scores against the lab's references also guards the referenced nodes it does not score: a
# filter that makes one of them worse than the open loop on a training file started as measured pays the same
# penalty per unit of log MSE. Why: the magnet criterion left the stator's process noise free, and on the motor
# suite's outrunner (2026-12-06, its designer's polished model) the tuned filter drove the tooth from 4.8 to 949 K²
# MSE on the test profiles (max 102 K), the winding and the magnet worse with it.
GUARDED_NODES = {"magnet": ("winding", "yoke", "tooth"), "nodes": ("magnet", "yoke", "tooth")}
CAUTIOUS_DECADES = 4.0
# "nodes" lets R grow further than LOG10_BOUNDS (a measurement barely used: the open loop within reach of the search)
NODES_R_MAX_LOG10 = 6.0


def scored_nodes(criterion: str, bias: str | None) -> tuple[str, ...]:
    """What a criterion scores: its `SCORED_NODES`, and the node of an output bias (`OUTPUT_BIAS_KINDS`), whose
    correction never reaches the magnet: scored by the magnet alone, its tuning would be flat."""
    nodes = SCORED_NODES[criterion]
    if bias in OUTPUT_BIAS_KINDS and OUTPUTS[BIAS_KINDS[bias]] not in nodes:
        nodes = (*nodes, OUTPUTS[BIAS_KINDS[bias]])
    return nodes


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
      `TUNING_START_OFFSETS_K` off (the deployed filter; the reference only scores it), with the guard's penalty
      (`GUARDED_NODES`) on each file whose winding, yoke or tooth, started as measured, the filter leaves worse,
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
    guarded: list[tuple[int, str]] = []
    if criterion == "likelihood":
        use_reference = all(m.node != TUNING_REFERENCE.node for m in measurements) and all(
            d.has(TUNING_REFERENCE.column) for d in datasets)
        tuning = (*measurements, TUNING_REFERENCE) if use_reference else measurements
        data = [filter_data(artifact, d, tuning, bias, consider, release_C2) for d in datasets]
        p0_tuning = initial_covariance(model, data[0].readings)

        def score(q, r):
            return sum(in_threads(lambda d: float(run_filter(model, d, q, [r], p0_tuning).nll[0]), data))
    else:
        magnet = OUTPUTS.index("magnet")
        scored = [(OUTPUTS.index(node), "pm" if node == "magnet" else node) for node in scored_nodes(criterion, bias)]
        # the guarded nodes every training file has a reference of, and their open loop's log MSE per file from
        # the measured start (the filter with no gain at all)
        output_node = set(scored_nodes(criterion, bias)) - set(SCORED_NODES[criterion])   # scored, not guarded
        guarded = [(OUTPUTS.index(node), "pm" if node == "magnet" else node) for node in GUARDED_NODES[criterion]
                   if node not in output_node
                   if all(d.run.reference("pm" if node == "magnet" else node) is not None for d in deployed)]

        def open_loop_of(d: FilterData) -> dict:
            estimates = run_filter(model, d, process_noise(model, np.zeros(n))[None], [np.full(m_count, 1e30)], p0,
                                   keep=True).estimates[0]
            return {i: _log_mse(estimates[:, i], d.run.reference(ref)) for i, ref in guarded}

        open_loop = in_threads(open_loop_of, deployed)
        # every file from every start: independent filter runs, in threads (one per core)
        shifted = [(index, offset) for index in range(len(deployed)) for offset in TUNING_START_OFFSETS_K]

        def errors_of(q, r, index: int, offset: float) -> dict:
            d = deployed[index]
            start = d.run.initial.copy()
            start[magnet] += offset
            moved = FilterData(replace(d.run, initial=start), d.readings, d.measurements)
            estimates = run_filter(model, moved, q, [r], p0, keep=True).estimates[0]
            # the scored nodes from every start; the guarded ones from the measured start only
            nodes = scored + (guarded if offset == 0.0 else [])
            return {(i, ref): _log_mse(estimates[:, i], d.run.reference(ref)) for i, ref in nodes}

        def score(q, r):
            total = 0.0    # summed in the files' and starts' order, whichever thread ran them
            for (index, offset), errors in zip(shifted, in_threads(lambda item: errors_of(q, r, *item), shifted),
                                               strict=True):
                total += sum(errors[node] for node in scored)
                if offset == 0.0:   # a guarded node worse than the open loop's: a steep penalty
                    total += sum(MAGNET_GUARD_WEIGHT * max(0.0, errors[node] - open_loop[index][node[0]])
                                 for node in guarded)
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
    starts = search_starts(start, n) if criterion == "nodes" else []
    most = len(starts) + max_evaluations     # the cost's calls at most (a progress bar's total)
    if starts:
        start = min(starts, key=cost)
    size = len(start)
    result = minimize(cost, start, method="Nelder-Mead",
                      options={"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-3,
                               "initial_simplex": start + np.vstack([np.zeros(size), np.eye(size)])})
    best = np.concatenate([np.clip(result.x[:n], *q_bounds), np.clip(result.x[n:], *r_bounds)])
    q, r = 10.0 ** best[:n], 10.0 ** best[n: n + m_count]
    runs = [run_filter(model, d, process_noise(model, q)[None], [r], p0) for d in deployed]
    return ObserverFit(measurements, q, r, float(10.0 ** best[n + m_count]) if use_reference else None, criterion,
                       float(cost(best)), sum(float(x.nll[0]) for x in runs), sum(int(x.updates[0]) for x in runs),
                       calls[0], [str(d.path) for d in datasets], bias,
                       converged=result.status not in NELDER_MEAD_CAPPED, consider=consider, release_C2=release_C2)


def search_starts(start: np.ndarray, n: int) -> list[np.ndarray]:
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
            which = f"the {listed(hit)} node{'s' * (len(hit) > 1)}"
            meaning = some.format(*(("its", "it") if len(hit) == 1 else ("their", "them")))
        if hit:
            out.append(f"the tuning ended at q {10.0 ** bound:.0e} °C² per step for {which}, its {limit} limit: "
                       f"{meaning}")
    if fit.bias and log_q[-1] <= q_low + LIMIT_MARGIN_DECADES:
        name = BIAS_NAMES[bias_kind(fit.bias) or "winding-heat"].split(" (")[0]
        out.append(f"the tuning ended at the lower limit of the {name}'s q: the bias never moves, so --bias "
                   "adds nothing")
    if not fit.converged:
        out.append(f"the tuning stopped after {fit.evaluations} filter runs, at its cap (--evaluations), before the "
                   "search converged: the observer may be far from the criterion's best; raise --evaluations")
    return out


def listed(names: Sequence[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def _log_mse(estimate: np.ndarray, reference: np.ndarray) -> float:
    return float(np.log(np.mean((estimate - reference) ** 2)))

