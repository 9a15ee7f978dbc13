"""The motor description file (JSON or TOML): what the bench needs to know about a user's motor.

Schema (version 1; `bench motor template` prints an example, `bench motor check FILE` validates one):

    schema = "pmsm-thermal-bench.motor"      # optional; when present it must be this
    schema_version = 1
    name = "my-motor"                         # letters, digits, '-', '_', '.'
    description = "free text"                 # optional
    pole_pairs = 4                            # integer >= 1

    [limits]                                  # positive numbers
    torque_Nm = 250.0                         # peak torque
    speed_rpm = 12000.0                       # maximum speed: the speed ratio of eqs. 8 and 15 is n / speed_rpm
    current_A = 400.0                         # phase current amplitude at peak torque: I_max of eq. 8

    [losses]
    kind = "maps" | "electrical"
    copper_reference_C = 20.0                 # the temperature the copper losses are given at (eqs. 3-4)
    copper_alpha_per_K = 0.0039               # temperature coefficient of the winding resistance
    # kind = "maps": file = "losses.csv", a CSV beside the motor file (path relative to it) with one row per
    #   point of a full, evenly spaced torque × speed grid and the columns torque_Nm, speed_rpm, copper_dc_W,
    #   copper_ac_W, iron_W, magnet_W, current_A (losses at copper_reference_C; current = phase amplitude)
    # kind = "electrical": losses from the measured d/q currents and the speed (bench.motor.losses):
    #   stator_resistance_ohm (per phase at copper_reference_C), ac_factor and ac_reference_Hz,
    #   iron_hysteresis_W, iron_eddy_W, iron_reference_Hz, iron_current_factor,
    #   magnet_W, magnet_reference_Hz, magnet_no_load_share (0..1)

    [thermal_prior]                           # optional: the identification's starting point and bounds
    parameters = "table1"                     # or a table of all 22 LPTN parameters (bench.thermal.parameters)
    bounds = [0.6, 1.6]                       # factors around the prior for capacitances and resistances

    [virtual_plant]                           # optional, virtual motors only: what 'bench data --motor' simulates
                                              # (bench.drive.virtual reads and checks it; the bench ignores it)

Every problem is one `MotorFileError` sentence naming the file, the key and what to do.
"""

from __future__ import annotations

import hashlib
import json
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.motor.check import Checker, is_number
from bench.motor.errors import MotorFileError
from bench.motor.losses import LossModel, MotorConstants
from bench.motor.losskinds import COMMON_KEYS, LAB_LOSS_KINDS
from bench.thermal.parameters import PARAMETER_SETS, LptnParameters
from target_sim.losses import reads_currents

SCHEMA = "pmsm-thermal-bench.motor"
SCHEMA_VERSION = 1
LIMIT_KEYS = ("torque_Nm", "speed_rpm", "current_A")
DEFAULT_BOUNDS = (0.6, 1.6)
TOP_KEYS = ("schema", "schema_version", "name", "description", "pole_pairs", "limits", "losses", "thermal_prior",
            "virtual_plant")


@dataclass(frozen=True)
class Limits:
    torque_Nm: float
    speed_rpm: float
    current_A: float


@dataclass(frozen=True)
class ThermalPrior:
    """Centre of the LPTN search and the factors around it for capacitances and resistances."""

    parameters: LptnParameters | None   # None for "auto": derived from the training data at identification
    source: str                     # "table1", "table1-refined", "file" or "auto"
    bounds: tuple[float, float] = DEFAULT_BOUNDS

    @property
    def automatic(self) -> bool:
        return self.source == AUTO_PRIOR

    @property
    def named(self) -> bool:
        """A built-in parameter set (PARAMETER_SETS: Table 1's out-runner), not an estimate of this motor."""
        return self.source in PARAMETER_SETS


AUTO_PRIOR = "auto"
AUTO_BOUNDS = (0.1, 10.0)     # bench.model.auto_prior.AUTO_BOUNDS: a data-derived prior is right within a few ×


def automatic_prior(bounds: tuple[float, float] | None = None) -> ThermalPrior:
    """`auto`: the starting network comes from the training data (bench.model.auto_prior)."""
    return ThermalPrior(None, AUTO_PRIOR, bounds or AUTO_BOUNDS)


