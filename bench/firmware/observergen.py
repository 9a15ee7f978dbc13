"""The observer's generated C (fw_model.c's observer part): the float32 Kalman filter of `target_sim.observer`
in its deployed UD form (or its steady-state gain), for an artifact with an observer section; an open-loop artifact
gets none of it (its C, and so its ELF, is what it was).

The C repeats `target_sim.observer.Float32Observer` with `BiermanThornton` (or `SteadyState`) operation for
operation:

| C (fw_model.c)         | Python (target_sim.observer)                  | what                                  |
|------------------------|-----------------------------------------------|---------------------------------------|
| obs_propagate_extra    | AugmentedLayout.propagate                     | bias into x, the lag states           |
| obs_predict            | Transition.matrix,                            | F of the step, augmented; Thornton's  |
|                        | BiermanThornton.predict                       | MWGS over [F U, G] (udgen.py)         |
| obs_update_<k>         | BiermanThornton.update with the k-th row h    | Bierman's scalar update (udgen.py),   |
|                        | (SteadyState.update)                          | then Agee-Turner's for consider       |
|                        |                                               | states; the steady form: the k-th row |
|                        |                                               | of K_ss (its held rows -0)            |
| fw_obs_step            | Float32Observer.step                          | model step, predict, update           |
| obs_update_<k>, tail   | Float32Observer._update                       | y += K nu (node coordinates), summed  |
| obs_output             | LinearBlockPart.output                        | y = C x (+ r), unrolled               |
| obs_move_state         | Float32Observer._measurement_update's end     | x += C^-1 (summed correction), y = Cx |
| fw_obs_reset, _restore | Float32Observer.reset, NodeObserver.restore   | x0, lag state, U0 d0                  |
| fw_obs_sigma           | Float32Observer.sigma                         | each node's 1-σ, unrolled (udgen.py)  |
| fw_obs_report          | Float32Observer.sigma, .innovations           | each node's 1-σ, each innovation      |
| fw_obs_gate            | InnovationGate.rejected, .flagged             | the gate's state after a step (DBC    |
|                        |                                               | 1.8.0: Innovations, Uncertainty1)     |
| obs_reading_<k>        | the k-th measurement's `reading` (its kind)   | its value and variance, or no reading |
| obs_variance_<k>,      | BiermanThornton/SteadyState                   | the gate (a section with `gate` only):|
| obs_gate               | .innovation_variance, InnovationGate.rejects  | S, nu*nu > sigma^2 S, the counts      |
| fw_obs_checkpoint      | Float32Observer.checkpoint                    | extra states, d, U above the diagonal |
|                        |                                               | (steady form: the extra states only,  |
|                        |                                               | with a gate then its counts in a row) |
| fw_obs_restore_checkpoint | NodeObserver.restore with every element    | x, then the filter bit for bit        |

What the reference computes once at load (P0's factors U0 and d0 by `ud_factor`, Q's factors G and q, the
constants of F, the bias column of B, each measurement's row h, 1 - a of each lag; the steady form's K_ss rows and
its constant 1-σ) is computed by that very code here and written as exact literals: the same float32 values the
reference starts from. The temperature sources keep their gains for
the Jacobian (`obs_gains`, written by temperature_sources only in an observer's C). Every measurement of the
section, in its order: a sample carries their raw channels after the drive values (FW_OBS_CHANNELS), each kind turns its
channels into a reading with its own C (`c_reading` of its `target_sim.observer.measurements` module, constants
`c_scalars`), and the valid ones update one after the other, as the reference's loop does. The firmware refuses what it
cannot run before this (`target_sim.firmware.node_protocol.firmware_refusal`: another form than UD and the steady-state
gain).
"""

from __future__ import annotations

import numpy as np

