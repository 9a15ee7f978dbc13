"""Model artifact -> portable C99: `fw_model.h` (the API) and `fw_model.c` (coefficients, state, step).

The C is the Python float32 reference (`target_sim.model`) written out again, operation for operation, so that
the compiled firmware's outputs equal the reference's bit for bit. Each C function names the Python method it
mirrors, and both spell every sum and product in the same order with the same parentheses. The loss model's
fragment comes from its kind (`target_sim.losses`), and the model kind's functions, step, constants and arrays
from the kind's module (`target_sim.modelkinds`); this module writes the rest around them:

| C (fw_model.c)          | Python (target_sim)                         | what                                   |
|-------------------------|---------------------------------------------|----------------------------------------|
| fw_exp                  | fmath.exp_f32                               | our float32 exp (no libm)              |
| dot                     | fmath.matvec (one row)                      | left-to-right sum of products          |
| grid_cell, loss_lookup  | losses.maps.LossTables._cell, .lookup       | bilinear loss tables (losses "maps")   |
| electrical_losses       | losses.electrical.ElectricalEvaluator       | losses from i_d, i_q, speed            |
| node_losses             | Float32Estimator.node_losses                | eqs. 3-8                               |
| input_nonlinearity      | modelkinds.hammerstein.HammersteinPart      | sigmoid, eqs. 28-30 (hammerstein)      |
| temperature_sources     | modelkinds.lti_lptn.LinearBlockPart         | eqs. 9-18 (lti-lptn, hammerstein)      |
| pv_network              | modelkinds.pv_lptn.PvNetworkPart            | parameter-varying network (pv-lptn)    |
| fw_step, fw_reset, ...  | Float32Estimator.step, .reset, .restore     | the state update (the kind's part)     |
| fw_accumulate, fw_mean  | model.InputAccumulator                      | interval means                         |

Every coefficient is a `static const float` written as a C hex-float literal of the artifact's `f32_hex`
(exact: no decimal round trip); the few derived constants (grid steps) are computed by the reference's own code
in float32 and written the same way. Every literal carries the `f` suffix and every intermediate is a float:
no double anywhere (the build checks with -Wdouble-promotion). No libc, no malloc, no recursion; the state is
four static arrays (.bss). An electrical loss model's square root and |speed| are the FPU's VSQRT.F32 and VABS.F32
(`__builtin_sqrtf`, `__builtin_fabsf` with -fno-math-errno: no libm call; VSQRT is correctly rounded, as np.sqrt
on float32 is), and its model takes 6 inputs per row (the drive values, then i_d and i_q) where a loss-map model
takes 4. Matrices are used densely (zeros included) in both languages, so the results agree
even for a diverging model (0·inf is NaN on both sides).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from bench.firmware.literals import FirmwareGenerationError, c_float
from bench.firmware.loopfacts import annotate_loops
from bench.firmware.nodegen import CONFIG_NAME, node_config, packers
from bench.firmware.observergen import (
    keep_gains,
    observer_channels,
    observer_code,
    observer_declarations,
    observer_defines,
    observer_header,
)
from target_sim.artifact import OUTPUTS, ModelArtifact
from target_sim.firmware.node_protocol import firmware_loss_models, firmware_refusal
from target_sim.fmath import EXP_CONSTANTS, EXP_EXPONENT_BIAS, EXP_MAX_ULP, EXP_POLYNOMIAL
from target_sim.kinds import MODEL_KINDS, REALIZATIONS
from target_sim.losses import C_NAMES, LOSS_KINDS, LossKind, reads_currents
from target_sim.network import COOLANT_REFERENCE_C
from target_sim.observer import has_observer
from target_sim.xcp.variables import ALPHA_CU_SYMBOL

HEADER_NAME = "fw_model.h"
SOURCE_NAME = "fw_model.c"


@dataclass(frozen=True)
class GeneratedSource:
    """The generated files: name -> text."""

    header: str
    source: str
    node: dict[str, str] = field(default_factory=dict)   # the CAN node's generated files (bench.firmware.nodegen)

    @property
    def files(self) -> dict[str, str]:
        return {HEADER_NAME: self.header, SOURCE_NAME: self.source, **self.node}


# ------------------------------------------------------------------------------------------------ literals


def c_float_of_hex(text: str, where: str) -> str:
    """The artifact's f32_hex string as a C literal (it must be a float32 value exactly)."""
    try:
        value = float.fromhex(text)
    except (ValueError, TypeError, OverflowError):
        raise FirmwareGenerationError(f"artifact field {where} holds {text!r}, not a hex float; rebuild the "
                                      "artifact with 'bench identify'") from None
    return c_float(value)