@dataclass(frozen=True, eq=False)
class MotorDescription:
    name: str
    description: str
    pole_pairs: int
    limits: Limits
    loss_model: LossModel              # the float64 model of a kind of bench.motor.losskinds
    copper_reference_C: float
    copper_alpha_per_K: float
    prior: ThermalPrior | None
    path: Path | None
    sha256: str | None
    maps_sha256: str | None = None
    virtual_plant: dict | None = None

    @property
    def loss_kind(self) -> str:
        return self.loss_model.kind

    @property
    def needs_currents(self) -> bool:
        return reads_currents(self.loss_model.inputs)

    def constants(self) -> MotorConstants:
        """What the estimator needs of the motor besides its loss model."""
        return MotorConstants(self.limits.current_A, self.limits.speed_rpm, self.copper_alpha_per_K,
                              self.copper_reference_C)

    def provenance(self) -> dict[str, Any]:
        """What an artifact records of the motor it was identified for."""
        record = {"name": self.name, "file": self.path.name if self.path else None, "sha256": self.sha256,
                  "loss_model": self.loss_kind, "pole_pairs": self.pole_pairs,
                  "limits": {"torque_Nm": self.limits.torque_Nm, "speed_rpm": self.limits.speed_rpm,
                             "current_A": self.limits.current_A}}
        if self.maps_sha256:
            record["loss_maps_sha256"] = self.maps_sha256
        return record


def load_motor(path: str | Path) -> MotorDescription:
    """Read and validate a motor description (.json or .toml); raises MotorFileError on the first problem."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise MotorFileError(f"motor file {path} does not exist; pass an existing file with --motor "
                             "('bench motor template > motor.toml' writes an example)") from None
    except IsADirectoryError:
        raise MotorFileError(f"motor file {path} is a directory; pass the motor's .json or .toml file") from None
    except OSError as exc:
        raise MotorFileError(f"motor file {path} cannot be read ({exc.strerror or exc}); check the path") from None
    content = _parse(path, raw)
    return motor_from_dict(content, path, hashlib.sha256(raw).hexdigest())


def _parse(path: Path, raw: bytes) -> dict:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise MotorFileError(f"{path} is not UTF-8 text; save it as UTF-8 JSON or TOML") from None
    suffix = path.suffix.lower()
    if suffix not in (".json", ".toml"):
        raise MotorFileError(f"{path} must end in .json or .toml (the suffix says which format it is)")
    try:
        content = json.loads(text) if suffix == ".json" else tomllib.loads(text)
    except json.JSONDecodeError as exc:
        raise MotorFileError(f"{path} is not valid JSON (line {exc.lineno}: {exc.msg}); fix it or start "
                             "from 'bench motor template --format json'") from None
    except tomllib.TOMLDecodeError as exc:
        raise MotorFileError(f"{path} is not valid TOML ({exc}); fix it or start from "
                             "'bench motor template'") from None
    except (ValueError, RecursionError):
        raise MotorFileError(f"{path} cannot be parsed (absurd numbers or nesting)") from None
    if not isinstance(content, dict):
        raise MotorFileError(f"{path} must hold one object (a table of keys), not {type(content).__name__}")
    return content


def motor_from_dict(content: dict, path: Path | None = None, sha256: str | None = None) -> MotorDescription:
    where = f"motor file {path}" if path else "motor description"
    check = Checker(where)
    unknown = [k for k in content if k not in TOP_KEYS]
    if unknown:
        raise MotorFileError(f"{where}: unknown key {unknown[0]!r}; the keys are {', '.join(TOP_KEYS)}")
    if "schema" in content and content["schema"] != SCHEMA:
        raise MotorFileError(f"{where}: schema {content['schema']!r} is not {SCHEMA!r}; is this a motor file?")
    check.version(content, SCHEMA_VERSION)
    name = check.text(content, "name")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", name):
        raise MotorFileError(f"{where}: name {name!r} must be 1-64 letters, digits, '.', '-' or '_'")
    description = content.get("description", "")
    if not isinstance(description, str):
        raise MotorFileError(f"{where}: description must be text")
    pole_pairs = check.whole(content, "pole_pairs", low=1, high=100)
    limits_table = check.table(content, "limits")
    check.only(limits_table, "limits", LIMIT_KEYS)
    limits = Limits(*(check.number(limits_table, k, "limits.", positive=True) for k in LIMIT_KEYS))
    losses = check.table(content, "losses")
    kind = losses.get("kind")
    if not isinstance(kind, str) or kind not in LAB_LOSS_KINDS:
        raise MotorFileError(f"{where}: losses.kind must be one of {', '.join(LAB_LOSS_KINDS.names())}, "
                             f"not {kind!r}")
    reference = check.number(losses, "losses.copper_reference_C", low=-50.0, high=250.0)
    alpha = check.number(losses, "losses.copper_alpha_per_K", low=0.0, high=0.02)
    loss_kind = LAB_LOSS_KINDS[kind]
    check.only(losses, "losses", (*COMMON_KEYS, *loss_kind.keys))
    loss_model, maps_sha = loss_kind.from_motor_file(check, losses, motor_path=path, pole_pairs=pole_pairs,
                                                     current_max_A=limits.current_A)
    prior = _prior(content.get("thermal_prior"), where)
    plant = content.get("virtual_plant")
    if plant is not None and not isinstance(plant, dict):
        raise MotorFileError(f"{where}: virtual_plant must be a table")
    return MotorDescription(name, description, pole_pairs, limits, loss_model, reference, alpha, prior, path,
                            sha256, maps_sha, plant)


def load_prior(path: str | Path) -> ThermalPrior:
    """A prior file (.json or .toml): the thermal_prior table of a motor file on its own."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MotorFileError(f"prior file {path} cannot be read ({exc.strerror or exc}); pass an existing .json or "
                             ".toml file with --prior") from None
    content = _parse(path, raw)
    prior = _prior(content, f"prior file {path}")
    if "parameters" not in content:
        raise MotorFileError(f"prior file {path} has no 'parameters' (a parameter set name or all 22 values)")
    return prior


