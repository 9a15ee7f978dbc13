"""Dataset files: the schema, the writer (CSV + JSON sidecar), the loader and the column mapping.

Generating the bench's own datasets (the virtual motor's runs) is `bench.drive.generate`'s; this module only
knows the file format.

Schema (one header line, comma-separated, one row per sample, no blank lines in between):

| column | unit | resolution in generated files | accepted range |
|---|---|---|---|
| time_s | s | 0.2 s steps from 0 | finite, strictly increasing, regular |
| torque_Nm | Nm | 0.1 | -2000 .. 2000 |
| speed_rpm | rpm | 1 | -1000 .. 15000 |
| coolant_C | °C | 0.1 | -40 .. 150 |
| ambient_C | °C | 0.1 | -40 .. 150 |
| winding_C | °C | 0.1 | -40 .. 250 |
| rotor_surface_C | °C | 0.1 | -40 .. 250 |
| pm_C | °C | 0.1 | -40 .. 250 |
| i_d_A, i_q_A (optional) | A | 0.1 | -3000 .. 3000 |
| u_d_V, u_q_V (optional) | V | 0.1 | -2000 .. 2000 |
| yoke_C, tooth_C (optional) | °C | 0.1 | -40 .. 250 |
| ntc_C (optional) | °C | 0.1 | -40 .. 250 |

The optional columns are read when present: the d/q currents feed a motor whose loss model is "electrical"
(bench.motor), the voltages are kept for the user's own use, measured yoke and tooth temperatures are
evaluated like winding and PM, and a stator NTC (ntc_C) is a sensor an observer may correct the model with
(`bench observer --measure ntc_C`).

pm_C is the PM reference, rotor_surface_C + 5 °C (paper section II-A). A user's file may carry either of the two;
the loader then derives the other with the same 5 °C offset and records that in `Dataset.metadata["derived"]`.
Other columns are ignored (listed in metadata). The ranges are those the CAN DBC can carry and a machine can
reach. The sidecar `<name>.json` beside `<name>.csv` is optional for a user's data; when present its sha256
must match the CSV.

The loader never drops, reorders or repairs a row: the first problem ends the load with one DatasetError
sentence naming the file, the column and the data row (1-based, the header is line 1, so data row n is line
n + 1).

A user's file is read through a ColumnMapping (in code, or from a mapping file: bench.drive.mapping): other column
names and units, columns derived as the mean of several sensors, a file without a time column (time = row index ×
the given sample period), and ';' or tab separators with decimal commas. A header that does not parse (one field
holding ';' or tabs) is reported with the separator and decimal mark the file seems to use. The d/q currents come
as a pair or not at all.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.errors import BenchError
from bench.fileio import write_bytes_atomically
from dbc.contract import DRIVE_SAMPLE_PERIOD_S

SCHEMA_VERSION = 1
SAMPLE_PERIOD_S = DRIVE_SAMPLE_PERIOD_S   # the data rate the host replays rows at
PM_OFFSET_K = 5.0
# Relative tolerance on each time step; generated files are exact, logged data may jitter a little.
TIME_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Column:
    name: str
    unit: str
    quantity: str
    resolution: float
    low: float
    high: float
    description: str
    fmt: str


SCHEMA: tuple[Column, ...] = (
    Column("time_s", "s", "time", 0.2, -math.inf, math.inf, "time since the start of the test", "%.1f"),
    Column("torque_Nm", "Nm", "torque", 0.1, -2000.0, 2000.0, "motor shaft torque", "%.1f"),
    Column("speed_rpm", "rpm", "speed", 1.0, -1000.0, 15000.0, "motor speed", "%.0f"),
    Column("coolant_C", "°C", "temperature", 0.1, -40.0, 150.0, "coolant inlet temperature", "%.1f"),
    Column("ambient_C", "°C", "temperature", 0.1, -40.0, 150.0, "ambient (test cell) temperature", "%.1f"),
    Column("winding_C", "°C", "temperature", 0.1, -40.0, 250.0, "stator winding temperature", "%.1f"),
    Column("rotor_surface_C", "°C", "temperature", 0.1, -40.0, 250.0, "rotor surface temperature", "%.1f"),
    Column("pm_C", "°C", "temperature", 0.1, -40.0, 250.0, "PM reference = rotor surface + 5 °C", "%.1f"),
)
COLUMNS = tuple(c.name for c in SCHEMA)
OPTIONAL_SCHEMA: tuple[Column, ...] = (
    Column("i_d_A", "A", "current", 0.1, -3000.0, 3000.0, "d-axis stator current (amplitude-invariant)", "%.1f"),
    Column("i_q_A", "A", "current", 0.1, -3000.0, 3000.0, "q-axis stator current (amplitude-invariant)", "%.1f"),
    Column("u_d_V", "V", "voltage", 0.1, -2000.0, 2000.0, "d-axis stator voltage", "%.1f"),
    Column("u_q_V", "V", "voltage", 0.1, -2000.0, 2000.0, "q-axis stator voltage", "%.1f"),
    Column("yoke_C", "°C", "temperature", 0.1, -40.0, 250.0, "stator yoke temperature", "%.1f"),
    Column("tooth_C", "°C", "temperature", 0.1, -40.0, 250.0, "stator tooth temperature", "%.1f"),
    Column("ntc_C", "°C", "temperature", 0.1, -40.0, 250.0,
           "stator NTC temperature (a production sensor: end winding, with lag and offset; an observer's measurement)",
           "%.1f"),
)
OPTIONAL_COLUMNS = tuple(c.name for c in OPTIONAL_SCHEMA)
# the measured temperatures a model's output can be compared with, by model output index
MEASURED_NODES = {"winding": "winding_C", "pm": "pm_C", "yoke": "yoke_C", "tooth": "tooth_C"}
BY_NAME = {c.name: c for c in (*SCHEMA, *OPTIONAL_SCHEMA)}

# Source unit -> (scale, offset) so that schema value = value·scale + offset.
UNITS: dict[str, dict[str, tuple[float, float]]] = {
    "time": {"s": (1.0, 0.0), "ms": (1e-3, 0.0), "min": (60.0, 0.0)},
    "torque": {"Nm": (1.0, 0.0), "N·m": (1.0, 0.0), "kNm": (1000.0, 0.0)},
    "speed": {"rpm": (1.0, 0.0), "1/min": (1.0, 0.0), "krpm": (1000.0, 0.0), "rad/s": (60.0 / (2 * math.pi), 0.0),
              "1/s": (60.0, 0.0), "Hz": (60.0, 0.0)},
    "temperature": {"°C": (1.0, 0.0), "C": (1.0, 0.0), "degC": (1.0, 0.0), "K": (1.0, -273.15),
                    "°F": (5.0 / 9.0, -32.0 * 5.0 / 9.0), "F": (5.0 / 9.0, -32.0 * 5.0 / 9.0),
                    "degF": (5.0 / 9.0, -32.0 * 5.0 / 9.0)},
    "current": {"A": (1.0, 0.0), "kA": (1000.0, 0.0), "mA": (1e-3, 0.0)},
    "voltage": {"V": (1.0, 0.0), "kV": (1000.0, 0.0), "mV": (1e-3, 0.0)},
}


class DatasetError(BenchError):
    """A dataset file (or its column mapping) that the bench cannot use as it is."""


# separators and decimal marks a file may use (mapping keys "separator" and "decimal"), with their names
SEPARATORS = {",": "comma", ";": "semicolon", "\t": "tab"}
DECIMALS = {".": "'.' decimals", ",": "decimal commas"}
DEFAULT_ORIGIN = "column mapping"


def mapping_key(*parts: str) -> str:
    """A key of a mapping for a message: key 'derived.winding_C.mean_of'."""
    return "key " + repr(".".join(parts))


@dataclass(frozen=True)
class ColumnMapping:
    """How a user's file maps onto the schema.

    columns: source column name -> schema column name (unmapped names are used as they are);
    units: schema column name -> unit of the source values (see UNITS), converted on load;
    derived: schema column name -> source columns whose mean it is (each in the unit `units` gives the target);
    time_column: the source column of time_s ("time_s" by default, or whichever `columns` maps to time_s);
    None: the file has no time column, time = row index × the sample period, which must then be given;
    sample_period_s: the file's sample period, checked against the time column (None: not stated);
    separator: ',', ';' or '\t'; decimal: '.' or ',' (not ',' with a ',' separator);
    origin: how messages name the mapping ("mapping file <path>" for one read by bench.drive.mapping).
    Example: ColumnMapping({"T_mot": "torque_Nm", "n_mot": "speed_rpm"}, {"speed_rpm": "rad/s"}).
    """

    columns: Mapping[str, str] = field(default_factory=dict)
    units: Mapping[str, str] = field(default_factory=dict)
    derived: Mapping[str, Sequence[str]] = field(default_factory=dict)
    time_column: str | None = "time_s"
    sample_period_s: float | None = None
    separator: str = ","
    decimal: str = "."
    origin: str = field(default=DEFAULT_ORIGIN, compare=False)

    def __post_init__(self) -> None:
        where = self.origin
        for target, sources in self.derived.items():
            if isinstance(sources, str):
                raise DatasetError(f"{where}, {mapping_key('derived', target, 'mean_of')}: give a list of one or "
                                   "more source column names")
        object.__setattr__(self, "derived", {k: tuple(v) for k, v in self.derived.items()})
        for source, target in self.columns.items():
            if target not in BY_NAME:
                raise DatasetError(f"{where}, {mapping_key('columns', source)}: {target!r} is not a schema column "
                                   f"({', '.join(COLUMNS)}; optional {', '.join(OPTIONAL_COLUMNS)})")
        targets = list(self.columns.values())
        for target in targets:
            if targets.count(target) > 1:
                sources = ", ".join(repr(s) for s, t in self.columns.items() if t == target)
                raise DatasetError(f"{where}, key 'columns': more than one source column maps to {target!r} "
                                   f"({sources}); keep one")
        for target, unit in self.units.items():
            if target not in BY_NAME:
                raise DatasetError(f"{where}, {mapping_key('units', target)}: unit given for {target!r}, which is "
                                   "not a schema column")
            known = UNITS[BY_NAME[target].quantity]
            if unit not in known:
                raise DatasetError(f"{where}, {mapping_key('units', target)}: unit {unit!r} of {target!r} is not "
                                   f"one of {', '.join(known)}")
        for target, sources in self.derived.items():
            key = mapping_key("derived", target)
            if target not in BY_NAME or target == "time_s":
                raise DatasetError(f"{where}, {key}: {target!r} is not a schema column that can be derived "
                                   f"({', '.join(c for c in BY_NAME if c != 'time_s')})")
            if target in targets:
                source = next(s for s, t in self.columns.items() if t == target)
                raise DatasetError(f"{where}, {key}: {target!r} is also mapped from {source!r} in 'columns'; "
                                   "map it or derive it, not both")
            if not sources or not all(isinstance(s, str) and s for s in sources):
                raise DatasetError(f"{where}, {mapping_key('derived', target, 'mean_of')}: give a list of one or "
                                   "more source column names")
            for i, source in enumerate(sources):
                if source in sources[:i]:
                    raise DatasetError(f"{where}, {mapping_key('derived', target, 'mean_of')}: column {source!r} "
                                       "is listed twice; list each source column once")
        if self.time_column != "time_s":
            mapped = [s for s, t in self.columns.items() if t == "time_s"]
            if self.time_column in self.columns and not mapped:
                raise DatasetError(f"{where}, key 'time.column': {self.time_column!r} is also mapped to "
                                   f"{self.columns[self.time_column]!r} in 'columns'; keep one of the two")
            if mapped and self.time_column is None:
                raise DatasetError(f"{where}, key 'time.column': null says the file has no time column, but "
                                   f"'columns' maps {mapped[0]!r} to 'time_s'; keep one of the two")
            if mapped and mapped[0] != self.time_column:
                raise DatasetError(f"{where}, key 'time.column': {self.time_column!r} disagrees with 'columns', "
                                   f"which maps {mapped[0]!r} to 'time_s'; keep one of the two")
        period = self.sample_period_s
        if period is not None and (isinstance(period, bool) or not isinstance(period, int | float)
                                   or not math.isfinite(period) or period <= 0):
            raise DatasetError(f"{where}, key 'time.sample_period_s': {period!r} is not a positive number of "
                               "seconds")
        if self.separator not in SEPARATORS:
            raise DatasetError(f"{where}, key 'separator': {self.separator!r} is not one of "
                               f"{', '.join(repr(s) for s in SEPARATORS)}")
        if self.decimal not in DECIMALS:
            raise DatasetError(f"{where}, key 'decimal': {self.decimal!r} is not one of "
                               f"{', '.join(repr(s) for s in DECIMALS)}")
        if self.separator == self.decimal:
            raise DatasetError(f"{where}, key 'decimal': the decimal mark {self.decimal!r} cannot also be the "
                               "separator; a file with decimal commas is ';'- or tab-separated")

    @property
    def time_source(self) -> str | None:
        """The source column of time_s, None for a file without one."""
        if self.time_column is None:
            return None
        mapped = [s for s, t in self.columns.items() if t == "time_s"]
        return mapped[0] if mapped else self.time_column


@dataclass(frozen=True, eq=False)
class Dataset:
    """One loaded dataset: read-only float64 arrays per schema column, plus what is known about it."""

    path: Path
    time_s: np.ndarray
    torque_Nm: np.ndarray
    speed_rpm: np.ndarray
    coolant_C: np.ndarray
    ambient_C: np.ndarray
    winding_C: np.ndarray
    rotor_surface_C: np.ndarray
    pm_C: np.ndarray
    sample_period_s: float
    coolant_setpoint_C: float | None   # from the sidecar; None for a file without one
    sha256: str
    metadata: dict
    i_d_A: np.ndarray | None = None
    i_q_A: np.ndarray | None = None
    u_d_V: np.ndarray | None = None
    u_q_V: np.ndarray | None = None
    yoke_C: np.ndarray | None = None
    tooth_C: np.ndarray | None = None
    ntc_C: np.ndarray | None = None

    def has(self, name: str) -> bool:
        """Whether the file had (or the loader derived) this column; the required ones always."""
        return name in BY_NAME and getattr(self, name) is not None

    @property
    def has_currents(self) -> bool:
        return self.has("i_d_A") and self.has("i_q_A")

    @property
    def rows(self) -> int:
        return len(self.time_s)

    @property
    def name(self) -> str:
        return self.path.stem

    def column(self, name: str) -> np.ndarray:
        if name not in BY_NAME:
            raise KeyError(f"unknown column {name!r}; the schema has {', '.join(BY_NAME)}")
        value = getattr(self, name)
        if value is None:
            raise KeyError(f"{self.path} has no column {name!r}")
        return value

    def drive_inputs(self) -> np.ndarray:
        """(rows, 4): torque_Nm, speed_rpm, coolant_C, ambient_C, the estimator's measured inputs."""
        return np.column_stack([self.torque_Nm, self.speed_rpm, self.coolant_C, self.ambient_C])

    def rows_sha256(self, rows: int | None = None) -> str:
        """The identity of the first `rows` data rows (all by default): hex sha256 over each present column's name
        and its float64 values as loaded, so the same data gives the same identity whatever the file's name,
        separator, units or mapping (a summary carries it; a baseline of other data is refused)."""
        digest = hashlib.sha256()
        for name in BY_NAME:
            values = getattr(self, name)
            if values is not None:
                digest.update(name.encode())
                digest.update(np.ascontiguousarray(values[:rows], dtype="<f8").tobytes())
        return digest.hexdigest()


