"""The observer's generated C (fw_model.c's observer part): the float32 Kalman filter of `target_sim.observer`
in its deployed UD form (or its steady-state gain), for an artifact with an observer section; an open-loop artifact
gets none of it (its C, and so its ELF, is what it was).

The C repeats `target_sim.observer.Float32Observer` with `BiermanThornton` (or `SteadyState`) operation for
operation:

| C (fw_model.c)         | Python (target_sim.observer)                  | what                                  |
|------------------------|-----------------------------------------------|---------------------------------------|
| obs_propagate_extra    | Float32Observer._propagate_extra              | bias into x, the lag state            |
| obs_predict            | Float32Observer.transition,                   | F of the step, augmented; Thornton's  |
|                        | BiermanThornton.predict                       | MWGS over [F U, G] (udgen.py)         |
| obs_update             | BiermanThornton.update                        | Bierman's scalar update (udgen.py)    |
| fw_obs_step            | Float32Observer.step                          | model step, predict, update           |
| fw_obs_reset, _restore | Float32Observer.reset, NodeObserver.restore   | x0, lag state, U0 d0                  |
| fw_obs_report          | Float32Observer.sigma, .innovation            | each node's 1-σ, the innovation       |

What the reference computes once at load (P0's factors U0 and d0 by `ud_factor`, Q's factors G and q, the
constants of F, the bias column of B, the measurement row h, 1 - a of the lag; the steady form's K_ss and its
constant 1-σ) is computed by that very code here and written as exact literals: the same float32 values the
reference starts from. The temperature sources keep their gains for the Jacobian (`obs_gains`, written by
temperature_sources only in an observer's C). One measurement of one raw channel (a lagged sensor: what the
Measurements frame carries); the firmware refuses any other observer before this runs
(`target_sim.firmware.node_protocol.firmware_refusal`).
"""

from __future__ import annotations

import numpy as np

from bench.firmware.literals import FirmwareGenerationError, c_float
from bench.firmware.udgen import predict_c, steady_c, update_c
from target_sim.artifact import ModelArtifact
from target_sim.firmware.node_protocol import FIRMWARE_OBSERVER_FORMS
from target_sim.kinds import REALIZATIONS
from target_sim.observer import Float32Observer, ud_factor

# the line temperature_sources gets in an observer's C: the gains the transition's Jacobian takes
KEEP_GAINS_C = "".join(f"    obs_gains[{i}] = {gain};\n" for i, gain in enumerate(("g_tm", "g_wm", "g_ma", "g_cy")))
SOURCES_END = "    src[3] = (y_est[1] + g_wm * y_est[3]) / (1.0f + g_wm);\n"


def _literal_array(name: str, values: np.ndarray, comment: str) -> str:
    values = np.asarray(values, dtype=np.float32)
    dims = "".join(f"[{n}]" for n in values.shape)
    if values.ndim == 1:
        body = "{" + ", ".join(c_float(v) for v in values) + "}"
    else:
        rows = ",\n    ".join("{" + ", ".join(c_float(v) for v in row) + "}" for row in values)
        body = "{\n    " + rows + "\n}"
    return f"/* {comment} */\nstatic const float {name}{dims} = {body};\n"


def observer_filter(artifact: ModelArtifact) -> Float32Observer:
    """The reference filter the C is generated from (FirmwareGenerationError when it is not one measurement of one
    raw channel in the UD or the steady-state-gain form: the refusal has said so before)."""
    obs = Float32Observer(artifact)
    if obs.form not in FIRMWARE_OBSERVER_FORMS or len(obs.measurements) != 1 or obs.widths != [1]:
        raise FirmwareGenerationError("the firmware generator has the UD and the steady-state-gain forms of an "
                                      "observer with one temperature measurement only")
    return obs


def observer_header() -> str:
    """fw_model.h's observer part."""
    return """
/* The observer (the artifact's observer section: a float32 Kalman filter on the linear block, Bierman-Thornton UD
 * form or the steady-state gain, as target_sim.observer.Float32Observer): a sample and a step's inputs carry the
 * measurement after the drive values (NaN: no reading, the step predicts only), FW_SAMPLE_WIDTH values. */

/* The model at y0 (fw_reset), the lag state at what its sensor sees, the covariance P0 (its factors U0, d0). */
void fw_obs_reset(const float y0[4]);

/* x bit for bit (fw_restore), the lag state at what its sensor sees, the covariance P0 (the firmware does not
   checkpoint the filter: it sends no ObserverCheckpoint and ignores RestoreObserver). */
void fw_obs_restore(const float x[4]);

/* One model step (fw_step on u's drive values), the covariance's prediction and, when u's measurement is finite,
 * the update; writes the corrected outputs to y. */
void fw_obs_step(const float u[FW_SAMPLE_WIDTH], float y[4]);

/* After a step: each node's 1-sigma [yoke, winding, tooth, magnet] (deg C) into out[0..3] and the innovation
 * (NaN: the step predicted only) into out[4]. */
void fw_obs_report(float out[5]);
"""


