"""The study's table: OUT/robustness.sqlite, one row per case (what it is, its status, attempts and its result as
JSON), written in one transaction when the case ends (the campaign's `SqliteTable`: an interrupted study leaves
every row whole, `--resume` skips the cases done, and a done row is never replaced: a case the cluster ran twice
is recorded once, `bench.campaign.once`)."""

from __future__ import annotations

import json
from typing import Any

from bench.campaign.store import Commit, SqliteTable

TABLE_NAME = "robustness.sqlite"
COLUMNS = (("case_id", "TEXT PRIMARY KEY"), ("position", "INTEGER"), ("model", "TEXT"), ("model_sha256", "TEXT"),
           ("data", "TEXT"), ("data_sha256", "TEXT"), ("kind", "TEXT"), ("subject", "TEXT"), ("magnitude", "REAL"),
           ("unit", "TEXT"), ("tau_s", "REAL"), ("lanes", "INTEGER"), ("status", "TEXT"), ("outcome", "TEXT"),
           ("error", "TEXT"), ("attempts", "INTEGER"), ("result", "TEXT"), ("worker", "TEXT"), ("wall_s", "REAL"),
           ("started_at", "TEXT"), ("finished_at", "TEXT"))


class CaseStore(SqliteTable):
    WHAT = "robustness study"
    HINT = "give the output directory of a study (bench robustness --out DIR)"
    VERSION = 1
    MAIN = "cases"
    KEY = "case_id"
    TABLES = {"cases": ", ".join(f"{c} {t}" for c, t in COLUMNS)}
    MAIN_COLUMNS = COLUMNS

    def rows(self) -> list[dict[str, Any]]:
        return [dict(r) for r in self._db.execute("SELECT * FROM cases ORDER BY position, case_id")]

    def row(self, case_id: str) -> dict[str, Any] | None:
        found = self._db.execute("SELECT * FROM cases WHERE case_id = ?", (case_id,)).fetchone()
        return dict(found) if found is not None else None

    def record(self, case, outcome: dict[str, Any], attempts: int) -> Commit:
        """The case's row from its outcome, committed (`SqliteTable.commit`: never over a done row)."""
        result = outcome.get("result")
        row = {"case_id": case.case_id, "position": case.index, "model": case.source.model_path,
               "model_sha256": case.source.model_sha256, "data": case.source.data_path,
               "data_sha256": case.source.data_sha256, "kind": case.kind, "subject": case.subject,
               "magnitude": case.magnitude, "unit": case.unit, "tau_s": case.tau_s, "lanes": case.lanes,
               "status": outcome["status"], "outcome": result["outcome"] if result else None,
               "error": outcome["error"], "attempts": attempts,
               "result": json.dumps(result, sort_keys=True) if result is not None else None,
               "worker": outcome.get("worker"), "wall_s": outcome.get("wall_s"),
               "started_at": outcome.get("started_at"), "finished_at": outcome.get("finished_at")}
        return self.commit(row)
