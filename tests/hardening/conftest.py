"""Fixtures of the hardening tests: good and broken inputs of every kind, and a runner for the real CLIs.

`cli` runs `python -m bench ...` / `python -m target_sim ...` in a child process and returns exit status,
stdout and stderr. By default the child is forked from a server that has the CLIs' modules imported already
(tests/zygote.py, `helpers.ForkServer`: a fresh interpreter, not pytest's), which makes a bad-input case cost ~0.1 s
instead of ~2 s of imports; HARDENING_SUBPROCESS=1 runs every case as `sys.executable -m ...` instead, and cases that
need a fresh interpreter (a broken DBC is found while importing) always do.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest

from helpers import ForkServer, artifact_text, subprocess_env, synthetic_columns, write_synthetic_dataset

ALWAYS_SUBPROCESS = os.environ.get("HARDENING_SUBPROCESS") == "1"


def child_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    # the developer's python-can settings must not change the cases
    return subprocess_env(can_settings=False, OPENBLAS_NUM_THREADS="1", **(extra or {}))


@dataclass
class Result:
    argv: list[str]
    rc: int
    stdout: str
    stderr: str
    seconds: float = 0.0

    @property
    def lines(self) -> list[str]:
        return self.stderr.splitlines()

    def __str__(self) -> str:
        return (f"$ {' '.join(self.argv)}\nexit {self.rc} after {self.seconds:.2f} s\n--- stderr ---\n{self.stderr}"
                f"--- stdout ---\n{self.stdout[-2000:]}")


class Cli:
    """Runs `python -m MODULE ARGS` in a child process (forked from the fork server, or a plain subprocess)."""

    def __init__(self, workdir: Path):
        self.workdir = workdir
        self.server = ForkServer(workdir, child_env())

    def __call__(self, module: str, *args: str, cwd: Path | None = None, env: dict[str, str] | None = None,
                 timeout: float = 60, fresh: bool = False) -> Result:
        args = [str(a) for a in args]
        cwd = Path(cwd or self.workdir)
        if fresh or ALWAYS_SUBPROCESS:
            return self.subprocess(module, *args, cwd=cwd, env=env, timeout=timeout)
        done = self.server.run(module, args, cwd=cwd, env=child_env(env), timeout=timeout)
        result = Result(["python", "-m", module, *args], done.rc, done.stdout, done.stderr, done.seconds)
        if done.timed_out:
            pytest.fail(f"timed out after {timeout} s\n{result}")
        return result

    def subprocess(self, module: str, *args: str, cwd: Path | None = None, env: dict[str, str] | None = None,
                   timeout: float = 60) -> Result:
        argv = [sys.executable, "-m", module, *map(str, args)]
        try:
            done = subprocess.run(argv, cwd=cwd or self.workdir, env=child_env(env), capture_output=True, text=True,
                                  timeout=timeout, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            pytest.fail(f"timed out after {timeout} s: {' '.join(argv)}")
        return Result(["python", "-m", module, *map(str, args)], done.returncode, done.stdout, done.stderr)

    def close(self) -> None:
        self.server.close()


@pytest.fixture(scope="session")
def cli(tmp_path_factory) -> Cli:
    runner = Cli(tmp_path_factory.mktemp("cli"))
    yield runner
    runner.close()


# ---------------------------------------------------------------- good inputs


@dataclass
class Material:
    root: Path
    art: Path            # a hammerstein artifact (what every good --model is)
    lti: Path            # another model (another model id)
    data: Path           # a valid 60-row dataset with its sidecar
    campaign: Path       # a directory with valid (small) cycle_coolant20/40/60.csv
    log: Path            # a .blf of `bench run` with `art` and `data` (50 rows)
    logs: dict[str, Path]  # the same frames in every format: suffix -> path
    bad: Path            # broken inputs are written here by the tests' builders
    afile: Path          # a regular file: a path "below" it cannot be created, even by root

    def model_id(self, path: Path) -> str:
        from target_sim.artifact import load_artifact

        return f"{load_artifact(path).model_id:08x}"


@pytest.fixture(scope="session")
def material(tmp_path_factory, cli) -> Material:
    from bench.drive.dataset import csv_bytes

    root = tmp_path_factory.mktemp("material")
    art, lti = root / "art.json", root / "lti.json"
    art.write_text(artifact_text("hammerstein"), encoding="utf-8")
    lti.write_text(artifact_text("lti-lptn"), encoding="utf-8")
    data = root / "data" / "small.csv"
    columns = synthetic_columns(60, seed=11, torque_sd=20.0, speed_sd=100.0, coolant_amplitude=1.5, coolant_period=30.0,
                                ambient_period=45.0, linear_warming=True)
    write_synthetic_dataset(data, columns, "hardening tests")
    campaign = root / "campaign"
    campaign.mkdir()
    for coolant in (20, 40, 60):
        (campaign / f"cycle_coolant{coolant}.csv").write_bytes(csv_bytes(columns))
    log = root / "logs" / "run.blf"
    made = cli("bench", "run", "--data", data, "--model", art, "--rows", 50, "--log", log, "--no-report", "--quiet",
               "--tolerate-gaps", timeout=90)
    assert made.rc == 0 and log.is_file(), str(made)
    import can

    frames = list(can.LogReader(str(log)))
    logs = {".blf": log}
    for suffix in (".asc", ".log", ".csv"):
        path = log.with_suffix(suffix)
        with can.Logger(str(path)) as writer:
            for msg in frames:
                writer.on_message_received(msg)
        logs[suffix] = path
    bad = root / "bad"
    bad.mkdir()
    afile = root / "afile"
    afile.write_text("a regular file, not a directory\n")
    return Material(root, art, lti, data, campaign, log, logs, bad, afile)


@pytest.fixture(scope="session")
def artifact_texts() -> dict[str, str]:
    """Valid artifacts of the three kinds, as JSON text."""
    return {kind: artifact_text(kind) for kind in ("hammerstein", "lti-lptn", "pv-lptn")}


@pytest.fixture
def scratch():
    """A fresh directory outside the repository (the working directory of a case)."""
    path = Path(tempfile.mkdtemp(prefix="hardening-"))
    yield path
    shutil.rmtree(path, ignore_errors=True)
