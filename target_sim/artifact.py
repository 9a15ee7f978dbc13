"""The model artifact: the contract between `bench` (which builds it) and the target (which runs it).

A JSON document, schema-versioned and sealed with a sha256 over its canonical form. Every coefficient is kept
twice: `f64` (the value it was derived from) and `f32_hex` (the float32 the target runs, as an exact hex string,
`float.hex()` of the rounded value). Loading verifies the schema, the checksum and that every f32 value is the
float32 rounding of its f64 twin, and refuses anything else in one sentence. Like firmware, this module knows
only json, hashlib and numpy.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dbc.contract import TEMPERATURE_NODES
from target_sim.errors import TargetError
from target_sim.kinds import MODEL_KINDS, REALIZATIONS
from target_sim.losses import DEFAULT as DEFAULT_LOSS_MODEL
from target_sim.losses import LOSS_KINDS, row_signals

SCHEMA = "pmsm-thermal-bench.model-artifact"
SCHEMA_VERSION = 3
# Version 1 had loss maps only (no losses.model); it is read as "maps". Version 3 is version 2 plus the optional
# `observer` section; an artifact without one is written as version 2 (what every earlier target reads).
READABLE_VERSIONS = (1, 2, 3)
OBSERVER_VERSION = 3
# the observer section's own version: 1 (absent) one unlagged sensor of one node; 2 a list of measurements of
# `target_sim.observer.measurements` kinds, lag states and an optional heat bias state (`BIAS_KINDS`: its node's
# loss input)
OBSERVER_SECTION_VERSIONS = (1, 2)
# The observer section (`target_sim.observer`): its arrays and shapes ((): a scalar), in the realization's
# coordinates; `node` names the measured output, `form` the covariance form the target deploys.
OBSERVER_ARRAYS = {"Q": (4, 4), "q_nodes_C2": (4,), "R": (), "P0": (4, 4), "offset_C": (), "K_ss": (4,),
                   "P_ss": (4, 4)}
OBSERVER_FORM_NAMES = ("conventional", "joseph", "ud", "steady")   # target_sim.observer.OBSERVER_FORMS
# The delta realization's linear block is x <- x + Δ·(A x + B ũ), y = C x + r, with ũ the inputs whose four
# temperature sources are taken relative to r = linear_block.reference_C (the states are deviations from r).
OUTPUTS = TEMPERATURE_NODES   # the model's outputs: the temperatures in the state order (dbc.contract)
# The observer's bias kinds (its section's `bias`, null: none): a state of watts into one node the loss model
# misses, a random walk, and the column of B it heats: its node's loss input (the inputs P_y, P_w, P_t, P_m are in
# the order of OUTPUTS). The one table of them: the target, the firmware generator and the lab read it here.
BIAS_KINDS = {"winding-heat": 1, "magnet-heat": 3, "winding-output": 1}
# Of those, the kinds whose state is added to its node's output instead (°C: the model's error at that node, a random
# walk that the node's sensors see and the estimate reports) and heats nothing: every measurement that reads the node
# holds all four nodes (`consider_held`), so the model's dynamics, and the magnet with them, stay the open loop's.
# Why: on the motor suite's validation profiles a winding sensor that corrects the winding node drives the magnet
# through the model's winding-magnet coupling (IPM: magnet MSE 1.38 -> 9.8 K² while the winding went 22.4 -> 0.4);
# the output bias brings the winding to 0.2-0.4 K² and leaves the magnet exactly as the model has it.
OUTPUT_BIAS_KINDS = ("winding-output",)
# The observer's consider kinds (its section's `consider`; absent or null: none): states that a measurement which
# does not read them never updates (Schmidt-Kalman "consider" states: their rows of the gain are zero, the covariance
# is the one of that gain). A kind names its nodes of OUTPUTS; a bias state is held with its node (BIAS_KINDS: the
# bias heats that node). A measurement "reads" a node when its `sees` weighs it (the flux linkage reads the magnet; a
# winding NTC does not, so it cannot move the magnet through a coupling the model may have wrong). "unmeasured": every
# node the measurement does not read (an end-winding NTC moves neither the magnet nor the tooth, which reaches the
# magnet through the tooth-magnet path; with a gradient it reads the yoke too, which it then updates).
CONSIDER_KINDS = {"magnet": ("magnet",), "unmeasured": OUTPUTS}   # of those, the ones not read
# losses.model names a loss model of `target_sim.losses` ("maps", "electrical", ...), which owns its fields
LPTN_PARAMETERS = ("C_y", "C_w", "C_t", "C_m", "R_yw", "R_yt", "R_wt", "R_cy0", "R_wm0", "a_wm", "b_wm", "R_tm0",
                   "a_tm", "b_tm", "R_ma0", "a_ma", "b_ma", "alpha_cy", "k_0", "k_1", "k_2", "k_3")


class ArtifactError(TargetError):
    """The artifact cannot be used; the message says why and what to do."""


def encode_array(values) -> dict[str, Any]:
    """{"shape", "f64", "f32_hex"} for a scalar, vector or matrix."""
    arr = np.asarray(values, dtype=np.float64)
    flat64 = [float(v) for v in arr.ravel()]
    flat32 = [float(v).hex() for v in arr.astype(np.float32).astype(np.float64).ravel()]
    return {"shape": list(arr.shape), "f64": flat64, "f32_hex": flat32}


def decode_array(entry: dict[str, Any], where: str, dtype=np.float32) -> np.ndarray:
    """The float32 (or float64) array of an encoded entry, checking shape and f32/f64 agreement."""
    try:
        if not isinstance(entry, dict):
            raise TypeError(f"expected an object with shape, f64 and f32_hex, not {type(entry).__name__}")
        raw_shape, raw_f64, raw_f32 = entry["shape"], entry["f64"], entry["f32_hex"]
        if not isinstance(raw_shape, list) or not all(type(n) is int and 0 <= n <= 1 << 16 for n in raw_shape) \
                or len(raw_shape) > 2:
            raise ValueError(f"shape {_shown(raw_shape)} is not a list of at most two sizes")
        if not isinstance(raw_f64, list) or not all(type(v) in (int, float) for v in raw_f64):
            raise ValueError("f64 is not a flat list of numbers")
        if not isinstance(raw_f32, list) or not all(isinstance(h, str) and len(h) < 64 for h in raw_f32):
            raise ValueError("f32_hex is not a flat list of hex strings")
        shape = tuple(raw_shape)
        f64 = np.array(raw_f64, dtype=np.float64)
        f32 = np.array([float.fromhex(h) for h in raw_f32], dtype=np.float64)
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise ArtifactError(f"artifact field {where} is malformed ({_shown(exc, 120)}); "
                            "rebuild it with 'bench identify'") from None
    if f64.size != int(np.prod(shape, dtype=np.int64)) or f32.size != f64.size:
        raise ArtifactError(f"artifact field {where} does not have shape {list(shape)}; "
                            "rebuild it with 'bench identify'")
    with np.errstate(over="ignore", invalid="ignore"):
        rounded = f64.astype(np.float32).astype(np.float64)
    if not np.array_equal(rounded, f32, equal_nan=False):
        raise ArtifactError(f"artifact field {where}: the float32 values are not the rounding of the float64 ones; "
                            "rebuild it with 'bench identify'")
    return (f32 if dtype == np.float32 else f64).reshape(shape).astype(dtype)


def canonical_bytes(content: dict[str, Any]) -> bytes:
    body = {k: v for k, v in content.items() if k != "sha256"}
    return json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def seal(content: dict[str, Any]) -> dict[str, Any]:
    """The content with its sha256 added (over everything else, canonical JSON)."""
    sealed = {k: v for k, v in content.items() if k != "sha256"}
    sealed["sha256"] = hashlib.sha256(canonical_bytes(sealed)).hexdigest()
    return sealed


def dumps(content: dict[str, Any]) -> str:
    return json.dumps(seal(content), indent=1, allow_nan=False) + "\n"


@dataclass(frozen=True)
class ModelArtifact:
    """A verified artifact: the raw content plus the float32 arrays the target runs."""

    content: dict[str, Any]
    path: Path | None

    @property
    def sha256(self) -> str:
        return self.content["sha256"]

    @property
    def model_id(self) -> int:
        """The first 32 bits of the checksum: what the target reports on the bus as its identity."""
        return int(self.sha256[:8], 16)

    @property
    def kind(self) -> str:
        return self.content["model_kind"]

    @property
    def realization(self) -> str:
        return self.content["realization"]

    @property
    def dt(self) -> float:
        return float(self.content["timing"]["dt_s"])

    @property
    def data_sample_period(self) -> float:
        return float(self.content["timing"]["data_sample_period_s"])

    @property
    def loss_model(self) -> str:
        return loss_model_of(self.content)

    @property
    def drive_signals(self) -> tuple[str, ...]:
        """The per-row values the model needs, in accumulation order (4, or 6 with the d/q currents)."""
        return row_signals(LOSS_KINDS[self.loss_model].inputs)

    def array(self, *keys: str, dtype=np.float32) -> np.ndarray:
        node = self.content
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                raise ArtifactError(f"artifact is missing the field {'.'.join(keys)}; rebuild it with 'bench identify'")
            node = node[key]
        return decode_array(node, ".".join(keys), dtype)


def _require(content: dict, key: str, kind: type | tuple[type, ...]):
    if key not in content:
        raise ArtifactError(f"artifact is missing the field {key!r}; rebuild it with 'bench identify'")
    if not isinstance(content[key], kind):
        raise ArtifactError(f"artifact field {key!r} has the wrong type; rebuild it with 'bench identify'")
    return content[key]


def _shown(value: Any, limit: int = 40) -> str:
    """A value of the file for a one-line message: repr, shortened."""
    try:
        shown = repr(value)
    except (RecursionError, ValueError):  # a deeply nested value, an int too long to print
        shown = f"<{type(value).__name__}>"
    return shown if len(shown) <= limit else shown[: limit - 4] + "…" + shown[-3:]


# Bounds of the timing an artifact may carry (s): anything else cannot be a model step or a CAN data rate.
TIMING_RANGE_S = (1e-3, 3600.0)


def verify(content: Any, path: Path | None = None) -> ModelArtifact:
    """Check schema, checksum, every array and its shape; return the artifact or raise ArtifactError."""
    if not isinstance(content, dict):
        raise ArtifactError("artifact is not a JSON object; rebuild it with 'bench identify'")
    if content.get("schema") != SCHEMA:
        raise ArtifactError(f"this is not a model artifact (schema {_shown(content.get('schema'))}, expected "
                            f"{SCHEMA!r}); pass a file written by 'bench identify'")
    version = content.get("schema_version")
    if type(version) is not int or version not in READABLE_VERSIONS:
        raise ArtifactError(f"artifact schema version {_shown(version)} is not supported "
                            f"(this target runs versions {READABLE_VERSIONS[0]} to {READABLE_VERSIONS[-1]}); "
                            "rebuild it with 'bench identify'")
    try:
        expected = hashlib.sha256(canonical_bytes(content)).hexdigest()
    except (TypeError, ValueError, RecursionError) as exc:  # NaN/Infinity, non-string keys, absurd nesting
        reason = "nested too deeply" if isinstance(exc, RecursionError) else str(exc).split(";")[0]
        raise ArtifactError(f"artifact content is not plain JSON ({reason}); rebuild it with 'bench identify'"
                            ) from None
    if content.get("sha256") != expected:
        raise ArtifactError("artifact checksum does not match its content (corrupted or edited); "
                            "rebuild it with 'bench identify'")
    kind = _require(content, "model_kind", str)
    if kind not in MODEL_KINDS:
        raise ArtifactError(f"artifact model kind {_shown(kind)} is not one of {', '.join(MODEL_KINDS.names())}; "
                            "rebuild it with 'bench identify'")
    if _require(content, "realization", str) not in REALIZATIONS:
        raise ArtifactError(f"artifact realization {_shown(content['realization'])} is not one of "
                            f"{', '.join(REALIZATIONS.names())}; rebuild it with 'bench identify'")
    losses = _require(content, "losses", dict)
    model = losses.get("model", DEFAULT_LOSS_MODEL)
    if not isinstance(model, str) or model not in LOSS_KINDS or (version == 1 and "model" in losses):
        raise ArtifactError(f"artifact losses.model {_shown(model)} is not one of {', '.join(LOSS_KINDS.names())}; "
                            "rebuild it with 'bench identify'")
    timing = _require(content, "timing", dict)
    low, high = TIMING_RANGE_S
    for key in ("dt_s", "data_sample_period_s"):
        value = timing.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
            raise ArtifactError(f"artifact timing.{key} is {_shown(value)}, it must be a number of seconds from "
                                f"{low:g} to {high:g}; rebuild it with 'bench identify'")
    artifact = ModelArtifact(content, path)
    shapes = _expected_shapes(content)
    for keys in _array_fields(content):
        values = artifact.array(*keys)  # decodes and cross-checks every array once
        where = ".".join(keys)
        expected_shape = shapes.get(keys, ())
        if values.shape != expected_shape:
            raise ArtifactError(f"artifact field {where} has shape {list(values.shape)}, the target needs "
                                f"{list(expected_shape)}; rebuild it with 'bench identify'")
        if not np.all(np.isfinite(values)):
            raise ArtifactError(f"artifact field {where} holds a value that is not finite in float32; "
                                "rebuild it with 'bench identify'")
    if "observer" in content:
        _check_observer(artifact, version)
    problem = LOSS_KINDS[model].problem(artifact)
    if problem:
        raise ArtifactError(f"{problem}; rebuild it with 'bench identify'")
    unstable = MODEL_KINDS[kind].instability(artifact)   # a step that grows without bound (the sentence has its fix)
    if unstable:
        raise ArtifactError(unstable)
    return artifact


def schema_version_of(content: dict) -> int:
    """The version an artifact is written as: the lowest that describes its content (an observer needs 3)."""
    return OBSERVER_VERSION if "observer" in content else 2


def _check_observer(artifact: ModelArtifact, version: int) -> None:
    """The observer section: a version 3 artifact of a kind with a linear block, a measured output, a known form,
    R > 0, Q symmetric positive semidefinite, P0 and P_ss symmetric positive definite (in float64, the
    filter the artifact describes)."""
    section = artifact.content["observer"]
    fix = "rebuild it with 'bench observer'"
    if version < OBSERVER_VERSION:
        raise ArtifactError(f"artifact schema version {version} has no observer section (version "
                            f"{OBSERVER_VERSION} has); {fix}")
    if not isinstance(section, dict):
        raise ArtifactError(f"artifact field 'observer' has the wrong type; {fix}")
    if not MODEL_KINDS[artifact.kind].linear_block:
        raise ArtifactError(f"artifact of kind {artifact.kind} carries an observer, which needs a linear block; {fix}")
    if section.get("node") not in OUTPUTS:
        raise ArtifactError(f"artifact observer.node {_shown(section.get('node'))} is not one of "
                            f"{', '.join(OUTPUTS)}; {fix}")
    if section.get("form") not in OBSERVER_FORM_NAMES:
        raise ArtifactError(f"artifact observer.form {_shown(section.get('form'))} is not one of "
                            f"{', '.join(OBSERVER_FORM_NAMES)}; {fix}")
    if section_version(section) >= 2:
        try:
            n = observer_state_count(section)
        except (KeyError, TypeError, ValueError, ArtifactError) as exc:
            raise ArtifactError(f"artifact observer.measurements is not readable ({exc}); {fix}") from None
        bias = section.get("bias")
        if bias is not None and (not isinstance(bias, str) or bias not in BIAS_KINDS):
            raise ArtifactError(f"artifact observer.bias {_shown(bias)} is not one of {', '.join(BIAS_KINDS)} or "
                                f"null; {fix}")
        if n != len(section["states"]):
            raise ArtifactError(f"artifact observer.states names {len(section['states'])} states, its measurements "
                                f"and bias make {n}; {fix}")
    _check_gate(section.get("gate"), fix)
    consider = section.get("consider")
    if consider is not None and (not isinstance(consider, str) or consider not in CONSIDER_KINDS):
        raise ArtifactError(f"artifact observer.consider {_shown(consider)} is not one of "
                            f"{', '.join(CONSIDER_KINDS)} or null; {fix}")
    if section.get("consider_release_C2") is not None:
        release = artifact.array("observer", "consider_release_C2", dtype=np.float64)
        if consider is None or release.shape != () or not (np.isfinite(release) and release > 0):
            raise ArtifactError("artifact observer.consider_release_C2 must be one finite variance > 0 beside a "
                                f"consider kind; {fix}")
    if not np.all(artifact.array("observer", "q_nodes_C2", dtype=np.float64) >= 0):
        raise ArtifactError(f"artifact observer.q_nodes_C2 holds a negative variance; {fix}")
    for key in ("R", "Q", "P0", "P_ss"):
        value = artifact.array("observer", key, dtype=np.float64)
        if key == "R":
            if not value > 0:
                raise ArtifactError(f"artifact observer.R is {float(value):g}, a measurement variance must be "
                                    f"positive; {fix}")
            continue
        scale = max(float(np.max(np.abs(value))), np.finfo(float).tiny)
        if not np.allclose(value, value.T, rtol=0, atol=1e-9 * scale):
            raise ArtifactError(f"artifact observer.{key} is not symmetric; {fix}")
        low = float(np.min(np.linalg.eigvalsh((value + value.T) / 2)))
        if low < (-1e-9 * scale if key == "Q" else 1e-300) or (key != "Q" and low <= 0):
            kind = "positive semidefinite" if key == "Q" else "positive definite"
            raise ArtifactError(f"artifact observer.{key} is not {kind} (smallest eigenvalue {low:.3g}); {fix}")


def _check_gate(gate: Any, fix: str) -> None:
    """The optional innovation gate (`observer_gate`): absent or null, or {"sigma": a finite number > 0,
    "flag_after": an integer >= 1}."""
    if gate is None:
        return
    sigma = gate.get("sigma") if isinstance(gate, dict) else None
    after = gate.get("flag_after") if isinstance(gate, dict) else None
    if (not isinstance(gate, dict) or set(gate) != {"sigma", "flag_after"}
            or isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not math.isfinite(sigma)
            or not sigma > 0 or isinstance(after, bool) or not isinstance(after, int) or after < 1):
        raise ArtifactError(f"artifact observer.gate {_shown(gate)} is not {{\"sigma\": a number > 0, "
                            f"\"flag_after\": an integer >= 1}} or null; {fix}")


def observer_gate(section: dict) -> tuple[float, int] | None:
    """The section's innovation gate: (sigma, flag_after), None without one (a reading with ν² > sigma² S is
    rejected; `flag_after` consecutive rejections of one measurement flag its sensor)."""
    gate = section.get("gate")
    return None if gate is None else (float(gate["sigma"]), int(gate["flag_after"]))


def consider_release(section: dict) -> float | None:
    """The section's key-on release (`consider_release_C2`, °C²): a held magnet whose variance before an update exceeds
    it is updated as an ordinary state; None without one (absent or null: held always, as before)."""
    entry = section.get("consider_release_C2")
    return None if entry is None else float(decode_array(entry, "observer.consider_release_C2", np.float64))


def _expected_shapes(content: dict) -> dict[tuple[str, ...], tuple[int, ...]]:
    """The shape the target's code needs for each non-scalar array field (scalars are ())."""
    kind = LOSS_KINDS[loss_model_of(content)]
    shapes = {("losses", *keys): shape for keys, shape in kind.shapes(content["losses"]).items()}
    shapes.update(MODEL_KINDS[content["model_kind"]].shapes(content))
    if isinstance(content.get("observer"), dict):
        shapes.update({("observer", key): shape for key, shape in observer_shapes(content["observer"]).items()
                       if shape})
    return shapes