def dataset_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def sidecar_path(csv_path: Path) -> Path:
    return Path(csv_path).with_suffix(".json")


def dataset_filename(setpoint_C: float) -> str:
    return f"cycle_coolant{setpoint_C:g}.csv"


def default_dataset_dir() -> Path:
    """out/data in the current directory."""
    return Path.cwd() / "out" / "data"


# ---------------------------------------------------------------- writing


def csv_bytes(columns: Mapping[str, np.ndarray]) -> bytes:
    """The CSV text of a dataset in schema order (then the optional columns it has), '\\n' line ends, values at
    their resolution."""
    names = [*COLUMNS, *(c for c in OPTIONAL_COLUMNS if c in columns)]
    fmt = ",".join(BY_NAME[c].fmt for c in names)
    data = np.column_stack([np.asarray(columns[c], dtype=float) for c in names])
    out = io.StringIO()
    out.write(",".join(names) + "\n")
    np.savetxt(out, data, fmt=fmt, delimiter=",", newline="\n")
    return out.getvalue().encode("ascii")


def write_dataset(csv_path: Path, columns: Mapping[str, np.ndarray], sidecar: dict) -> str:
    """Write the CSV, then its sidecar with the CSV's sha256 (each atomically); returns the sha256."""
    payload = csv_bytes(columns)
    sha = hashlib.sha256(payload).hexdigest()
    write_bytes_atomically(csv_path, payload)
    meta = {**sidecar, "schema_version": SCHEMA_VERSION, "rows": len(columns["time_s"]), "sha256": sha,
            "columns": [{"name": c.name, "unit": c.unit, "resolution": c.resolution, "description": c.description}
                        for c in (*SCHEMA, *OPTIONAL_SCHEMA) if c.name in columns]}
    text = json.dumps(meta, indent=2, sort_keys=True, ensure_ascii=False) + "\n"
    write_bytes_atomically(sidecar_path(csv_path), text.encode("utf-8"))
    return sha