from bench.firmware.literals import FirmwareGenerationError, c_float
from bench.firmware.udgen import (
    Value,
    literal,
    move_state_c,
    output_c,
    predict_c,
    product,
    sigma_c,
    steady_c,
    total,
    update_c,
    variance_c,
)
from target_sim.artifact import OUTPUTS, ModelArtifact
from target_sim.firmware.node_protocol import FIRMWARE_OBSERVER_FORMS
from target_sim.observer import Float32Observer
from target_sim.observer.ud import ud_factor
from target_sim.xcp.variables import (
    EXTRA_SYMBOL,
    INNOVATION_SYMBOL,
    LAG_SYMBOL,
    OFFSET_SYMBOL,
    Q_SYMBOL,
    R_SYMBOL,
    SIGMA_SYMBOL,
)

# the line temperature_sources gets in an observer's C: the gains the transition's Jacobian takes
KEEP_GAINS_C = "".join(f"    obs_gains[{i}] = {gain};\n" for i, gain in enumerate(("g_tm", "g_wm", "g_ma", "g_cy")))
SOURCES_END = "    src[3] = (y_est[1] + g_wm * y_est[3]) / (1.0f + g_wm);\n"


def _literal_array(name: str, values: np.ndarray, comment: str, storage: str = "static const ") -> str:
    values = np.asarray(values, dtype=np.float32)
    dims = "".join(f"[{n}]" for n in values.shape)
    if values.ndim == 1:
        body = "{" + ", ".join(c_float(v) for v in values) + "}"
    else:
        rows = ",\n    ".join("{" + ", ".join(c_float(v) for v in row) + "}" for row in values)
        body = "{\n    " + rows + "\n}"
    return f"/* {comment} */\n{storage}float {name}{dims} = {body};\n"


def observer_filter(artifact: ModelArtifact) -> Float32Observer:
    """The reference filter the C is generated from (FirmwareGenerationError when it is neither in the UD nor in the
    steady-state-gain form: the refusal has said so before)."""
    obs = Float32Observer(artifact)
    if obs.form not in FIRMWARE_OBSERVER_FORMS:
        raise FirmwareGenerationError("the firmware generator has the UD and the steady-state-gain forms of an "
                                      "observer only")
    return obs


def observer_channels(artifact: ModelArtifact) -> int:
    """The raw channels of the observer's measurements a sample carries after the drive values."""
    return sum(Float32Observer(artifact).layout.widths)


def observer_header(artifact: ModelArtifact) -> str:
    """fw_model.h's observer part."""
    externs = "".join(f"extern float {name};\n" for name in calibrated_scalars(artifact))
    return _HEADER.replace("OBS_CALIBRATED_EXTERNS", externs)


_HEADER = """
/* The observer (the artifact's observer section: a float32 Kalman filter on the linear block, Bierman-Thornton UD
 * form or the steady-state gain, as target_sim.observer.Float32Observer): a sample and a step's inputs carry the
 * raw channels of its measurements after the drive values (FW_OBS_CHANNELS; NaN in a measurement's channels: no
 * reading of it, a step without any predicts only), FW_SAMPLE_WIDTH values. */

/* The model at y0 (fw_reset), each lag state at what its sensor sees, the covariance P0 (its factors U0, d0; the
   steady form has none). */
void fw_obs_reset(const float y0[4]);

/* x bit for bit (fw_restore), each lag state at what its sensor sees, the covariance P0: a restore without the
   filter's checkpoint (not every RestoreObserver element came). */
void fw_obs_restore(const float x[4]);

/* x bit for bit, then the filter's extra states and covariance from its checkpoint (fw_obs_checkpoint's values,
   echoed back in RestoreObserver): the filter continues bit for bit. */
void fw_obs_restore_checkpoint(const float x[4], const float values[]);

/* The filter's checkpoint (Float32Observer.checkpoint, the ObserverCheckpoint elements in order): the extra states
   (lags, bias), then d, then U above its diagonal row by row (the steady form: the extra states only). */
void fw_obs_checkpoint(float values[]);

/* One model step (fw_step on u's drive values), the covariance's prediction and, for each measurement with a valid
 * reading in u, in order, the update; writes the corrected outputs to y. */
void fw_obs_step(const float u[FW_SAMPLE_WIDTH], float y[4]);

/* Each node's 1-sigma [yoke, winding, tooth, magnet] (deg C) into obs_sigma; fw_obs_step, fw_obs_reset and the
 * restores call it last. */
void fw_obs_sigma(void);

/* After a step: obs_sigma into out[0..3] and each measurement's innovation (NaN: the step did not use it) into
 * out[4..]. */
void fw_obs_report(float out[4 + FW_OBS_MEASUREMENTS]);

/* What an XCP master measures and calibrates (target_sim.xcp.variables: the C symbols of its cells): the filter's
 * states from index 4 on (the lag states, the bias), each node's 1-sigma (fw_obs_sigma), each measurement's
 * innovation of the last step, Q's diagonal (node coordinates; read by each prediction), and each measurement's
 * calibratable constants (read by each step). */
extern float obs_extra[FW_OBS_STATES];
extern float obs_sigma[4];
extern float obs_innovation[FW_OBS_MEASUREMENTS];
extern float obs_q[FW_OBS_STATES];
OBS_CALIBRATED_EXTERNS
/* After a step: each measurement's innovation gate (InnovationGate.rejected, .flagged): bit 0 its reading was
 * rejected in this step, bit 1 its sensor is flagged (latched until a reset or restore); 0 without a gate. */
void fw_obs_gate(unsigned char out[FW_OBS_MEASUREMENTS]);
"""


