"""The campaign's table: OUT/campaign.sqlite, one row per run (its options, its JSON summary flattened and whole,
status, attempts, log and its sha256) and one row per run and fault kind (injected, detected).

The figures come from the run's summary, so they are over the rows the bench's rule keeps
(`bench.analysis.rowfilter`); `rows_kept`, `rows_excluded` and `rows_excluded_by_reason` stand beside them.

A run's rows are written in one transaction when the run ends, so an interrupted campaign leaves a table whose
every row is whole; only the driver writes (the workers return their results to it), and a done row is never
replaced: the first attempt committed wins (`SqliteTable.commit`, `bench.campaign.once`).
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.analysis.results import RunSummary
from bench.errors import BenchError

TABLE_NAME = "campaign.sqlite"
SCHEMA_VERSION = 2      # 2: rows_kept, rows_excluded, rows_excluded_by_reason (issue 23)
DONE = "done"                         # the bench ran and gave its verdict, whatever it is
STATUSES = (DONE, "failed", "timeout", "lost-worker")

# (column, SQL type); the options first (every run option, so a query needs no JSON), then the results.
OPTION_COLUMNS = (("model", "TEXT"), ("engine", "TEXT"), ("data", "TEXT"), ("mapping", "TEXT"),
                  ("sample_period", "TEXT"), ("seed", "INTEGER"), ("mode", "TEXT"), ("speed", "REAL"),
                  ("rows", "INTEGER"), ("reply_timeout", "REAL"), ("faults", "TEXT"), ("fault_seed", "INTEGER"),
                  ("tolerate_faults", "INTEGER"), ("tolerate_gaps", "INTEGER"), ("report", "INTEGER"))
RESULT_COLUMNS = (
    ("status", "TEXT"), ("verdict", "TEXT"), ("clean", "INTEGER"), ("exit_code", "INTEGER"), ("error", "TEXT"),
    ("problems", "TEXT"), ("attempts", "INTEGER"),
    ("model_kind", "TEXT"), ("model_id", "TEXT"), ("engine_used", "TEXT"),
    ("rmse_winding_C", "REAL"), ("rmse_pm_C", "REAL"), ("max_can_minus_float32_C", "REAL"),
    # the rows the figures are over, and those a check flagged as not the target's own answer (by reason, JSON)
    ("rows_kept", "INTEGER"), ("rows_excluded", "INTEGER"), ("rows_excluded_by_reason", "TEXT"),
    ("faults_injected", "INTEGER"), ("faults_detected", "INTEGER"), ("faults_undetected", "INTEGER"),
    ("retransmitted_rows", "INTEGER"), ("gaps", "INTEGER"),
    ("est_c28x_cycles", "INTEGER"), ("m4_cycles_p50", "INTEGER"), ("m4_cycles_max", "INTEGER"),
    ("step_time_us_p50", "REAL"), ("throughput_rows_per_s", "REAL"),
    ("rows_sent", "INTEGER"), ("replies", "INTEGER"), ("missing", "INTEGER"),
    ("wall_s", "REAL"), ("bench_elapsed_s", "REAL"), ("bus_port", "INTEGER"), ("worker", "TEXT"),
    ("log_path", "TEXT"), ("log_sha256", "TEXT"), ("report_path", "TEXT"), ("run_dir", "TEXT"),
    ("started_at", "TEXT"), ("finished_at", "TEXT"), ("summary", "TEXT"))
COLUMNS = (("run_id", "TEXT PRIMARY KEY"), ("position", "INTEGER"), ("axes", "TEXT"), ("options", "TEXT"),
           *OPTION_COLUMNS, *RESULT_COLUMNS)


def holds_another(meta: dict[str, str], identity: dict[str, Any]) -> bool:
    """Whether a table's meta (`SqliteTable.meta`) holds another campaign or study than `identity` ({meta key:
    value}, compared as JSON; a key the table lacks reads as {}): a resume into it would mix both in one table and
    report and replace the stored spec. A table without any of the keys (a new one) holds none."""
    if not any(key in meta for key in identity):
        return False
    return any(json.loads(meta.get(key, "{}")) != json.loads(json.dumps(value)) for key, value in identity.items())


class StoreError(BenchError):
    """A table that is not a campaign's, or cannot be read or written."""