def section_version(section: dict) -> int:
    """The observer section's version (1 when absent); a version this target does not read is refused."""
    version = section.get("version", 1)
    if type(version) is not int or version not in OBSERVER_SECTION_VERSIONS:
        raise ArtifactError(f"artifact observer.version {_shown(version)} is not supported (this target reads "
                            f"observer sections of versions {OBSERVER_SECTION_VERSIONS[0]} to "
                            f"{OBSERVER_SECTION_VERSIONS[-1]}); rebuild it with 'bench observer' or update the bench")
    return version


def observer_state_count(section: dict) -> int:
    """The filter's states: 4 model states, one lag state per measurement with a lag (its `arrays.lag_pole` > 0),
    one bias state if `bias` is set (version 1: 4)."""
    if section_version(section) < 2:
        return len(OUTPUTS)
    lags = 0
    for i, entry in enumerate(section["measurements"]):
        pole = entry["arrays"].get("lag_pole")
        if pole is not None and decode_array(pole, f"observer.measurements[{i}].arrays.lag_pole", np.float64) > 0:
            lags += 1
    return len(OUTPUTS) + lags + (1 if section.get("bias") else 0)


def consider_held(consider: str | None, sees: np.ndarray, bias: str | None, states: int) -> np.ndarray:
    """(measurements, states) booleans: the states each measurement's update leaves as they are (`CONSIDER_KINDS`):
    for a measurement whose `sees` (a row of 4 node weights) does not weigh one of the kind's nodes, that node (its
    index in OUTPUTS: the filter's node coordinates) and, when the section's bias heats that node, the bias state (the
    last)."""
    sees = np.atleast_2d(np.asarray(sees, dtype=np.float64))
    held = np.zeros((len(sees), states), dtype=bool)
    bias_node = BIAS_KINDS[bias] if bias else None
    if bias in OUTPUT_BIAS_KINDS:      # a reading of the output bias's node moves the bias, never a node
        held[sees[:, bias_node] != 0, :len(OUTPUTS)] = True
        bias_node = None
    if consider is None:
        return held
    for name in CONSIDER_KINDS[consider]:
        node = OUTPUTS.index(name)
        for m, row in enumerate(sees):
            if row[node] == 0:
                held[m, node] = True
                if bias_node == node:
                    held[m, states - 1] = True
    return held