def calibrated_scalars(artifact: ModelArtifact) -> list[str]:
    """The C names of the measurements' scalars an XCP master calibrates (the cells of `target_sim.xcp.variables`
    with a per-measurement symbol): each a variable in RAM, the others constants in flash."""
    from target_sim.node import TargetNode
    from target_sim.xcp.variables import node_cells

    _, calibrations = node_cells(TargetNode(artifact))
    per_measurement = (OFFSET_SYMBOL, LAG_SYMBOL, R_SYMBOL)        # each <name>_<k>
    return [spec.symbol for spec in calibrations
            if spec.symbol is not None and spec.symbol.rpartition("_")[0] in per_measurement]


def observer_defines(artifact: ModelArtifact) -> str:
    """fw_model.h's observer constants (after FW_INPUTS)."""
    obs = observer_filter(artifact)
    return ("#define FW_OBSERVER 1 /* the model has an observer: fw_obs_* below */\n"
            f"#define FW_OBS_MEASUREMENTS {len(obs.measurements)} /* its measurements, in the section's order */\n"
            f"#define FW_OBS_STATES {obs.n} /* the filter's states: the model's 4, the lag states, the bias */\n"
            f"#define FW_OBS_CHANNELS {sum(obs.layout.widths)} /* their raw channels in a sample */\n"
            f"#define FW_OBS_CHECKPOINT_SIZE {obs.checkpoint_size()} /* the ObserverCheckpoint elements */\n"
            "#define FW_SAMPLE_WIDTH (FW_INPUTS + FW_OBS_CHANNELS) /* a sample: the drive values, then the raw "
            "channels */\n")


def _measurement_declarations(obs: Float32Observer, index: int, calibrated: set[str]) -> str:
    """The constants of the index-th measurement (suffix _<index>): what it sees, its lag, its kind's, and in the
    steady form its row of K_ss (its row h is in its update's code: udgen.update_c); those in `calibrated` are
    variables an XCP master writes (RAM), the others constants (flash)."""
    m, lag = obs.measurements[index], obs.layout.lag_index[index]
    k = f"_{index}"
    lines = [f"#define OBS_LAG{k} {lag} /* {m.name}: its lag state's index (-1: it reads the model without lag) */"]
    scalars = [(f"{LAG_SYMBOL}{k}", m.lag_pole, "its lag a = exp(-dt/tau)")] if lag >= 0 else []
    scalars += [(f"{name}{k}", value, comment) for name, value, comment in m.c_scalars()]
    lines += [f"{'float' if name in calibrated else 'static const float'} {name} = {c_float(value)}; /* {comment} */"
              for name, value, comment in scalars]
    arrays = [(f"OBS_SEES{k}", m.sees, "what it sees of [yoke, winding, tooth, magnet]")] if lag >= 0 else []
    if obs.form == "steady":
        arrays.append((f"OBS_GAIN{k}", obs.gain_steady[index], "its row of K_ss: the steady-state gain"))
    return "\n".join(lines) + "\n" + "".join(_literal_array(name, value, comment) for name, value, comment in arrays)