OBSERVER_DEFINES = ("#define FW_OBSERVER 1 /* the model has an observer: fw_obs_* below */\n"
                    "#define FW_SAMPLE_WIDTH (FW_INPUTS + 1) /* a sample: the drive values, then the measurement */\n")


def observer_declarations(artifact: ModelArtifact) -> str:
    """The observer's constants (computed by the reference's own float32 code) and state (.bss)."""
    obs = observer_filter(artifact)
    f, n = obs.f, obs.n
    measurement = obs.measurements[0]
    u0, d0 = ud_factor(obs.p0, f)
    lag, bias = obs.lag_index[0], obs.bias_index
    steady = obs.form == "steady"
    lines = [f"#define OBS_N {n} /* the filter's states: the model's 4, then the lag state, then the bias */",
             f"#define OBS_STEADY {int(steady)} /* 1: the steady-state gain K_ss (no covariance), 0: the UD form */",
             f"#define OBS_LAG {lag} /* the lag state's index (-1: the sensor reads the model without lag) */",
             f"#define OBS_BIAS {bias} /* the bias state's index (-1: none) */"]
    scalars = {"OBS_OFFSET": (measurement.offset, "the sensor's offset (deg C)"),
               "OBS_R": (measurement.r, "its variance R (deg C^2)"),
               "OBS_LAG_POLE": (measurement.lag_pole, "its lag a = exp(-dt/tau)"),
               "OBS_LAG_GAIN": (f(1.0) - measurement.lag_pole, "1 - a")}
    used = {"OBS_LAG_POLE", "OBS_LAG_GAIN"} if lag >= 0 else set()
    used |= {"OBS_BIAS_COLUMN"} if bias >= 0 else set()
    used |= {"OBS_OFFSET", "OBS_R", "OBS_SEES"} | ({"OBS_GAIN", "OBS_SIGMA"} if steady else {"OBS_U0", "OBS_D0"})
    lines += [f"static const float {name} = {c_float(value)}; /* {comment} */"
              for name, (value, comment) in scalars.items() if name in used]
    arrays = [("OBS_U0", u0, "U0 of P0 = U0 diag(d0) U0^T (ud_factor)"), ("OBS_D0", d0, "d0"),
              ("OBS_GAIN", obs.gain_steady[0], "K_ss: the steady-state gain"),
              ("OBS_SIGMA", obs.sigma(), "each node's 1-sigma of P_ss (Float32Observer.sigma: constant)"),
              ("OBS_SEES", measurement.sees, "what the sensor sees of [yoke, winding, tooth, magnet]"),
              ("OBS_BIAS_COLUMN", obs.bias_column, "the bias's column of B (delta: times dt)")]
    text = "\n".join(lines) + "\n" + "".join(_literal_array(name, value, comment)
                                            for name, value, comment in arrays if name in used)
    factors = "" if steady else "static float obs_u[OBS_N][OBS_N];\nstatic float obs_d[OBS_N];\n"
    return text + ("/* the observer's state: U, d of P = U diag(d) U^T (UD form), the extra states (lag, bias: by\n"
                   " * their index), the last innovation, the sources' gains of the last step */\n"
                   f"{factors}static float obs_extra[OBS_N];\n"
                   "static float obs_innovation;\nstatic float obs_gains[4];\n")