# ---------------------------------------------------------------- loading


def load_dataset(path: Path, mapping: ColumnMapping | None = None,
                 sample_period_s: float | None = SAMPLE_PERIOD_S) -> Dataset:
    """Read and check a dataset CSV (and its sidecar, if any); raises DatasetError on the first problem.

    sample_period_s: the period the file must have (the bench's 5 Hz by default); None accepts any
    regular period (the mapping's, if it gives one). For a file without a time column it is the file's period
    (else the mapping's; one of the two is needed).
    """
    path = Path(path)
    mapping = mapping or ColumnMapping()
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DatasetError(f"{path} cannot be read ({exc.strerror or exc}); check the path") from None
    sha = hashlib.sha256(raw).hexdigest()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DatasetError(f"{path} is not UTF-8 text; save it as a UTF-8 CSV") from None
    header, rows = _split(path, text, mapping)
    sources = _locate_columns(path, header, mapping)
    derived_sources = _locate_derived(path, header, mapping)
    values = {name: _parse_column(path, name, src, idx, rows, mapping) for name, (src, idx) in sources.items()}
    derived = []
    for name, parts in derived_sources.items():
        columns = []
        for src, idx in parts:
            column = _parse_column(path, name, src, idx, rows, mapping)
            _check_range(path, BY_NAME[name], src, column)
            columns.append(column)
        values[name] = np.mean(columns, axis=0)
        sources[name] = (_mean_label(src for src, _ in parts), -1)
        derived.append(f"{name} = {sources[name][0]}")
    derived += _derive_pm(values)
    _check_pairs(path, sources)
    if len(rows) < 2:
        raise DatasetError(f"{path} has {len(rows)} data row(s); a dataset needs at least two")
    if "time_s" in sources:
        time_source = sources["time_s"][0]
        stated = mapping.sample_period_s
        if sample_period_s is not None:
            period = _check_time(path, time_source, values["time_s"], sample_period_s)
            if stated is not None:  # the mapping's period must be the file's too
                _check_time(path, time_source, values["time_s"], stated, mapping.origin)
        else:
            period = _check_time(path, time_source, values["time_s"], stated, mapping.origin)
    else:
        period = _given_period(path, mapping, sample_period_s)
        values["time_s"] = np.arange(len(rows)) * period
        derived.append(f"time_s = row index × {period:g} s")
    for name, column in BY_NAME.items():
        if name in sources and name not in derived_sources:  # a mean is in range when its sources are
            _check_range(path, column, sources[name][0], values[name])
    meta = _read_sidecar(path, sha)
    used = {idx for _, idx in sources.values()} | {idx for parts in derived_sources.values() for _, idx in parts}
    meta.update({
        "derived": derived,
        "source_columns": {name: src for name, (src, _) in sources.items()},
        "ignored_columns": [h for i, h in enumerate(header) if i not in used],
        "units_converted": dict(mapping.units),
    })
    if mapping.origin != DEFAULT_ORIGIN:
        meta["mapping"] = mapping.origin
    setpoint = meta.get("coolant_setpoint_C")
    for array in values.values():
        array.setflags(write=False)
    return Dataset(path=path, **values, sample_period_s=period,
                   coolant_setpoint_C=None if setpoint is None else float(setpoint), sha256=sha, metadata=meta)