def observer_declarations(artifact: ModelArtifact) -> str:
    """The observer's constants (computed by the reference's own float32 code) and state (.bss)."""
    obs = observer_filter(artifact)
    f, n = obs.f, obs.n
    bias, steady = obs.layout.bias_index, obs.form == "steady"
    calibrated = set(calibrated_scalars(artifact))
    lines = [f"#define OBS_N {n} /* the filter's states: the model's 4, then a lag state per lagged measurement, "
             "then the bias */",
             f"#define OBS_STEADY {int(steady)} /* 1: the steady-state gain K_ss (no covariance), 0: the UD form */",
             f"#define OBS_BIAS {bias} /* the bias state's index (-1: none) */",
             f"#define OBS_BIAS_OUTPUT {obs.layout.bias_output} /* the node an output bias adds to (-1: none, or a "
             "heat bias) */"]
    if steady:
        arrays = []
    else:
        u0, d0 = ud_factor(obs.p0, f)
        arrays = [("OBS_U0", u0, "U0 of P0 = U0 diag(d0) U0^T (ud_factor)"), ("OBS_D0", d0, "d0")]
    if bias >= 0 and obs.layout.bias_output < 0:
        arrays.append(("OBS_BIAS_COLUMN", obs.layout.bias_column,
                       "the bias's column of B: its node's loss (delta: times dt)"))
    text = "\n".join(lines) + "\n" + "".join(_literal_array(name, value, comment) for name, value, comment in arrays)
    text += "".join(_measurement_declarations(obs, index, calibrated) for index in range(len(obs.measurements)))
    factors = "" if steady else "static float obs_u[OBS_N][OBS_N];\nstatic float obs_d[OBS_N];\n"
    text += _gate_declarations(obs)
    nans = ", ".join(["__builtin_nanf(\"\")"] * len(obs.measurements))
    return text + ("/* the observer's state: U, d of P = U diag(d) U^T (UD form), the extra states (lags, bias: by\n"
                   " * index), each measurement's last innovation, the sources' gains of the last step; each node's\n"
                   " * 1-sigma and Q's diagonal. Those an XCP master reads start as the Python filter does at\n"
                   " * power-on (P0's 1-sigma, no innovation yet, the artifact's Q) */\n"
                   f"{factors}float {EXTRA_SYMBOL}[OBS_N];\n"
                   f"float {INNOVATION_SYMBOL}[FW_OBS_MEASUREMENTS] = {{{nans}}};\nstatic float obs_gains[4];\n"
                   + _literal_array(SIGMA_SYMBOL, obs.sigma(), "each node's 1-sigma (fw_obs_sigma)", "")
                   + _literal_array(Q_SYMBOL, obs.q_nodes, "Q's diagonal (node coordinates)", ""))


def _gate_declarations(obs: Float32Observer) -> str:
    """The gate's constants and counts (a section with `gate` only: without it the C is what it was)."""
    if obs.gate.threshold is None:
        return ""
    text = (f"#define OBS_FLAG_AFTER {obs.gate.flag_after} /* rejections in a row that flag a sensor */\n"
            f"static const float OBS_GATE = {c_float(obs.gate.threshold)}; /* sigma^2: nu*nu > OBS_GATE * S "
            "rejects */\n")
    if obs.form == "steady":
        text += _literal_array("OBS_PRIOR", np.array(obs.cov.prior, dtype=np.float32),
                               "each measurement's h P- h^T of the steady prior (SteadyState.prior)")
    return text + ("/* each measurement's rejected readings, rejections in a row, flag, rejected in this step "
                   "(InnovationGate.rejects) */\n"
                   "static unsigned long obs_rejections[FW_OBS_MEASUREMENTS];\n"
                   "static unsigned long obs_consecutive[FW_OBS_MEASUREMENTS];\n"
                   "static unsigned char obs_flagged[FW_OBS_MEASUREMENTS];\n"
                   "static unsigned char obs_rejected[FW_OBS_MEASUREMENTS];\n")


