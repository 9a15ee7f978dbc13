"""Mapping files: how a user's own motor data map onto the dataset schema (`--mapping FILE`).

A mapping file is JSON (`.json`) or TOML (`.toml`), the suffix says which. Every key is optional:

```json
{
  "columns": {"motor_speed": "speed_rpm", "coolant": "coolant_C", "ambient": "ambient_C", "torque": "torque_Nm",
              "i_d": "i_d_A", "i_q": "i_q_A", "u_d": "u_d_V", "u_q": "u_q_V", "pm": "pm_C"},
  "units": {"speed_rpm": "krpm", "coolant_C": "K"},
  "derived": {"winding_C": {"mean_of": ["stator_winding_1", "stator_winding_2"]}},
  "time": {"column": null, "sample_period_s": 1.0},
  "separator": ",",
  "decimal": ".",
  "comment": "free text"
}
```

- `columns`: source column name -> schema column name (required or optional ones: time_s, torque_Nm, speed_rpm,
  coolant_C, ambient_C, winding_C, rotor_surface_C, pm_C, i_d_A, i_q_A, u_d_V, u_q_V, yoke_C, tooth_C, ntc_C). Columns
  already named as in the schema need no entry; columns that are neither mapped nor schema names are ignored
  (and listed in the dataset's metadata).
- `units`: schema column name -> unit of the source values: time s, ms, min; torque Nm, N·m, kNm; speed rpm,
  1/min, krpm, rad/s, 1/s, Hz; temperatures °C, C, degC, K, °F, F, degF; currents A, kA, mA; voltages V, kV, mV.
- `derived`: schema column name -> {"mean_of": [source columns, one or more]}: the column is the mean of those
  source columns, each in the target's unit from `units`, e.g. a winding temperature from two sensors. A derived
  column cannot also be a `columns` target, and each source is checked (numbers, range) on its own.
- `time`: `column` is the source column of time_s (default: "time_s", or whichever `columns` maps to time_s);
  null (in TOML: false) says the file has no time column: time is then row index × the sample period, which must
  be given here or with `--sample-period`. `sample_period_s` (seconds, > 0) is the file's sample period; with a
  time column it is checked against it.
- `separator`: "," (default), ";" or "\\t"; `decimal`: "." (default) or "," (not with a "," separator).
- `comment`: any text, ignored.

In TOML the same keys: `[columns]`, `[units]`, `[derived.winding_C] mean_of = [...]`, `[time] column = false`.
Every problem in the file is one DatasetError sentence naming the file and the key.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

from bench.drive.dataset import ColumnMapping, DatasetError, mapping_key

KEYS = ("columns", "units", "derived", "time", "separator", "decimal", "comment")
TIME_KEYS = ("column", "sample_period_s")
DERIVED_KEYS = ("mean_of",)


def load_mapping(path: Path) -> ColumnMapping:
    """Read a mapping file (JSON or TOML by suffix); DatasetError naming the file and the key on any problem."""
    path = Path(path)
    origin = f"mapping file {path}"
    suffix = path.suffix.lower()
    if suffix not in (".json", ".toml"):
        raise DatasetError(f"{origin}: the name must end in .json or .toml, which says its format; rename it")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DatasetError(f"{origin} cannot be read ({exc.strerror or exc}); check the path") from None
    except UnicodeDecodeError:
        raise DatasetError(f"{origin} is not UTF-8 text; save it as UTF-8") from None
    content = _parse(origin, text, suffix)
    if not isinstance(content, dict):
        raise DatasetError(f"{origin} must hold a {'JSON object' if suffix == '.json' else 'TOML table'} with the "
                           f"keys {', '.join(KEYS)}")
    _known(origin, content, KEYS, ())
    columns = _string_table(origin, content, "columns", "a schema column name")
    units = _string_table(origin, content, "units", "a unit")
    derived = _derived(origin, content.get("derived", {}))
    time_column, period = _time(origin, content.get("time", {}))
    kwargs = {}
    for key in ("separator", "decimal"):
        if key in content:
            if not isinstance(content[key], str):
                raise DatasetError(f"{origin}, {mapping_key(key)}: {_shown(content[key])} is not a string")
            kwargs[key] = content[key]
    if "comment" in content and not isinstance(content["comment"], str):
        raise DatasetError(f"{origin}, key 'comment': {_shown(content['comment'])} is not a string")
    return ColumnMapping(columns, units, derived, time_column, period, origin=origin, **kwargs)


def _parse(origin: str, text: str, suffix: str):
    if suffix == ".toml":
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise DatasetError(f"{origin} is not valid TOML ({_one_line(exc)}); fix it") from None

    def no_duplicates(pairs):
        keys = [k for k, _ in pairs]
        for i, k in enumerate(keys):
            if k in keys[:i]:
                raise DatasetError(f"{origin}: key {k!r} appears twice in one object; keep one")
        return dict(pairs)

    try:
        return json.loads(text, object_pairs_hook=no_duplicates)
    except ValueError as exc:
        raise DatasetError(f"{origin} is not valid JSON ({_one_line(exc)}); fix it") from None


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split())[:200]


def _shown(value) -> str:
    shown = json.dumps(value, ensure_ascii=False) if isinstance(value, list | dict) else repr(value)
    return shown if len(shown) <= 60 else shown[:56] + "…" + shown[-3:]


def _known(origin: str, table: dict, keys: tuple[str, ...], where: tuple[str, ...]) -> None:
    for key in table:
        if key not in keys:
            raise DatasetError(f"{origin}, {mapping_key(*where, str(key))}: unknown key; the keys "
                               f"{'here ' if where else ''}are {', '.join(keys)}")


def _table(origin: str, value, *where: str) -> dict:
    if not isinstance(value, dict):
        raise DatasetError(f"{origin}, {mapping_key(*where)}: {_shown(value)} is not an object (a table in TOML)")
    return value


def _string_table(origin: str, content: dict, key: str, what: str) -> dict[str, str]:
    table = _table(origin, content.get(key, {}), key)
    for name, value in table.items():
        if not isinstance(value, str):
            raise DatasetError(f"{origin}, {mapping_key(key, name)}: {_shown(value)} is not a string ({what})")
    return dict(table)


def _derived(origin: str, value) -> dict[str, tuple[str, ...]]:
    out = {}
    for target, entry in _table(origin, value, "derived").items():
        entry = _table(origin, entry, "derived", target)
        _known(origin, entry, DERIVED_KEYS, ("derived", target))
        sources = entry.get("mean_of")
        if not isinstance(sources, list) or not sources or not all(isinstance(s, str) and s for s in sources):
            raise DatasetError(f"{origin}, {mapping_key('derived', target, 'mean_of')}: "
                               f"{'missing' if sources is None else _shown(sources)}; give a list of one or more "
                               "source column names")
        out[target] = tuple(sources)
    return out


def _time(origin: str, value) -> tuple[str | None, float | None]:
    table = _table(origin, value, "time")
    _known(origin, table, TIME_KEYS, ("time",))
    column = table.get("column", "time_s")
    if column is None or column is False:
        column = None
    elif not isinstance(column, str) or not column:
        raise DatasetError(f"{origin}, key 'time.column': {_shown(column)} is not a column name (or null, false in "
                           "TOML, for a file without a time column)")
    period = table.get("sample_period_s")
    if period is not None and (isinstance(period, bool) or not isinstance(period, int | float)
                               or not math.isfinite(period) or period <= 0):
        raise DatasetError(f"{origin}, key 'time.sample_period_s': {_shown(period)} is not a positive number of "
                           "seconds")
    return column, None if period is None else float(period)