def _shown(text: str, limit: int = 40) -> str:
    """A field for a one-line message: repr (so control characters and line breaks stay visible), shortened."""
    shown = repr(text)
    return shown if len(shown) <= limit else shown[: limit - 4] + "…" + shown[-3:]


def _shown_header(header: list[str], limit: int = 200) -> str:
    """The header for a one-line message: plain names as they are, odd ones quoted, the whole shortened."""
    names = [h if h.isprintable() and len(h) <= 40 else _shown(h) for h in header]
    text = ", ".join(names)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _label(source: str, name: str) -> str:
    """How a message names a column: the schema name, or the source name with the schema name after it."""
    return name if source == name else f"{_shown(source)} ({name})"


def _mean_label(sources) -> str:
    return "mean(" + ", ".join(sources) + ")"


def _split(path: Path, text: str, mapping: ColumnMapping) -> tuple[list[str], list[list[str]]]:
    # newline=None: universal newlines, so CR-only and CRLF files read like LF files
    reader = csv.reader(io.StringIO(text, newline=None), delimiter=mapping.separator, strict=True)
    try:
        lines = list(reader)
    except csv.Error as exc:
        raise DatasetError(f"{path}, line {reader.line_num} cannot be read as CSV ({exc}: an unclosed quote or a "
                           f"damaged file?); save it as a plain {SEPARATORS[mapping.separator]}-separated "
                           "file") from None
    while lines and not lines[-1]:
        lines.pop()  # trailing empty lines are the end of the file, not rows
    if not lines:
        raise DatasetError(f"{path} is empty; it needs a header line ({','.join(COLUMNS)}) and data rows")
    header = [h.strip() for h in lines[0]]
    if len(header) == 1:
        _sniff(path, text, header[0], mapping)
    for i, name in enumerate(header):
        if name in header[:i]:
            raise DatasetError(f"{path}, line 1: column {_shown(name)} appears twice in the header; rename or "
                               "remove one of them")
    rows = lines[1:]
    for n, row in enumerate(rows, start=1):
        if len(row) != len(header):
            what = "is empty" if not row else f"has {len(row)} fields, the header has {len(header)}"
            raise DatasetError(f"{path}, data row {n} (line {n + 1}) {what}; fix or remove that line")
    return header, rows