def flatten(summary: RunSummary | dict | None) -> tuple[dict[str, Any], list[tuple[str, int, int | None]]]:
    """The columns a `bench run --json` summary gives (a `RunSummary`, or its JSON), and its (fault kind,
    injected, detected) rows. ResultsError (one sentence) for JSON of another schema version."""
    if not summary:
        return {}, []
    s = summary if isinstance(summary, RunSummary) else RunSummary.from_json(summary)
    m = s.metrics
    faults, m4 = s.faults, m.timing.m4_cycles
    row = {
        "clean": bool(s.clean),
        "problems": json.dumps(s.problems),
        "model_kind": m.model.kind,
        "model_id": m.model.id,
        "engine_used": s.engine,
        "rmse_winding_C": m.accuracy.rmse_C.winding,
        "rmse_pm_C": m.accuracy.rmse_C.magnet,
        "max_can_minus_float32_C": m.agreement.max_abs_can_minus_float32_C.worst(),
        "rows_kept": m.figure_rows.kept,
        "rows_excluded": m.figure_rows.excluded_total,
        "rows_excluded_by_reason": json.dumps(m.figure_rows.excluded, sort_keys=True),
        "faults_injected": faults.injected_total if faults else 0,
        "faults_detected": faults.detected_total if faults else 0,
        "faults_undetected": faults.undetected if faults else 0,
        "retransmitted_rows": faults.retransmitted_rows if faults else 0,
        "gaps": len(faults.gaps) if faults else 0,
        "est_c28x_cycles": m.timing.est_cycles,
        "m4_cycles_p50": m4.p50 if m4 else None,
        "m4_cycles_max": m4.max if m4 else None,
        "step_time_us_p50": m.timing.step_time_us.p50,
        "throughput_rows_per_s": m.throughput.throughput_steps_per_s,
        "rows_sent": m.counts.steps_sent,
        "replies": m.counts.replies,
        "missing": m.counts.missing,
        "bench_elapsed_s": round(s.elapsed_s, 2),
        "bus_port": s.bus.port,
        "log_path": m.integrity.log,
        "report_path": m.report,
        "summary": json.dumps(s.to_json(), sort_keys=True),
    }
    kinds = [(kind, int(n), faults.detected.get(kind)) for kind, n in faults.injected.items()] if faults else []
    return row, kinds


def summary_of(row: dict[str, Any]) -> RunSummary | None:
    """The run's `RunSummary` from its table row (None: the run gave none)."""
    return RunSummary.from_json(json.loads(row["summary"])) if row.get("summary") else None


@dataclass(frozen=True)
class Commit:
    """What `SqliteTable.commit` did: `applied` (the row went in) and the row it found for the id (None: none)."""

    applied: bool
    previous: dict[str, Any] | None