def consider_released(held: np.ndarray, bias: str | None) -> np.ndarray:
    """`held` (`consider_held`) with the magnet and a magnet heat bias free: what a measurement holds while the
    magnet's own variance exceeds the section's `consider_release_C2` (key-on, a magnet nobody measured)."""
    released = np.array(held, dtype=bool, copy=True)
    if bias in OUTPUT_BIAS_KINDS:      # what the output bias holds it holds always
        return released
    released[:, OUTPUTS.index("magnet")] = False
    if bias is not None and OUTPUTS[BIAS_KINDS[bias]] == "magnet":
        released[:, -1] = False
    return released


def observer_shapes(section: dict) -> dict[str, tuple[int, ...]]:
    """The observer arrays' shapes: version 1 as `OBSERVER_ARRAYS`; version 2 with n = len(states) (the model's
    4, a lag state per lagged measurement, the bias) and K_ss one row per measurement."""
    if section_version(section) < 2:
        return OBSERVER_ARRAYS
    states, measurements = section.get("states"), section.get("measurements")
    if not (isinstance(states, list) and len(states) >= 4 and isinstance(measurements, list) and measurements):
        raise ArtifactError("artifact observer version 2 needs a list of states (at least 4) and of measurements; "
                            "rebuild it with 'bench observer'")
    n, m = len(states), len(measurements)
    return {"Q": (n, n), "q_nodes_C2": (n,), "R": (), "P0": (n, n), "offset_C": (), "K_ss": (m, n), "P_ss": (n, n)}