DECIMAL_COMMA = re.compile(r"\s*[-+]?\d*,\d+(?:[eE][-+]?\d+)?\s*")
DECIMAL_POINT = re.compile(r"\s*[-+]?\d*\.\d+(?:[eE][-+]?\d+)?\s*")


def _sniff(path: Path, text: str, field: str, mapping: ColumnMapping) -> None:
    """A one-field header that another separator splits: say which separator and decimal mark the file seems to
    use (DatasetError); otherwise return and let the missing columns be reported."""
    found = max((s for s in SEPARATORS if s != mapping.separator), key=field.count)
    if field.count(found) == 0:
        return
    decimal = "."
    if found != ",":
        try:
            sample = list(itertools.islice(csv.reader(io.StringIO(text, newline=None), delimiter=found), 1, 21))
        except csv.Error:
            sample = []
        cells = [c for row in sample for c in row]
        if any(DECIMAL_COMMA.fullmatch(c) for c in cells) and not any(DECIMAL_POINT.fullmatch(c) for c in cells):
            decimal = ","
    looks = f"{SEPARATORS[found]}-separated with {DECIMALS[decimal]}"
    wanted = {"separator": found, "decimal": decimal}
    keys = ", ".join(f"{json.dumps(k)}: {json.dumps(v)}" for k, v in wanted.items() if v != getattr(mapping, k))
    if mapping.origin != DEFAULT_ORIGIN:
        fix = f"set {keys} in {mapping.origin} (or save the file comma-separated with '.' decimals)"
    elif (mapping.separator, mapping.decimal) == (",", "."):
        fix = f"save it comma-separated with '.' decimals (or pass --mapping with {keys})"
    else:
        fix = f"read it with {keys} in the column mapping"
    raise DatasetError(f"{path}: the header is one field {_shown(field, 60)} — the file looks {looks}; {fix}")