GATE_C = """
/* InnovationGate.rejects: whether the k-th measurement's reading (innovation nu, variance s) is rejected, counted;
 * the steady form re-admits the reading after OBS_FLAG_AFTER rejections in a row */
static int obs_gate(int k, float nu, float s)
{
    int readmit = OBS_STEADY && obs_consecutive[k] >= OBS_FLAG_AFTER;
    if (!(nu * nu > OBS_GATE * s) || readmit) {
        obs_consecutive[k] = 0;
        return 0;
    }
    obs_rejected[k] = 1;
    obs_rejections[k] = obs_rejections[k] + 1;
    obs_consecutive[k] = obs_consecutive[k] + 1;
    if (obs_consecutive[k] >= OBS_FLAG_AFTER) obs_flagged[k] = 1;
    return 1;
}
"""

OBSERVER_C = """\
OBS_OUTPUT
/* AugmentedLayout.propagate: the bias heats its node, each lag state follows what its sensor sees */
static void obs_propagate_extra(void)
{
#if OBS_BIAS >= 0 && OBS_BIAS_OUTPUT < 0
    int i;
    for (i = 0; i < 4; i++) x_state[i] = x_state[i] + OBS_BIAS_COLUMN[i] * obs_extra[OBS_BIAS];
    obs_output();
#endif
OBS_LAG_PROPAGATE}

/* Each lag state at what its sensor sees of y (AugmentedLayout.initial_extra) */
static void obs_reset_lags(void)
{
OBS_LAG_RESET}

OBS_KERNELS
static int obs_finite(float value)
{
    fw_bits bits;
    bits.f = value;
    return ((bits.u >> 23) & 0xFFu) != 0xFFu;
}

OBS_MOVE_STATEOBS_READINGS
/* Float32Observer.step: the model step, F, the extra states, the prediction, and the update with each measurement
 * that has a valid reading, in the section's order (each reads the estimate the previous one corrected) */
void fw_obs_step(const float u[FW_SAMPLE_WIDTH], float y[4])
{
    float value, r, nu;
    float correction[4] = {-0.0f, -0.0f, -0.0f, -0.0f};
    int i, corrected = 0;
    fw_step(u, y);
    obs_propagate_extra();
    obs_predict();
    for (i = 0; i < FW_OBS_MEASUREMENTS; i++) obs_innovation[i] = __builtin_nanf("");
OBS_GATE_STEPOBS_UPDATES    if (corrected) {
        obs_move_state(correction);
        obs_output();
    }
    for (i = 0; i < 4; i++) y[i] = y_est[i];
#if OBS_BIAS_OUTPUT >= 0
    y[OBS_BIAS_OUTPUT] = y[OBS_BIAS_OUTPUT] + obs_extra[OBS_BIAS];   /* AugmentedLayout.reported */
#endif
    fw_obs_sigma();                                         /* what XCP reads right after the step */
}

/* Float32Observer.reset */
void fw_obs_reset(const float y0[4])
{
    int i;
#if !OBS_STEADY
    int j;
#endif
    fw_reset(y0);
    for (i = 0; i < OBS_N; i++) obs_extra[i] = 0.0f;
    obs_reset_lags();
#if !OBS_STEADY
    for (i = 0; i < OBS_N; i++) {
        for (j = 0; j < OBS_N; j++) obs_u[i][j] = OBS_U0[i][j];
        obs_d[i] = OBS_D0[i];
    }
#endif
    for (i = 0; i < FW_OBS_MEASUREMENTS; i++) obs_innovation[i] = __builtin_nanf("");
OBS_GATE_RESET    fw_obs_sigma();
}

/* NodeObserver.restore without the filter's checkpoint: a fresh filter at zero temperatures, x bit for bit, then
   each lag state at what its sensor sees of y = C x (AugmentedLayout.initial_extra) */
void fw_obs_restore(const float x[4])
{
    static const float zero[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    fw_obs_reset(zero);
    fw_restore(x);
    obs_reset_lags();
}

/* Float32Observer.checkpoint: obs_extra[4..], then d and U above its diagonal row by row (UD form; the steady form
   has no covariance: the extra states only) */
void fw_obs_checkpoint(float values[])
{
    int i, at = 0;
#if !OBS_STEADY
    int j;
#endif
    for (i = 4; i < OBS_N; i++) values[at++] = obs_extra[i];
#if !OBS_STEADY
    for (i = 0; i < OBS_N; i++) values[at++] = obs_d[i];
    for (i = 0; i < OBS_N; i++) {
        for (j = i + 1; j < OBS_N; j++) values[at++] = obs_u[i][j];
    }
#endif
OBS_COUNTS_CHECKPOINT}

/* NodeObserver.restore with every element: a fresh filter at zero temperatures, x bit for bit, then
   Float32Observer.restore_checkpoint (U unit upper triangular, zeros below; the steady form: the extra states) */
void fw_obs_restore_checkpoint(const float x[4], const float values[])
{
    static const float zero[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    int i, at = 0;
#if !OBS_STEADY
    int j;
#endif
    fw_obs_reset(zero);
    fw_restore(x);
    for (i = 4; i < OBS_N; i++) obs_extra[i] = values[at++];
#if !OBS_STEADY
    for (i = 0; i < OBS_N; i++) obs_d[i] = values[at++];
    for (i = 0; i < OBS_N; i++) {
        for (j = 0; j < OBS_N; j++) obs_u[i][j] = i == j ? 1.0f : 0.0f;
        for (j = i + 1; j < OBS_N; j++) obs_u[i][j] = values[at++];
    }
#endif
OBS_COUNTS_RESTORE    fw_obs_sigma();
}

OBS_SIGMA
/* Float32Observer.sigma (fw_obs_sigma's, after the step) and .innovations */
void fw_obs_report(float out[4 + FW_OBS_MEASUREMENTS])
{
    int i;
    for (i = 0; i < 4; i++) out[i] = obs_sigma[i];
    for (i = 0; i < FW_OBS_MEASUREMENTS; i++) out[4 + i] = obs_innovation[i];
}

/* InnovationGate.rejected (bit 0) and .flagged (bit 1) of each measurement after a step */
void fw_obs_gate(unsigned char out[FW_OBS_MEASUREMENTS])
{
    int i;
    for (i = 0; i < FW_OBS_MEASUREMENTS; i++) out[i] = OBS_GATE_STATUS;
}
"""