# the sections in the order their fields are checked (a model kind's own sections after these)
SECTIONS = ("linear_block", "lptn", "losses", "input_nonlinearity", "observer")


def _array_fields(content: dict) -> list[tuple[str, ...]]:
    fields = MODEL_KINDS[content["model_kind"]].fields(content)
    fields += [("lptn", "parameters", name) for name in LPTN_PARAMETERS]
    fields += [("lptn", "speed_max_rpm")]
    fields += [("losses", k) for k in ("current_max_A", "alpha_cu_per_K", "copper_reference_C")]
    fields += [("losses", *keys) for keys in LOSS_KINDS[loss_model_of(content)].fields(content["losses"])]
    if isinstance(content.get("observer"), dict):
        fields += [("observer", key) for key in OBSERVER_ARRAYS]
    fields.sort(key=lambda keys: SECTIONS.index(keys[0]) if keys[0] in SECTIONS else len(SECTIONS))
    for keys in fields:
        node = content
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                raise ArtifactError(f"artifact is missing the field {'.'.join(keys)}; rebuild it with 'bench identify'")
            node = node[key]
    return fields


def loss_model_of(content: dict) -> str:
    """The artifact's loss model; version 1 artifacts (no losses.model) have loss maps."""
    losses = content.get("losses")
    return losses.get("model", DEFAULT_LOSS_MODEL) if isinstance(losses, dict) else DEFAULT_LOSS_MODEL