def _locate_columns(path: Path, header: list[str], mapping: ColumnMapping) -> dict[str, tuple[str, int]]:
    """schema name -> (source name, index), applying the mapping; derived columns are _locate_derived's."""
    for source in mapping.columns:
        if source not in header:
            named = ("the column mapping" if mapping.origin == DEFAULT_ORIGIN
                     else f"{mapping.origin} ({mapping_key('columns', source)})")
            raise DatasetError(f"{path}: column {_shown(source)} named in {named} is not in the header "
                               f"({_shown_header(header)}); fix the mapping or the header")
    columns = dict(mapping.columns)
    time_source = mapping.time_source
    if time_source is not None and time_source != "time_s":
        if time_source not in header:
            raise DatasetError(f"{path}: time column {_shown(time_source)} named in {mapping.origin} (key "
                               f"'time.column') is not in the header ({_shown_header(header)}); fix the mapping "
                               "or the header")
        columns[time_source] = "time_s"
    derived_from = {s for parts in mapping.derived.values() for s in parts}
    found: dict[str, tuple[str, int]] = {}
    for i, name in enumerate(header):
        target = columns.get(name, name if name not in columns.values() else None)
        if target in mapping.derived:
            if name in derived_from:
                continue  # a source of a derived column that happens to carry a schema name
            raise DatasetError(f"{path}: the file has a column {_shown(name)} and {mapping.origin} derives "
                               f"{target!r} ({mapping_key('derived', target)}); rename the column or drop the "
                               "derived entry")
        if target == "time_s" and time_source is None:
            raise DatasetError(f"{path}: the file has a time column {_shown(name)}, but {mapping.origin} says it "
                               "has none (key 'time.column' is null); drop that key or map the column")
        if target in BY_NAME:
            found[target] = (name, i)
    required = [c for c in COLUMNS if c not in ("rotor_surface_C", "pm_C") and c not in mapping.derived]
    for name in required:
        if name == "time_s" and time_source is None:
            continue
        if name not in found:
            hint = "rename it or map it with a column mapping"
            if name == "time_s":
                hint += ("; a file without a time column needs \"time\": {\"column\": null} and a sample period "
                         "in the mapping")
            raise DatasetError(f"{path}: column {name!r} is missing (header: {_shown_header(header)}); {hint}")
    if not {"pm_C", "rotor_surface_C"} & (found.keys() | mapping.derived.keys()):
        raise DatasetError(f"{path}: column 'pm_C' (or 'rotor_surface_C') is missing (header: "
                           f"{_shown_header(header)}); rename it or map it with a column mapping")
    return found