# per lagged measurement k (its state OBS_LAG_k): its propagation, its reset
_LAG_PROPAGATE = (f"    obs_extra[OBS_LAG_K] = {LAG_SYMBOL}_K * obs_extra[OBS_LAG_K] + (1.0f - {LAG_SYMBOL}_K) * "
                  "(dot(OBS_SEES_K, y_est, 4)BIAS_SEEN);\n")
_LAG_RESET = "    obs_extra[OBS_LAG_K] = dot(OBS_SEES_K, y_est, 4);\n"
# per measurement k: its reading, its own update (the row h is its code's) and the correction
_UPDATE = ("    if (obs_reading_K(u + FW_INPUTS + {first}, u[1], &value, &r)) {\n"
           "        nu = value - (PREDICTED);\n"
           "        obs_innovation[INDEX] = nu;\n"
           "        corrected |= obs_update_K(r, nu, correction);\n    }\n")
# ... with the gate: a rejected reading predicts only (its innovation stays NaN)
_GATED_UPDATE = ("    if (obs_reading_K(u + FW_INPUTS + {first}, u[1], &value, &r)) {\n"
                 "        nu = value - (PREDICTED);\n"
                 "        if (!obs_gate(INDEX, nu, obs_variance_K(r))) {\n"
                 "            obs_innovation[INDEX] = nu;\n"
                 "            corrected |= obs_update_K(r, nu, correction);\n        }\n    }\n")