def _artifact_literals(artifact: ModelArtifact, *keys: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """The literals of an artifact array, from its f32_hex strings, shaped; checked against the decoded float32
    values the Python reference runs (the same numbers, or the generator refuses)."""
    where = ".".join(keys)
    values = artifact.array(*keys)                      # decodes and cross-checks f64/f32
    if shape is not None and values.shape != shape:
        raise FirmwareGenerationError(f"artifact field {where} has shape {list(values.shape)}, the firmware "
                                      f"generator needs {list(shape)}; rebuild the artifact with 'bench identify'")
    node = artifact.content
    for key in keys:
        node = node[key]
    literals = np.array([c_float_of_hex(h, where) for h in node["f32_hex"]], dtype=object).reshape(values.shape)
    if not all(float.fromhex(h) == float(v) for h, v in zip(node["f32_hex"], values.ravel(), strict=True)):
        raise FirmwareGenerationError(f"artifact field {where}: f32_hex and the decoded values differ")
    return literals


def _c_array(name: str, literals: np.ndarray, comment: str, per_line: int = 4) -> str:
    dims = "".join(f"[{n}]" for n in literals.shape)

    def body(block: np.ndarray, indent: str) -> str:
        if block.ndim == 1:
            items = list(block)
            lines = [", ".join(items[k:k + per_line]) for k in range(0, len(items), per_line)]
            if len(lines) == 1:
                return "{" + lines[0] + "}"
            inner = f",\n{indent}    ".join(lines)
            return "{\n" + indent + "    " + inner + "\n" + indent + "}"
        parts = [body(sub, indent + "    ") for sub in block]
        return "{\n" + indent + "    " + f",\n{indent}    ".join(parts) + "\n" + indent + "}"

    return f"/* {comment} */\nstatic const float {name}{dims} = {body(literals, '')};\n"


def _c_shared_rows(name: str, literals: np.ndarray, comment: str) -> str:
    """An array whose repeated rows (last axis) are stored once, with an index of each row's place, when that is
    smaller than the whole array; `NAME_ROW(k, r)` is row r of part k either way (the same literals: the same
    float32 values, read by the same loads)."""
    if literals.ndim != 3:
        raise FirmwareGenerationError(f"{name} is stacked tables of rows (3 axes), not {literals.ndim} axes")
    distinct: dict[tuple[str, ...], int] = {}
    index = np.array([[distinct.setdefault(tuple(row), len(distinct)) for row in part] for part in literals])
    index_type, index_bytes = ("uint8_t", 1) if len(distinct) <= 0x100 else ("uint16_t", 2)
    columns = literals.shape[-1]
    shared_bytes = 4 * columns * len(distinct) + index_bytes * index.size
    if shared_bytes >= 4 * literals.size:            # nothing repeats enough: the whole array
        return _c_array(name, literals, comment) + f"#define {name}_ROW(k, r) ({name}[k][r])\n"
    rows = np.array([list(row) for row in distinct], dtype=object)
    index_lines = ",\n".join("    {" + ", ".join(f"{int(v)}u" for v in part) + "}" for part in index)
    return (_c_array(f"{name}_ROWS", rows, f"{comment}: its {len(distinct)} distinct rows of {index.size} "
                     f"({4 * literals.size - shared_bytes} bytes less than the whole array)")
            + f"/* the row of {name}_ROWS that is row r of part k */\n"
            + f"static const {index_type} {name}_ROW_INDEX[{index.shape[0]}][{index.shape[1]}] = {{\n"
            + index_lines + "\n};\n"
            + f"#define {name}_ROW(k, r) ({name}_ROWS[{name}_ROW_INDEX[k][r]])\n")


# ------------------------------------------------------------------------------------------------ checks


def check_expressible(artifact: ModelArtifact) -> None:
    """Refuse, in one sentence, an artifact whose kind, realization, loss model or shapes the generator cannot
    express."""
    refusal = firmware_refusal(artifact)
    if refusal:
        raise FirmwareGenerationError(refusal)
    kind, realization = artifact.content.get("model_kind"), artifact.content.get("realization")
    if kind not in MODEL_KINDS:
        raise FirmwareGenerationError(f"model kind {kind!r} cannot be generated as firmware (the generator knows "
                                      f"{', '.join(MODEL_KINDS.names())}); use an artifact of one of those kinds")
    if realization not in REALIZATIONS:
        raise FirmwareGenerationError(f"realization {realization!r} cannot be generated as firmware (the generator "
                                      f"knows {', '.join(REALIZATIONS.names())}); rebuild the artifact with "
                                      "'bench identify --realization'")
    if artifact.loss_model not in firmware_loss_models():
        raise FirmwareGenerationError(f"loss model {artifact.loss_model!r} cannot be generated as firmware (the "
                                      f"generator knows {', '.join(firmware_loss_models())})")
    problem = LOSS_KINDS[artifact.loss_model].c_problem(artifact)
    if problem:
        raise FirmwareGenerationError(problem)
    for _, source, _ in LOSS_KINDS[artifact.loss_model].c_scalars(artifact):
        if isinstance(source, tuple):
            _scalar_literal(artifact, source)


# ------------------------------------------------------------------------------------------------ the C text

_EXP_C = """\
/* e^x in float32: fmath.exp_f32, the same operations in the same order (its docstring has the derivation).
 * x is clamped to [EXP_X_MIN, EXP_X_MAX] = [-80, 80] (NaN -> -80); n = round(x log2 e) by the shifter trick,
 * r = x - n ln2 in two parts (Cody-Waite), e^r = (P(r) r^2 + r) + 1 with the Cephes expf polynomial (Horner),
 * times 2^n built from its bits. Max error {max_ulp} ulp against the exact value. */
float fw_exp(float x)
{{
    fw_bits scale;
    float k, r, z, p;
    if (!(x >= EXP_X_MIN)) x = EXP_X_MIN;
    if (x > EXP_X_MAX) x = EXP_X_MAX;
    k = (x * EXP_LOG2E + EXP_SHIFTER) - EXP_SHIFTER;
    r = (x - k * EXP_LN2_HI) - k * EXP_LN2_LO;
    z = r * r;
{horner}
    scale.u = (uint32_t)((int32_t)k + {bias}) << 23;
    return ((p * z + r) + 1.0f) * scale.f;
}}
"""

_DOT_C = """\
/* fmath.matvec, one row: ((m[0] v[0] + m[1] v[1]) + m[2] v[2]) + ..., left to right, zeros included */
static float dot(const float *m, const float *v, int n)
{
    float acc = m[0] * v[0];
    int j;
    for (j = 1; j < n; j++) acc = acc + m[j] * v[j];
    return acc;
}
"""

_NODE_LOSSES_C = """\
/* Float32Estimator.node_losses: [P_y, P_w, P_t, P_m] in W from the {source} and the previous winding estimate:
 * copper temperature factor (eqs. 3-5), stator split k_s (eqs. 6-8) */
static void node_losses({parameters}, float losses[4])
{{
    float table[LOSS_TABLE_COUNT];
    float factor, p_w, i_ratio, n_ratio, k_s;
    {lookup}
    factor = 1.0f + fw_cal_alpha_cu * (y_est[1] - COPPER_REF);
    p_w = (table[0] * factor) + (table[1] / factor);
    i_ratio = table[4] / CURRENT_MAX;
    n_ratio = speed / SPEED_MAX;
    k_s = ((K_0 + K_1 * i_ratio) + K_2 * n_ratio) + (K_3 * i_ratio) * n_ratio;
    losses[0] = k_s * table[2];
    losses[1] = p_w;
    losses[2] = (1.0f - k_s) * table[2];
    losses[3] = table[3];
}}
"""

# the templates' call of node_losses (a loss-map row's torque and speed), replaced by the kind's own
_STEP_CALL = "node_losses(inputs[0], inputs[1], u);"


def _scalar_literal(artifact: ModelArtifact, source: tuple) -> str:
    """The literal of a scalar artifact field, or of one element of a vector field (keys ending in an index)."""
    if source and isinstance(source[-1], int):
        return _artifact_literals(artifact, *source[:-1])[source[-1]]
    return _artifact_literals(artifact, *source, shape=())[()]


def _loss_parameters(kind: LossKind) -> list[str]:
    """The row values node_losses takes: what the loss model reads, and the speed (eqs. 6-8), in row order."""
    read = set(kind.inputs) | {"speed_rpm"}
    return [name for name in C_NAMES if name in read]


def _common_c(kind: LossKind) -> str:
    """dot, the loss model's own C and node_losses."""
    node_losses = _NODE_LOSSES_C.format(
        source=kind.c_words, parameters=", ".join(f"float {C_NAMES[n]}" for n in _loss_parameters(kind)),
        lookup=f"{kind.c_function}({', '.join(C_NAMES[n] for n in kind.inputs)}, table);")
    return "\n".join([_DOT_C, kind.c_code, node_losses])


def _node_losses_call(kind: LossKind, row: tuple[str, ...]) -> str:
    """fw_step's call of node_losses with the row's values it takes."""
    return f"node_losses({', '.join(f'inputs[{row.index(n)}]' for n in _loss_parameters(kind))}, u);"


_API_C = """\
void fw_state(float x[4])
{{
    int i;
    for (i = 0; i < 4; i++) x[i] = x_state[i];
}}

void fw_output(float y[4])
{{
    int i;
    for (i = 0; i < 4; i++) y[i] = y_est[i];
}}

/* InputAccumulator.add: sum <- sum + sample, elementwise */
void fw_accumulate(const float sample[{width}])
{{
    int i;
    for (i = 0; i < {width}; i++) acc_sum[i] = acc_sum[i] + sample[i];
    acc_count = acc_count + 1u;
}}

/* InputAccumulator.add (interval complete): mean = sum / float32(count), then cleared */
unsigned int fw_mean(float u[{width}])
{{
    const unsigned int count = acc_count;
    int i;
    if (count == 0u) return 0u;
    for (i = 0; i < {width}; i++) u[i] = acc_sum[i] / (float)count;
    fw_clear();
    return count;
}}

/* InputAccumulator.clear */
void fw_clear(void)
{{
    int i;
    for (i = 0; i < {width}; i++) acc_sum[i] = 0.0f;
    acc_count = 0u;
}}
"""

_HEADER = """\
/* {header} - the {kind} model ({realization} realization, dt {dt} s) as C99 firmware.
 * Generated by 'bench firmware export' from the model artifact with sha256
 * {sha256}.
 * Do not edit: regenerate it from the artifact.
 *
 * Portable C99 (no libc, no malloc, no double, no recursion): every operation in float32, in the same order as
 * the bench's Python reference (target_sim.model), so both give the same bits. Compile with FMA contraction off
 * (-ffp-contract=off) and without -ffast-math, under round-to-nearest with denormals kept (the FPU's reset state).
 *
 * The model state lives in this module's static RAM (.bss): one model instance. Typical use on the target:
 *   fw_reset(y0);                              at start, from measured temperatures
 *   every 5 Hz drive sample:  fw_accumulate(sample);
 *   when an interval of FW_DT_S has ended:  if (fw_mean(u)) fw_step(u, y);
 *   every N steps, send fw_state(x) as a checkpoint; after a restart fw_restore(x) continues bit for bit.
 * Deciding WHEN an interval ends (integer row logic: step k takes the samples in [k dt, (k+1) dt)) is the
 * caller's job, as in target_sim.model.InputAccumulator.
 *
 * Temperatures are [yoke, winding, tooth, magnet] in deg C; drive inputs [{inputs_doc}]
 * ({loss_doc}). No function keeps a pointer it was given; arrays may not overlap.
 */
#ifndef FW_MODEL_H
#define FW_MODEL_H

#include <stdint.h> /* uint32_t: a header of the compiler's, not of a libc (C99 freestanding) */

/* What this file was generated from: model kind, realization, model step and drive data period (s), and the
 * first 32 bits of the artifact's sha256 (the model's identity on the bus). */
#define FW_MODEL_KIND "{kind}"
#define FW_REALIZATION "{realization}"
#define FW_DT_S {dt_literal}
#define FW_SAMPLE_PERIOD_S {sample_literal}
#define FW_MODEL_ID 0x{model_id:08x}u
#define FW_LOSS_MODEL "{loss_model}"
#define FW_INPUTS {width} /* drive values per sample and per model step: 4, or 6 with the d/q currents */

/* The first 32 bits of the artifact's sha256, what the target reports on the bus (= FW_MODEL_ID), kept in the
 * image so a flashed firmware can be matched with its artifact. */
extern const uint32_t fw_model_id;

/* What the node's XCP slave (xcp.c) shows a calibration tool at these symbols' addresses (the A2L's): the model's
 * state x and outputs y (read-only), and its calibratable copper temperature coefficient (losses.alpha_cu_per_K,
 * 1/K; target_sim.xcp.variables' cal_alpha_cu), which the loss correction reads at every step. */
extern float x_state[4];
extern float y_est[4];
extern float fw_cal_alpha_cu;

/* Start from temperatures y0: y = y0, x = C_inv y0 (delta: C_inv (y0 - r); pv-lptn: x = y0); clears the
 * accumulator. */
void fw_reset(const float y0[4]);

/* Continue from a checkpointed state vector x, bit for bit: y = C x (pv-lptn: y = x); accumulator cleared. */
void fw_restore(const float x[4]);

/* The state vector x (the realization's coordinates): what a StateCheckpoint carries. */
void fw_state(float x[4]);

/* The latest outputs y [yoke, winding, tooth, magnet] (deg C): y0 after fw_reset, else the last step's. */
void fw_output(float y[4]);

/* One model step from the interval means u = [{inputs}]; writes the outputs to y. */
void fw_step(const float u[{width}], float y[4]);

/* Add one drive sample [{inputs}] to the interval sum (float32, elementwise). */
void fw_accumulate(const float sample[{width}]);

/* The float32 mean of the accumulated samples into u, then clear; returns their count (0: u untouched). */
unsigned int fw_mean(float u[{width}]);

/* Forget the accumulated samples. */
void fw_clear(void);

/* The model's own e^x in float32 (argument clamped to [-80, 80], NaN -> -80; max error {max_ulp} ulp), the
 * function target_sim.fmath.exp_f32 equals bit for bit; exposed for verification. */
float fw_exp(float x);

#endif /* FW_MODEL_H */
"""

def _scalar_constants(artifact: ModelArtifact) -> list[tuple[str, str, str]]:
    """(C name, literal, comment) of every scalar the step may use; only the used ones are emitted."""
    out: list[tuple[str, str, str]] = []
    for name in ("C_y", "C_w", "C_t", "C_m", "R_yw", "R_yt", "R_wt", "R_cy0", "R_wm0", "a_wm", "b_wm", "R_tm0",
                 "a_tm", "b_tm", "R_ma0", "a_ma", "b_ma", "alpha_cy", "k_0", "k_1", "k_2", "k_3"):
        literal = _artifact_literals(artifact, "lptn", "parameters", name, shape=())[()]
        out.append((name.upper(), literal, f"lptn.parameters.{name}"))
    for c_name, keys in (("SPEED_MAX", ("lptn", "speed_max_rpm")), ("CURRENT_MAX", ("losses", "current_max_A")),
                         ("ALPHA_CU", ("losses", "alpha_cu_per_K")),
                         ("COPPER_REF", ("losses", "copper_reference_C"))):
        out.append((c_name, _artifact_literals(artifact, *keys, shape=())[()], ".".join(keys)))
    kinds = (LOSS_KINDS[artifact.loss_model], MODEL_KINDS[artifact.kind])   # the loss model's, then the kind's
    for name, source, comment in (scalar for kind in kinds for scalar in kind.c_scalars(artifact)):
        literal = _scalar_literal(artifact, source) if isinstance(source, tuple) else c_float(source)
        out.append((name, literal, comment))
    out += [("COOLANT_REF", c_float(np.float32(COOLANT_REFERENCE_C)), "coolant temperature of R_cy0 (eq. 16)"),
            ("DT", c_float(np.float32(artifact.dt)), "timing.dt_s: the model step (s)")]
    return out


# the scalars a calibration tool may change (XCP DOWNLOAD): C name in the step -> the RAM variable it reads
CALIBRATABLE = {"ALPHA_CU": ALPHA_CU_SYMBOL}


def _calibratable(artifact: ModelArtifact) -> list[tuple[str, str, str, str]]:
    """(name in the step, RAM variable, initial literal, comment) of each calibratable scalar (always emitted: the
    node's XCP table names them)."""
    return [(name, CALIBRATABLE[name], literal, comment) for name, literal, comment in _scalar_constants(artifact)
            if name in CALIBRATABLE]


def _value_comment(literal: str) -> str:
    return f"{np.float32(float.fromhex(literal[:-1])):.9g}"


def generate(artifact: ModelArtifact) -> GeneratedSource:
    """The C header and source of `artifact`'s model (kind and realization as the artifact says)."""
    check_expressible(artifact)
    kind = artifact.kind
    model_id = artifact.model_id
    dt_literal = c_float(np.float32(artifact.dt))
    sample_literal = c_float(np.float32(artifact.data_sample_period))
    loss_model = artifact.loss_model
    loss_kind = LOSS_KINDS[loss_model]
    model_kind = MODEL_KINDS[kind]
    observer = has_observer(artifact)     # the observer's C only for an observer's artifact (open loop: as before)
    row = artifact.drive_signals
    width = len(row)     # 4 drive values, 6 with the d/q currents
    currents = reads_currents(row)
    inputs = "torque, speed, coolant, ambient" + (", i_d, i_q" if currents else "")
    inputs_doc = "torque Nm, speed rpm, coolant deg C,\n * ambient deg C" + (", i_d A, i_q A" if currents else "")
    loss_doc = loss_kind.summary
    header = _HEADER.format(header=HEADER_NAME, kind=kind, realization=artifact.realization, dt=f"{artifact.dt:g}",
                            sha256=artifact.sha256, dt_literal=dt_literal, sample_literal=sample_literal,
                            model_id=model_id, max_ulp=EXP_MAX_ULP, loss_model=loss_model, width=width,
                            inputs=inputs, inputs_doc=inputs_doc, loss_doc=loss_doc)

    if observer:
        header = (header.replace(f"void fw_accumulate(const float sample[{width}]);",
                                 "void fw_accumulate(const float sample[FW_SAMPLE_WIDTH]);")
                  .replace(f"unsigned int fw_mean(float u[{width}]);",
                           "unsigned int fw_mean(float u[FW_SAMPLE_WIDTH]);")
                  .replace("#endif /* FW_MODEL_H */", observer_header(artifact) + "\n#endif /* FW_MODEL_H */"))
        header = re.sub(r"(#define FW_INPUTS [^\n]*\n)", lambda m: m.group(1) + observer_defines(artifact), header)

    # the code first: only the constants it names are emitted (an unused static const is a warning)
    horner = [f"    p = EXP_{EXP_POLYNOMIAL[0]};"]
    horner += [f"    p = p * r + EXP_{name};" for name in EXP_POLYNOMIAL[1:]]
    code = [_EXP_C.format(horner="\n".join(horner), bias=EXP_EXPONENT_BIAS, max_ulp=EXP_MAX_ULP),
            _common_c(loss_kind)]
    functions = model_kind.c_functions(artifact)     # the kind's own (sigmoid, sources, network)
    code += [keep_gains(text) if observer and "temperature_sources(" in text else text for text in functions]
    step = model_kind.c_step(artifact)
    # fw_step takes the row's width of inputs and hands node_losses what the loss model needs
    step = step.replace("void fw_step(const float inputs[4], float y[4])",
                        f"void fw_step(const float inputs[{width}], float y[4])")
    code.append(step.replace(_STEP_CALL, _node_losses_call(loss_kind, row)))
    # a sample (and a step's interval mean) of an observer's model carries its raw channels after the drive values
    sample_width = width + observer_channels(artifact) if observer else width
    code.append(_API_C.format(width=sample_width))
    if observer:
        code.append(observer_code(artifact))
    code_text = "\n".join(code)
    used = set(re.findall(r"\b[A-Z][A-Z0-9_]*\b", code_text))

    parts = [f"/* {SOURCE_NAME} - generated by 'bench firmware export' from the model artifact with sha256\n"
             f" * {artifact.sha256} ({kind}, {artifact.realization} realization, dt {artifact.dt:g} s).\n"
             " * Do not edit: regenerate it. The Python reference it equals bit for bit is target_sim.model;\n"
             " * each function below names the method it mirrors. */\n",
             f'#include <float.h>\n#include "{HEADER_NAME}"\n',
             "/* Type punning through a union: defined behaviour in C99 (TC3), used to build 2^n from its bits;\n"
             " * float must be IEEE binary32 (a negative array size stops the build otherwise). */\n"
             "typedef union {\n    float f;\n    uint32_t u;\n} fw_bits;\n"
             "typedef char fw_float_is_binary32[(sizeof(float) == sizeof(uint32_t) && FLT_MANT_DIG == 24) ? 1 : -1];\n",
             f"const uint32_t fw_model_id = 0x{model_id:08x}u;\n",
             "/* ---- coefficients: float32, written exactly as the artifact's f32_hex ---- */\n"]
    exp_lines = [f"static const float EXP_{name} = {c_float(value)}; /* {float(value):.9g} */"
                 for name, value in EXP_CONSTANTS.items()]
    parts.append("/* fw_exp's constants (target_sim.fmath.EXP_CONSTANTS) */\n" + "\n".join(exp_lines) + "\n")
    calibratable = {name for name, _, _, _ in _calibratable(artifact)}
    scalars = [f"static const float {name} = {literal}; /* {comment} = {_value_comment(literal)} */"
               for name, literal, comment in _scalar_constants(artifact) if name in used and name not in calibratable]
    parts.append("\n".join(scalars) + "\n")
    # the calibratable scalars: in RAM (.data), written by the XCP slave's DOWNLOAD, read by the step
    parts.append("".join(f"float {symbol} = {literal}; /* {comment} = {_value_comment(literal)}, calibratable */\n"
                         for name, symbol, literal, comment in _calibratable(artifact)))
    defines, arrays = loss_kind.c_declarations(artifact)
    parts.append("".join(f"{line}\n" for line in defines))
    for array in arrays + model_kind.c_arrays(artifact):   # the loss model's, then the kind's
        stacked = np.stack([_artifact_literals(artifact, *keys, shape=array.shape) for keys in array.fields])
        literals = stacked if len(array.fields) > 1 else stacked[0]
        parts.append(_c_shared_rows(array.name, literals, array.comment) if array.shared_rows
                     else _c_array(array.name, literals, array.comment))
    parts.append("/* ---- state (.bss): x, the latest outputs y, the interval sum and count ---- */\n"
                 "float x_state[4];\n"
                 f"float y_est[4]; /* [{', '.join(OUTPUTS)}] */\n"
                 f"static float acc_sum[{sample_width}];\n"
                 "static unsigned int acc_count;\n")
    if observer:
        parts.append(observer_declarations(artifact))
    parts.append(code_text)
    node = {CONFIG_NAME: node_config(artifact), **packers()}
    # each loop's count, stated where the WCET analysis finds it (bench.firmware.loopfacts)
    return GeneratedSource(header=header, source=annotate_loops("\n".join(parts)), node=node)