def _prior(table: Any, where: str) -> ThermalPrior | None:
    if table is None:
        return None
    if not isinstance(table, dict):
        raise MotorFileError(f"{where}: thermal_prior must be a table with 'parameters' and optionally 'bounds'")
    check = Checker(where)
    check.only(table, "thermal_prior", ("parameters", "bounds"))
    default = AUTO_BOUNDS if table.get("parameters") == AUTO_PRIOR else DEFAULT_BOUNDS
    bounds = parse_bounds(table.get("bounds", list(default)), f"{where}: thermal_prior.bounds")
    return ThermalPrior(*prior_parameters(table.get("parameters"), f"{where}: thermal_prior.parameters"), bounds)


def prior_parameters(value: Any, where: str) -> tuple[LptnParameters | None, str]:
    """A named parameter set, "auto" or a table of all 22 parameters -> (parameters, source)."""
    if value == AUTO_PRIOR:
        return None, AUTO_PRIOR
    if isinstance(value, str):
        if value not in PARAMETER_SETS:
            raise MotorFileError(f"{where} {value!r} is not a parameter set ({', '.join(PARAMETER_SETS)}) or "
                                 f"{AUTO_PRIOR!r}; give one of those or a table of all 22 parameters")
        return PARAMETER_SETS[value], value
    if not isinstance(value, dict):
        raise MotorFileError(f"{where} must name a parameter set ({', '.join(PARAMETER_SETS)}), be {AUTO_PRIOR!r} "
                             "or be a table of the 22 LPTN parameters")
    names = LptnParameters.names()
    missing = [n for n in names if n not in value]
    extra = [k for k in value if k not in names]
    if missing or extra:
        what = f"lacks {missing[0]!r}" if missing else f"has an unknown parameter {extra[0]!r}"
        raise MotorFileError(f"{where} {what}; it needs exactly {', '.join(names)}")
    numbers = {}
    for n in names:
        v = value[n]
        if not is_number(v):
            raise MotorFileError(f"{where}.{n} must be a finite number, not {v!r}")
        numbers[n] = float(v)
    for n in names:
        if n.startswith(("C_", "R_", "a_")) and numbers[n] <= 0:
            raise MotorFileError(f"{where}.{n} must be positive (a capacitance or resistance), not {numbers[n]:g}")
    for n in ("b_wm", "b_tm", "b_ma"):
        if numbers[n] == 0:
            raise MotorFileError(f"{where}.{n} must not be zero (it divides the speed ratio in eq. 15)")
    return LptnParameters(**numbers), "file"


def parse_bounds(value: Any, where: str) -> tuple[float, float]:
    """[low, high] factors with 0 < low < 1 < high <= 100."""
    if isinstance(value, str):
        try:
            value = [float(v) for v in value.split(",")]
        except ValueError:
            value = None
    ok = isinstance(value, list | tuple) and len(value) == 2 and all(is_number(v) for v in value)
    if not ok or not 0 < value[0] < 1 < value[1] <= 100:
        raise MotorFileError(f"{where} must be two factors LOW,HIGH with 0 < LOW < 1 < HIGH <= 100 "
                             f"(e.g. 0.6,1.6), not {value!r}")
    return float(value[0]), float(value[1])


def default_motor_path() -> Path:
    """The built-in virtual 200 kW motor, shipped with the package."""
    return Path(__file__).resolve().parent.parent / "data" / "motors" / "virtual-200kw.json"


def default_motor() -> MotorDescription:
    return load_motor(default_motor_path())