OBSERVER_C = """\
/* y = C x (delta: (C x) + r): LinearBlockPart.output */
static void obs_output(void)
{
    int i;
    for (i = 0; i < 4; i++) y_est[i] = dot(LB_C[i], x_state, 4)OBS_PLUS_REF;
}

/* Float32Observer._propagate_extra: the bias heats the winding, the lag state follows what its sensor sees */
static void obs_propagate_extra(void)
{
#if OBS_BIAS >= 0
    int i;
    for (i = 0; i < 4; i++) x_state[i] = x_state[i] + OBS_BIAS_COLUMN[i] * obs_extra[OBS_BIAS];
    obs_output();
#endif
#if OBS_LAG >= 0
    obs_extra[OBS_LAG] = OBS_LAG_POLE * obs_extra[OBS_LAG] + OBS_LAG_GAIN * dot(OBS_SEES, y_est, 4);
#endif
}

OBS_KERNELS
static int obs_finite(float value)
{
    fw_bits bits;
    bits.f = value;
    return ((bits.u >> 23) & 0xFFu) != 0xFFu;
}

/* Float32Observer.step: the model step, F, the extra states, the prediction, and the update with a finite
 * reading: innovation = (z - offset) - (the lag state, or sees y), x <- x + K innovation, y = C x */
void fw_obs_step(const float u[FW_SAMPLE_WIDTH], float y[4])
{
    float gain[OBS_N];
    const float z = u[FW_INPUTS];
    int i;
    fw_step(u, y);
    obs_propagate_extra();
    obs_predict();
    obs_innovation = __builtin_nanf("");
    if (obs_finite(z)) {
        const float value = z - OBS_OFFSET;
#if OBS_LAG >= 0
        const float predicted = obs_extra[OBS_LAG];
#else
        const float predicted = dot(OBS_SEES, y_est, 4);
#endif
        const float nu = value - predicted;
        obs_innovation = nu;
        obs_update(OBS_R, gain);
        for (i = 0; i < 4; i++) x_state[i] = x_state[i] + gain[i] * nu;
        for (i = 4; i < OBS_N; i++) obs_extra[i] = obs_extra[i] + gain[i] * nu;
        obs_output();
    }
    for (i = 0; i < 4; i++) y[i] = y_est[i];
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
#if OBS_LAG >= 0
    obs_extra[OBS_LAG] = dot(OBS_SEES, y_est, 4);
#endif
#if !OBS_STEADY
    for (i = 0; i < OBS_N; i++) {
        for (j = 0; j < OBS_N; j++) obs_u[i][j] = OBS_U0[i][j];
        obs_d[i] = OBS_D0[i];
    }
#endif
    obs_innovation = __builtin_nanf("");
}

/* NodeObserver.restore without the filter's checkpoint: a fresh filter at zero temperatures, x bit for bit, then
   the lag state at what its sensor sees of y = C x (Float32Observer.reset_lags) */
void fw_obs_restore(const float x[4])
{
    static const float zero[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    fw_obs_reset(zero);
    fw_restore(x);
#if OBS_LAG >= 0
    obs_extra[OBS_LAG] = dot(OBS_SEES, y_est, 4);
#endif
}

/* Float32Observer.sigma (BiermanThornton.variance: v = U^T c, sigma^2 = (d_0 v_0) v_0 + ...) and .innovation */
void fw_obs_report(float out[5])
{
#if OBS_STEADY
    int node;
    for (node = 0; node < 4; node++) out[node] = OBS_SIGMA[node];   /* P_ss: the same every step */
#else
    float v[OBS_N];
    float s;
    int node, i, j;
    for (node = 0; node < 4; node++) {
        for (j = 0; j < OBS_N; j++) {                       /* c padded with zeros to the filter's states */
            v[j] = obs_u[0][j] * LB_C[node][0];
            for (i = 1; i < OBS_N; i++) v[j] = v[j] + obs_u[i][j] * (i < 4 ? LB_C[node][i] : 0.0f);
        }
        s = (obs_d[0] * v[0]) * v[0];
        for (j = 1; j < OBS_N; j++) s = s + (obs_d[j] * v[j]) * v[j];
        out[node] = s > 0.0f ? __builtin_sqrtf(s) : 0.0f;
    }
#endif
    out[4] = obs_innovation;
}
"""


def observer_code(artifact: ModelArtifact) -> str:
    """The observer's functions (after the model's: they call fw_step, fw_reset, fw_restore and dot)."""
    obs = observer_filter(artifact)
    delta = REALIZATIONS[artifact.realization].delta
    kernels = (steady_c() if obs.form == "steady" else
               predict_c(obs) + "\n" + update_c(obs, "obs_update", obs.rows[0]))
    return OBSERVER_C.replace("OBS_PLUS_REF", " + LB_REF" if delta else "").replace("OBS_KERNELS", kernels)


def keep_gains(sources_c: str) -> str:
    """temperature_sources of an observer's C: it also keeps the gains for the transition's Jacobian."""
    if SOURCES_END not in sources_c:
        raise FirmwareGenerationError("the temperature sources' C has changed; the observer's generator must follow")
    return sources_c.replace(SOURCES_END, SOURCES_END + KEEP_GAINS_C)
