"""The CLI reference's command table (hand-written: what each command is for) has a row for every subcommand of
`bench.cli.SUBCOMMANDS` and none for a command that is not one; `docs/check_generated.py` checks it, and so does the
default test run, before the docs are built."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "docs"))

import check_generated  # noqa: E402


def test_the_command_table_has_a_row_for_every_subcommand():
    assert check_generated.cli_table_problems() == []


def test_a_missing_row_and_a_row_of_no_subcommand_are_named(tmp_path):
    text = check_generated.CLI_PAGE.read_text(encoding="utf-8")
    rows = [line for line in text.splitlines() if line.startswith("| `bench robustness`")]
    assert len(rows) == 1
    page = tmp_path / "cli.md"
    page.write_text(text.replace(rows[0] + "\n", "| `bench robustnes` | a typo |\n"), encoding="utf-8")
    assert check_generated.cli_table_problems(page) == [
        f"{page}: the command table has no row for bench robustness",
        f"{page}: the command table has a row for bench robustnes, which is no subcommand"]
