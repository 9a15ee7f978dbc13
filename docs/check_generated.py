"""Check the generated documentation pages against their sources: `python docs/check_generated.py [--write] [HTML_DIR]`.

The protocol page must list every message of `dbc/thermal_bench.dbc` (name, id, and a section of its own with every
signal), the artifact page every loss model, model kind and realization of the registries and the schema version,
the command table of the CLI reference every subcommand.
Every benchmark script must have its record in `docs/results/`, and the README's headline table must be the one
the records give (`--write` rewrites it). With HTML_DIR (the output of `sphinx -b html docs HTML_DIR`), the built
pages are checked too. Exit 1 with one line per problem.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent))
sys.path.insert(0, str(DOCS / "_ext"))

import bench_docs  # noqa: E402
import results_page  # noqa: E402

README = DOCS.parent / "README.md"
CLI_PAGE = DOCS / "reference" / "cli.md"
BENCHMARKS = DOCS.parent / "tests" / "benchmarks"


def problems(html_dir: Path | None = None) -> list[str]:
    from dbc.database import load_database
    from target_sim.artifact import SCHEMA_VERSION
    from target_sim.kinds import REALIZATIONS
    from target_sim.losses import LOSS_KINDS
    from target_sim.modelkinds import MODEL_KINDS
    from target_sim.observer.measurements import MEASUREMENT_KINDS

    found = []
    protocol = bench_docs.render_protocol()
    database = load_database()
    for message in database.messages:
        if f"`0x{message.frame_id:03X}`" not in protocol or f"\n### {message.name}\n" not in protocol:
            found.append(f"protocol page: message {message.name} (0x{message.frame_id:03X}) is missing")
        for signal in message.signals:
            if f"| `{signal.name}` |" not in protocol:
                found.append(f"protocol page: signal {message.name}.{signal.name} is missing")
    schema = bench_docs.render_artifact_schema()
    if f"`schema_version`: {SCHEMA_VERSION} " not in schema:
        found.append(f"artifact page: schema version {SCHEMA_VERSION} is missing")
    for family, names in (("loss model", LOSS_KINDS.names()), ("model kind", MODEL_KINDS.names()),
                          ("realization", REALIZATIONS.names()), ("measurement kind", MEASUREMENT_KINDS.names())):
        for name in names:
            if f"`{name}`" not in schema:
                found.append(f"artifact page: {family} {name} is missing")
    found += cli_table_problems()
    found += results_problems()
    if html_dir is not None:
        page = html_dir / "reference" / "protocol.html"
        html = page.read_text(encoding="utf-8") if page.exists() else ""
        for message in database.messages:
            if f'id="msg-{message.name.lower()}"' not in html:
                found.append(f"{page}: no section for message {message.name}")
        cli = html_dir / "reference" / "cli.html"
        text = cli.read_text(encoding="utf-8") if cli.exists() else ""
        from bench.cli import SUBCOMMANDS
        for name in SUBCOMMANDS:
            if f"bench {name}" not in text:
                found.append(f"{cli}: subcommand {name} is missing")
    return found


def cli_table_problems(page: Path = CLI_PAGE) -> list[str]:
    """The command table of the CLI reference (hand-written: what each command is for, with links) must have a row
    `| `bench NAME ...` | for every subcommand of `bench.cli.SUBCOMMANDS`, and no row of a subcommand that is not."""
    from bench.cli import SUBCOMMANDS

    rows = re.findall(r"^\| `bench ([a-z][\w-]*)", page.read_text(encoding="utf-8"), flags=re.M)
    shown = page.relative_to(DOCS.parent) if page.is_relative_to(DOCS.parent) else page
    found = [f"{shown}: the command table has no row for bench {name}" for name in SUBCOMMANDS if name not in rows]
    found += [f"{shown}: the command table has a row for bench {name}, which is no subcommand"
              for name in sorted(set(rows) - set(SUBCOMMANDS))]
    return found


def results_problems() -> list[str]:
    """A benchmark script without a record, a record of no script, or a README table the records do not give."""
    found = []
    records = results_page.load_records()
    scripts = {path.stem.removeprefix("bench_") for path in BENCHMARKS.glob("bench_*.py")}
    for name in sorted(scripts - set(records)):
        found.append(f"docs/results: no record of tests/benchmarks/bench_{name}.py (run it)")
    for name in sorted(set(records) - scripts):
        found.append(f"docs/results: records of {name}, which no script in tests/benchmarks writes")
    for name in sorted(scripts - set(results_page.BENCHMARKS)):
        found.append(f"docs/_ext/results_page.py: no section for tests/benchmarks/bench_{name}.py")
    try:
        expected = results_page.splice_readme(README.read_text(encoding="utf-8"), results_page.render_headline(records))
    except ValueError as exc:
        return found + [str(exc)]
    if expected != README.read_text(encoding="utf-8"):
        found.append("README.md: the headline table is not the one docs/results gives "
                     "(python docs/check_generated.py --write)")
    return found


def write_readme() -> None:
    text = results_page.splice_readme(README.read_text(encoding="utf-8"), results_page.render_headline())
    README.write_text(text, encoding="utf-8")


def main() -> int:
    args = sys.argv[1:]
    if "--write" in args:
        args.remove("--write")
        write_readme()
    html_dir = Path(args[0]) if args else None
    found = problems(html_dir)
    for line in found:
        print(line)
    if not found:
        print("generated pages: every DBC message and signal, every kind, every subcommand, every benchmark's record "
              "present; the README's headline table up to date")
    return 1 if found else 0


if __name__ == "__main__":
    raise SystemExit(main())