# the steady form with a gate: each measurement's rejections in a row in the checkpoint (InnovationGate.checkpoint)
_COUNTS_CHECKPOINT = "    for (i = 0; i < FW_OBS_MEASUREMENTS; i++) values[at++] = (float)obs_consecutive[i];\n"
_COUNTS_RESTORE = ("    for (i = 0; i < FW_OBS_MEASUREMENTS; i++) {\n"
                   "        obs_consecutive[i] = values[at] > 0.0f && values[at] < 1e9f ? (unsigned long)values[at]\n"
                   "            : 0u;\n"
                   "        at++;\n    }\n")
_GATE_RESET = ("    for (i = 0; i < FW_OBS_MEASUREMENTS; i++) {\n"
               "        obs_rejections[i] = 0;\n        obs_consecutive[i] = 0;\n        obs_flagged[i] = 0;\n"
               "        obs_rejected[i] = 0;\n    }\n")
# a step starts with no reading rejected yet (InnovationGate.new_step)
_GATE_STEP = "    for (i = 0; i < FW_OBS_MEASUREMENTS; i++) obs_rejected[i] = 0;\n"
# fw_obs_gate's value of measurement i: rejected (bit 0), flagged (bit 1); without a gate none
_GATE_STATUS = "(unsigned char)(obs_rejected[i] | (obs_flagged[i] << 1))"


# ... with the key-on release (ConsiderStates.holds): the magnet free while its variance exceeds OBS_RELEASE
_RELEASED_UPDATE = ("(obs_magnet_variance(0.0f) > OBS_RELEASE ? obs_update_K_released(r, nu, correction)\n"
                    "                : obs_update_K(r, nu, correction))")


def _releases(obs: Float32Observer, index: int) -> bool:
    """Whether the index-th measurement's update depends on the key-on release (it holds the magnet, and the
    section has a release)."""
    held = obs.consider.held[index]
    return obs.consider.release is not None and held is not None and bool(held[OUTPUTS.index("magnet")])


def _output_bias_seen(obs: Float32Observer, m) -> str:
    """What measurement m sees of an output bias (AugmentedLayout.seen): " + w * obs_extra[bias]", or nothing."""
    output = obs.layout.bias_output
    if output < 0 or m.sees[output] == 0:
        return ""
    return f" + {product(literal(m.sees[output]), Value(f'obs_extra[{obs.layout.bias_index}]'))}"


def _per_measurement(obs: Float32Observer) -> dict[str, str]:
    """The generated parts of OBSERVER_C for the section's measurements (their lags, readings and updates)."""
    propagate, reset, readings, updates, first = [], [], [], [], 0
    for index, (m, lag) in enumerate(zip(obs.measurements, obs.layout.lag_index, strict=True)):
        suffix = f"_{index}"
        seen = _output_bias_seen(obs, m)
        if lag >= 0:
            propagate.append(_LAG_PROPAGATE.replace("_K", suffix).replace("BIAS_SEEN", seen))
            reset.append(_LAG_RESET.replace("_K", suffix))
        readings.append("\n" + m.c_reading.replace("_K", suffix))
        predicted = f"obs_extra[{lag}]" if lag >= 0 else total(
            [product(literal(m.sees[i]), Value(f"y_est[{i}]")) for i in range(len(m.sees)) if m.sees[i] != 0]) + seen
        template = _UPDATE if obs.gate.threshold is None else _GATED_UPDATE
        if _releases(obs, index):
            template = template.replace("obs_update_K(r, nu, correction)", _RELEASED_UPDATE)
        updates.append(template.replace("{first}", str(first)).replace("_K", suffix).replace("INDEX", str(index))
                       .replace("PREDICTED", predicted))
        first += m.width
    counts = obs.gate.in_checkpoint
    gated = obs.gate.threshold is not None
    return {"OBS_GATE_RESET": _GATE_RESET if gated else "", "OBS_GATE_STEP": _GATE_STEP if gated else "",
            "OBS_GATE_STATUS": _GATE_STATUS if gated else "0u",
            "OBS_COUNTS_CHECKPOINT": _COUNTS_CHECKPOINT if counts else "",
            "OBS_COUNTS_RESTORE": _COUNTS_RESTORE if counts else "",
            "OBS_LAG_PROPAGATE": "".join(propagate), "OBS_LAG_RESET": "".join(reset),
            "OBS_READINGS": "".join(readings), "OBS_UPDATES": "".join(updates)}