def _locate_derived(path: Path, header: list[str], mapping: ColumnMapping) -> dict[str, list[tuple[str, int]]]:
    """derived schema name -> [(source name, index)] of the columns it is the mean of."""
    out = {}
    for target, sources in mapping.derived.items():
        for source in sources:
            if source not in header:
                raise DatasetError(f"{path}: column {_shown(source)} named in {mapping.origin} "
                                   f"({mapping_key('derived', target, 'mean_of')}) is not in the header "
                                   f"({_shown_header(header)}); fix the mapping or the header")
        out[target] = [(s, header.index(s)) for s in sources]
    return out


def _check_pairs(path: Path, sources: Mapping[str, tuple[str, int]]) -> None:
    """The d/q currents come together or not at all."""
    for one, other in (("i_d_A", "i_q_A"), ("i_q_A", "i_d_A")):
        if one in sources and other not in sources:
            raise DatasetError(f"{path}: column {_label(sources[one][0], one)} has no partner {other!r}; the d/q "
                               f"currents come as a pair, so add or map {other!r}, or rename "
                               f"{_shown(sources[one][0])} so that the bench ignores it")


def _given_period(path: Path, mapping: ColumnMapping, given: float | None) -> float:
    """The sample period of a file without a time column: given, or the mapping's; both must agree."""
    stated = mapping.sample_period_s
    if given is None and stated is None:
        raise DatasetError(f"{path} has no time column ({mapping.origin}, key 'time.column' is null) and no sample "
                           "period is given; set \"sample_period_s\" under \"time\" in the mapping or pass "
                           "--sample-period")
    if given is not None and stated is not None and abs(given - stated) > TIME_TOLERANCE * stated:
        raise DatasetError(f"{path} has no time column and {mapping.origin} gives the sample period {stated:g} s "
                           f"(key 'time.sample_period_s'), but {given:g} s is needed; resample the data or fix "
                           "the mapping")
    return float(given if given is not None else stated)


def _parse_column(path, name, source, index, rows, mapping: ColumnMapping) -> np.ndarray:
    label = _label(source, name)
    comma = mapping.decimal == ","
    values = np.empty(len(rows))
    for n, row in enumerate(rows):
        cell = row[index]
        try:
            if comma:
                if "." in cell:
                    raise ValueError
                cell = cell.replace(",", ".")
            values[n] = float(cell)
        except ValueError:
            shown = _shown(row[index]) if row[index].strip() else "empty"
            hint = ""
            if comma and DECIMAL_POINT.fullmatch(row[index]):
                hint = f" with the decimal mark ',' ({mapping.origin}, key 'decimal')"
            elif not comma and DECIMAL_COMMA.fullmatch(row[index]):
                hint = " (a decimal comma? the mapping's \"decimal\" is '.')"
            raise DatasetError(f"{path}, column {label}, data row {n + 1} (line {n + 2}): value {shown} "
                               f"is not a number{hint}; fix or remove that row") from None
    bad = ~np.isfinite(values)
    if bad.any():
        n = int(np.argmax(bad)) + 1
        kind = "NaN" if np.isnan(values[n - 1]) else "infinite"
        raise DatasetError(f"{path}, column {label}, data row {n} (line {n + 1}): value is {kind}; "
                           "the bench never fills gaps, so fix the source data")
    unit = mapping.units.get(name)
    if unit is not None:
        scale, offset = UNITS[BY_NAME[name].quantity][unit]
        values = values * scale + offset
    return values