def load_artifact(path: str | Path) -> ModelArtifact:
    """Read and verify an artifact file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ArtifactError(f"model artifact {path} does not exist; pass an existing file with --model") from None
    except IsADirectoryError:
        raise ArtifactError(f"model artifact {path} is a directory; pass the artifact's JSON file with --model"
                            ) from None
    except UnicodeDecodeError:
        raise ArtifactError(f"model artifact {path} is not UTF-8 JSON text (corrupted or not an artifact); "
                            "rebuild it with 'bench identify'") from None
    except OSError as exc:
        raise ArtifactError(f"model artifact {path} cannot be read ({exc.strerror or exc.__class__.__name__}); "
                            "check the file's permissions or pass another with --model") from None
    if not text.strip():
        raise ArtifactError(f"model artifact {path} is empty; rebuild it with 'bench identify'")
    try:
        content = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ArtifactError(f"model artifact {path} is not valid JSON (truncated or corrupted at line {exc.lineno}); "
                            "rebuild it with 'bench identify'") from None
    except (ValueError, RecursionError):  # an integer too long to convert, nesting too deep for the parser
        raise ArtifactError(f"model artifact {path} is not an artifact's JSON (absurd numbers or nesting); "
                            "rebuild it with 'bench identify'") from None
    try:
        return verify(content, path)
    except ArtifactError as exc:
        raise ArtifactError(f"model artifact {path}: {exc}") from None