def observer_code(artifact: ModelArtifact) -> str:
    """The observer's functions (after the model's: they call fw_step, fw_reset, fw_restore and dot)."""
    obs = observer_filter(artifact)
    code = (OBSERVER_C.replace("OBS_KERNELS", _kernels(obs)).replace("OBS_MOVE_STATE", move_state_c(obs))
            .replace("OBS_OUTPUT", output_c(obs)).replace("OBS_SIGMA", sigma_c(obs)))
    for name, text in _per_measurement(obs).items():
        code = code.replace(name, text)
    return code


def _kernels(obs: Float32Observer) -> str:
    """obs_predict and one obs_update_<k> per measurement (udgen.py): the UD form's unrolled over its structure, one
    Bierman update per row h; the steady form's, no prediction and the k-th row of K_ss."""
    count = len(obs.measurements)
    moves_y = [k < count - 1 for k in range(count)]     # the last update's y is C x again at the step's end
    if obs.form == "steady":
        return steady_c(obs.n, [(f"obs_update_{k}", f"OBS_GAIN_{k}", moves_y[k], obs.consider.held[k])
                                for k in range(count)]) + \
            _gate_c(obs)
    updates = "".join("\n" + update_c(obs, f"obs_update_{k}", obs.layout.rows[k], moves_y[k], obs.consider.held[k])
                      for k in range(count))
    released = [k for k in range(count) if _releases(obs, k)]
    if released:
        release = c_float(obs.consider.release)
        updates += (f"\nstatic const float OBS_RELEASE = {release}; /* the key-on release (variance) */\n"
                    + "\n" + variance_c(obs, "obs_magnet_variance", obs.consider.magnet_row)
                    + "".join("\n" + update_c(obs, f"obs_update_{k}_released", obs.layout.rows[k], moves_y[k],
                                              obs.consider.released[k]) for k in released))
    return predict_c(obs) + _gate_c(obs) + updates


def _gate_c(obs: Float32Observer) -> str:
    """obs_gate and one obs_variance_<k> per measurement (a section with `gate` only)."""
    if obs.gate.threshold is None:
        return ""
    if obs.form == "steady":
        variances = "".join(f"\n/* SteadyState.innovation_variance */\nstatic float obs_variance_{k}(float r)\n"
                            f"{{\n    return OBS_PRIOR[{k}] + r;\n}}\n" for k in range(len(obs.measurements)))
    else:
        variances = "".join("\n" + variance_c(obs, f"obs_variance_{k}", obs.layout.rows[k])
                            for k in range(len(obs.measurements)))
    return GATE_C + variances


def keep_gains(sources_c: str) -> str:
    """temperature_sources of an observer's C: it also keeps the gains for the transition's Jacobian."""
    if SOURCES_END not in sources_c:
        raise FirmwareGenerationError("the temperature sources' C has changed; the observer's generator must follow")
    return sources_c.replace(SOURCES_END, SOURCES_END + KEEP_GAINS_C)