def _derive_pm(values: dict[str, np.ndarray]) -> list[str]:
    """Fill the one of pm_C / rotor_surface_C a file lacks from the other (PM reference = surface + 5 °C)."""
    if "pm_C" not in values:
        values["pm_C"] = values["rotor_surface_C"] + PM_OFFSET_K
        return ["pm_C = rotor_surface_C + 5"]
    if "rotor_surface_C" not in values:
        values["rotor_surface_C"] = values["pm_C"] - PM_OFFSET_K
        return ["rotor_surface_C = pm_C - 5"]
    return []


def _check_time(path: Path, source: str, t: np.ndarray, expected: float | None, stated_by: str | None = None
                ) -> float:
    """The period of time column `t` (`expected`, or the median step), checked to be increasing and regular;
    stated_by: the mapping `expected` comes from, for the message."""
    label = _label(source, "time_s")
    steps = np.diff(t)
    bad = steps <= 0
    if bad.any():
        n = int(np.argmax(bad)) + 2
        raise DatasetError(f"{path}, column {label}, data row {n} (line {n + 1}): time {t[n - 1]:g} s does not "
                           f"increase after {t[n - 2]:g} s; rows must be in time order without repeats")
    period = float(np.median(steps))
    if expected is not None and abs(period - expected) > TIME_TOLERANCE * expected:
        if stated_by is not None:
            raise DatasetError(f"{path}, column {label}: the sample period is {period:g} s, {stated_by} says "
                               f"{expected:g} s (key 'time.sample_period_s'); fix the mapping or the data")
        raise DatasetError(f"{path}, column {label}: the sample period is {period:g} s ({1 / period:g} Hz), "
                           f"the bench needs {expected:g} s ({1 / expected:g} Hz); resample the data first")
    period = expected if expected is not None else period
    off = np.abs(steps - period) > TIME_TOLERANCE * period
    if off.any():
        n = int(np.argmax(off)) + 2
        raise DatasetError(f"{path}, column {label}, data row {n} (line {n + 1}): irregular time step "
                           f"{steps[n - 2]:g} s (from {t[n - 2]:g} s to {t[n - 1]:g} s), the sample period "
                           f"is {period:g} s; the data need a gap-free regular time base")
    return period


def _check_range(path: Path, column: Column, source: str, values: np.ndarray) -> None:
    bad = (values < column.low) | (values > column.high)
    if bad.any():
        n = int(np.argmax(bad)) + 1
        label = column.name if source == column.name else f"{_shown(source)} ({column.name})"
        raise DatasetError(f"{path}, column {label}, data row {n} (line {n + 1}): value {values[n - 1]:g} "
                           f"{column.unit} is outside the physical range {column.low:g} .. {column.high:g} "
                           f"{column.unit}; check the column's unit and mapping")


def _read_sidecar(path: Path, sha: str) -> dict:
    side = sidecar_path(path)
    if not side.exists():
        return {"sidecar": None}
    try:
        meta = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{side} is not valid JSON ({exc}); regenerate it or delete it") from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{side} must hold a JSON object; regenerate it or delete it")
    if meta.get("schema_version") != SCHEMA_VERSION:
        raise DatasetError(f"{side} has schema version {meta.get('schema_version')!r}, this bench reads "
                           f"version {SCHEMA_VERSION}; regenerate the dataset with 'bench data'")
    if meta.get("sha256") not in (None, sha):
        raise DatasetError(f"{path} does not match the sha256 in its sidecar {side.name} (the CSV was changed "
                           "after it was written); regenerate it with 'bench data' or delete the sidecar")
    return {**meta, "sidecar": str(side)}