class SqliteTable:
    """A results table in one SQLite file: a meta table (key, value) and the subclass's tables (`TABLES`: name ->
    columns), created when new and only checked when it exists (never altered to fit). `WHAT` names it in
    messages ("campaign"), `MAIN` is the table whose columns are checked, `HINT` how to make one. `bench campaign`
    (runs) and `bench robustness` (cases) each have one."""

    WHAT: str = "campaign"
    HINT: str = "give the output directory of a campaign (bench campaign run --out DIR)"
    VERSION: int = SCHEMA_VERSION
    MAIN: str = "runs"
    KEY: str = "run_id"             # the main table's primary key
    TABLES: dict[str, str] = {}     # table -> "column type, ..." as CREATE TABLE takes it
    MAIN_COLUMNS: tuple[tuple[str, str], ...] = ()

    def __init__(self, path: Path, *, create: bool = False):
        self.path = Path(path)
        what = self.WHAT
        if not create and not self.path.is_file():
            raise StoreError(f"{self.path} does not exist; {self.HINT}")
        existed = self.path.exists()
        if create:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._db = sqlite3.connect(self.path, timeout=30)
            self._db.row_factory = sqlite3.Row
            if not existed:      # a new table; an existing file is only checked, never altered to fit
                with self._db:
                    self._db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
                    for name, columns in self.TABLES.items():
                        self._db.execute(f"CREATE TABLE {name} ({columns})")
                    self._db.execute("INSERT INTO meta VALUES ('schema_version', ?)", (str(self.VERSION),))
            if existed:   # a damaged page reads as a traceback later, and a resume would write onto it first
                damage = self._damage()
                if damage:
                    self._db.close()
                    raise StoreError(f"{self.path} is damaged (SQLite finds: {damage}); its files are "
                                     f"still there, but the {what} cannot be resumed or reported from it: run the "
                                     f"{what} again into another --out")
            tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            if not {"meta", *self.TABLES} <= tables:
                self._db.close()
                names = ", ".join(["meta", *self.TABLES][:-1]) + f" and {[*self.TABLES][-1]}"
                raise StoreError(f"{self.path} is not a {what} table (it lacks the tables {names}); give a "
                                 f"{what}'s directory")
            version = self.meta().get("schema_version")
            present = {r["name"] for r in self._db.execute(f"PRAGMA table_info({self.MAIN})")}
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path} is not a {what} table ({exc}); give a {what}'s directory") from None
        if version != str(self.VERSION):
            self._db.close()
            raise StoreError(f"{self.path} has table schema {version}, this bench reads {self.VERSION}; run the "
                             f"{what} again into another --out")
        missing = [c for c, _ in self.MAIN_COLUMNS if c not in present]
        if missing:
            self._db.close()
            raise StoreError(f"{self.path} is not a {what} table (its {self.MAIN} table lacks {missing[0]})")

    def _damage(self) -> str | None:
        """What SQLite's quick check finds wrong with an existing file (None: nothing; a file that is no database
        at all is left to the checks after it, which say so)."""
        try:
            found = [r[0] for r in self._db.execute("PRAGMA quick_check(3)")]
        except sqlite3.DatabaseError as exc:
            if "not a database" in str(exc):
                return None
            return str(exc)
        return None if found == ["ok"] else "; ".join(found)

    def close(self) -> None:
        self._db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def meta(self) -> dict[str, str]:
        return {r["key"]: r["value"] for r in self._db.execute("SELECT key, value FROM meta")}

    def set_meta(self, values: dict[str, str]) -> None:
        with self._db:
            self._db.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)", list(values.items()))

    def done(self) -> set[str]:
        """The ids whose row is done: what --resume skips, and what `commit` never replaces."""
        return {r[0] for r in self._db.execute(f"SELECT {self.KEY} FROM {self.MAIN} WHERE status = ?", (DONE,))}

    def commit(self, row: dict[str, Any], children: Iterable[tuple] = ()) -> Commit:
        """Write `row` (and its `children`, see `_write_children`) in one transaction, unless the table holds its
        id as done already: the first done row wins, a later attempt's is not written (`applied` False). A row that
        is not done (failed, timed out, lost) is replaced by the next attempt's."""
        names = [c for c, _ in self.MAIN_COLUMNS]
        unknown = set(row) - set(names)
        if unknown:
            raise ValueError(f"not columns of the {self.MAIN} table: {sorted(unknown)}")
        self._db.execute("BEGIN IMMEDIATE")       # the check and the write as one: no other writer in between
        try:
            found = self._db.execute(f"SELECT * FROM {self.MAIN} WHERE {self.KEY} = ?", (row[self.KEY],)).fetchone()
            previous = dict(found) if found is not None else None
            if previous is not None and previous["status"] == DONE:
                self._db.rollback()
                return Commit(False, previous)
            self._db.execute(f"INSERT OR REPLACE INTO {self.MAIN} ({', '.join(names)}) VALUES "
                             f"({', '.join('?' for _ in names)})", [row.get(c) for c in names])
            self._write_children(row[self.KEY], list(children))
            self._db.commit()
        except BaseException:
            self._db.rollback()
            raise
        return Commit(True, previous)

    def _write_children(self, key: str, children: list[tuple]) -> None:
        """The rows of other tables that belong to the main row `key` (inside `commit`'s transaction)."""
        if children:
            raise ValueError(f"a {self.WHAT} row has no child rows")


class Store(SqliteTable):
    """The table of one campaign directory."""

    TABLES = {"runs": ", ".join(f"{c} {t}" for c, t in COLUMNS),
              "faults": "run_id TEXT, kind TEXT, injected INTEGER, detected INTEGER, PRIMARY KEY (run_id, kind)"}
    MAIN_COLUMNS = COLUMNS

    def rows(self) -> list[dict[str, Any]]:
        """Every run's row, in the spec's order."""
        return [dict(r) for r in self._db.execute("SELECT * FROM runs ORDER BY position, run_id")]

    def faults(self) -> list[dict[str, Any]]:
        return [dict(r) for r in self._db.execute("SELECT * FROM faults ORDER BY run_id, kind")]

    def row(self, run_id: str) -> dict[str, Any] | None:
        found = self._db.execute("SELECT * FROM runs WHERE run_id = ?", (run_id,)).fetchone()
        return dict(found) if found is not None else None

    def _write_children(self, key: str, children: list[tuple]) -> None:
        """The run's fault rows (kind, injected, detected) replace those of its earlier attempt."""
        self._db.execute("DELETE FROM faults WHERE run_id = ?", (key,))
        self._db.executemany("INSERT INTO faults VALUES (?, ?, ?, ?)",
                             [(key, kind, n, d) for kind, n, d in children])


def option_columns(options: dict[str, Any]) -> dict[str, Any]:
    """A run's options as columns (booleans as 0/1, the data set point as text like a path)."""
    out = {}
    for column, _ in OPTION_COLUMNS:
        value = options.get(column)
        out[column] = int(value) if isinstance(value, bool) else (str(value) if column == "data" else value)
    return out
