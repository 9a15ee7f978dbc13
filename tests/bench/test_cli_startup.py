"""`bench` starts without its heavy dependencies: building the parser (every subcommand's `add_subparser`, so that
`bench --help` lists them all), any subcommand's --help and a bad argument of any subcommand import no scipy, numba,
matplotlib, pandas, dask or unicorn; each command imports what it runs on when it runs. And the Python engine's
target (`python -m target_sim`, which every `bench run` starts) starts without the firmware engine's emulator.

Each check runs in a fresh interpreter (not the tests' fork server, which imports all of it up front)."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest

from helpers import ROOT, subprocess_env

# the heavy dependencies (each 0.3-1 s to import on a 2-core machine) that no parser may need
HEAVY = ("scipy", "numba", "llvmlite", "matplotlib", "pandas", "dask", "distributed", "unicorn", "capstone")

# in a fresh interpreter: the parser as `bench` builds it, then --help and an unknown option of the top parser and of
# every (sub)command, as `bench.cli.main` parses them; prints the heavy modules imported on the way
WALK = f"""
import contextlib, io, json, sys
from bench.cli import build_parser
from bench.errors import UsageError

def paths(parser, path=()):
    yield path
    if parser.subcommands is not None:
        for name, sub in parser.subcommands.choices.items():
            yield from paths(sub, (*path, name))

walked = []
parser = build_parser()
for path in paths(parser):
    for argv in ([*path, "--help"], [*path, "--no-such-option"]):
        with contextlib.redirect_stdout(io.StringIO()):
            try:
                parser.parse_args(argv)
            except (SystemExit, UsageError):
                pass
    walked.append(" ".join(path))
heavy = sorted({{name.split(".")[0] for name in sys.modules}} & set({HEAVY!r}))
print(json.dumps({{"walked": walked, "heavy": heavy}}))
"""


def _python(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=subprocess_env(), capture_output=True, text=True,
                          timeout=120)


def _imported(importtime: str) -> set[str]:
    """The top-level packages a `python -X importtime` run imported (its stderr)."""
    return {m.group(1).split(".")[0] for m in re.finditer(r"^import time:.*\|\s*(\S+)\s*$", importtime, re.M)}


def test_no_parser_imports_a_heavy_dependency():
    done = _python("-c", WALK)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert {"", "run", "identify", "host", "firmware"} <= set(result["walked"])
    assert result["heavy"] == [], f"building the parser, a --help or a bad argument imported {result['heavy']}"


@pytest.mark.parametrize("argv", [("--help",), ("run", "--help"), ("identify", "--help")], ids=" ".join)
def test_help_imports_no_heavy_dependency(argv):
    done = _python("-X", "importtime", "-m", "bench", *argv)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage: bench" in done.stdout
    heavy = _imported(done.stderr) & set(HEAVY)
    assert not heavy, f"bench {' '.join(argv)} imported {sorted(heavy)}"


def test_python_target_starts_without_the_firmware_emulator():
    """The Python engine's start (artifact loaded, node made) up to a bus it cannot open: no unicorn, no capstone."""
    done = _python("-X", "importtime", "-m", "target_sim", "--model", str(ROOT / "bench/data/default_model.json"),
                   "-i", "socketcan", "-c", "nosuchcan0")
    lines = [line for line in done.stderr.splitlines() if not line.startswith("import time:")]
    assert done.returncode == 1 and lines and "cannot open the CAN bus" in lines[-1], done.stderr[-2000:]
    assert "target_sim" in _imported(done.stderr)
    assert not _imported(done.stderr) & {"unicorn", "capstone", "elftools"}
