"""Progress as pip and tqdm show it (bench/progress.py): on a terminal a bar with a total, a percentage and an ETA;
into a pipe nothing but final lines (no carriage-return states); a sentence never written onto a bar."""

import io
import os
import pty
import re
import subprocess
import sys
import threading
import time

import pytest

from bench import progress

from helpers import subprocess_env, synthetic_columns, write_synthetic_dataset

TIMEOUT_S = 600    # a tiny identify takes ~15 s on an idle machine; generous for a loaded one


@pytest.fixture(scope="module")
def identify_argv(tmp_path_factory) -> list[str]:
    """A tiny identify: 600 rows to train on, 600 to validate on, a swarm of 6 for 4 iterations, 3 LM evaluations."""
    root = tmp_path_factory.mktemp("progress")
    train = write_synthetic_dataset(root / "train.csv", synthetic_columns(600, seed=1), "progress test")
    validate = write_synthetic_dataset(root / "validate.csv", synthetic_columns(600, seed=2), "progress test")
    return [sys.executable, "-m", "bench", "identify", "--train", str(train), "--validate", str(validate),
            "--swarm", "6", "--iterations", "4", "--lm-iterations", "3", "--out", str(root / "m.json")]


def _on_terminal(argv: list[str]) -> tuple[int, str]:
    """Run `argv` with its stderr on a pseudo-terminal (of no size, as `script` from a pipe gives); exit status and
    what the terminal received."""
    master, slave = pty.openpty()
    chunks: list[bytes] = []

    def read() -> None:
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:     # EIO: the child closed the terminal's last writer
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=slave,
                                   env=subprocess_env(can_settings=False))
        os.close(slave)
        rc = process.wait(TIMEOUT_S)
        reader.join(30)
    finally:
        os.close(master)
    return rc, b"".join(chunks).decode("utf-8", "replace")


@pytest.mark.slow
def test_identify_into_a_pipe_writes_no_carriage_return(identify_argv):
    proc = subprocess.run(identify_argv, capture_output=True, text=True, timeout=TIMEOUT_S,
                          env=subprocess_env(can_settings=False))
    assert proc.returncode == 0, proc.stderr
    assert "\r" not in proc.stderr and "PSO LPTN" not in proc.stderr, proc.stderr
    assert "PSO " in proc.stdout     # the summary, the final lines, are there


@pytest.mark.slow
def test_identify_on_a_terminal_shows_total_percentage_and_eta(identify_argv):
    rc, screen = _on_terminal(identify_argv)
    assert rc == 0, screen
    states = [s for s in re.split(r"[\r\n]+", screen) if s.startswith(("PSO LPTN", "LM Hammerstein"))]
    # tqdm's format: "PSO LPTN:  50%|█████     | 2/4 [00:01<00:01,  1.9it/s, cost=...]"
    pso = [s for s in states if s.startswith("PSO LPTN")]
    assert pso and re.search(r"100%\|.*\| 4/4 \[\d\d:\d\d<\d\d:\d\d", pso[-1]), states
    lm = [s for s in states if s.startswith("LM Hammerstein")]
    assert lm and re.search(r"\d+%\|.*\| \d/4 \[\d\d:\d\d<", lm[-1]), states   # 3 evaluations and the start's


# a small study: one seed of torque noise on one model (two filters), on a local Dask cluster of two workers
ROBUSTNESS_SPEC = """[study]
name = "progress"
seeds = 1
kinds = ["noise"]
[perturbations.noise]
subjects = ["torque"]
"""


@pytest.fixture(scope="module")
def robustness_argv(tmp_path_factory, identify_argv) -> list[str]:
    root = tmp_path_factory.mktemp("robustness")
    (root / "spec.toml").write_text(ROBUSTNESS_SPEC)
    data = identify_argv[identify_argv.index("--train") + 1]
    return [sys.executable, "-m", "bench", "robustness", "--data", data, "--spec", str(root / "spec.toml"),
            "--rows", "300", "--workers", "2", "--out"]


@pytest.mark.slow
def test_robustness_says_its_first_sentence_on_a_line_of_its_own(robustness_argv, tmp_path):
    rc, screen = _on_terminal([*robustness_argv, str(tmp_path / "tty")])
    assert rc == 0, screen
    sentence = screen.index("bench: ")
    assert "robustness:" in screen[:sentence], screen     # the bar was shown first ...
    assert re.search(r"\r *\r$", screen[:sentence]), repr(screen[:sentence + 80])   # ... and cleared for it
    # a total, a percentage and an ETA (the bar, leave=False, is removed at the end)
    assert re.search(r"robustness: +[1-9]\d*%\|.*\| [1-9]\d*/\d+ \[\d\d:\d\d<\d\d:\d\d", screen), screen
    piped = subprocess.run([*robustness_argv, str(tmp_path / "pipe")], capture_output=True, text=True,
                           timeout=TIMEOUT_S, env=subprocess_env(can_settings=False))
    assert piped.returncode == 0, piped.stderr
    assert "\r" not in piped.stderr and piped.stderr.startswith("bench: "), piped.stderr


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_sentence_clears_the_bar_line_first(monkeypatch):
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    bar = progress.progress_bar(10, "robustness", "case", quiet=False)
    bar.update(3)
    bar.refresh()
    progress.say("bench: 10 case(s) to do")
    bar.close()
    text = terminal.getvalue()
    before = text[:text.index("bench: 10 case(s) to do")]
    assert "3/10" in before
    # the bar's line was blanked and the cursor is back at its start: the sentence stands on a line of its own
    assert re.search(r"\r *\r$", before), repr(before)


def test_bars_are_off_into_a_pipe_and_with_quiet(monkeypatch):
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert not progress.shows_bars(quiet=False)
    bar = progress.progress_bar(5, "replay", "row", quiet=False)
    bar.update(5)
    bar.close()
    assert sys.stderr.getvalue() == ""
    monkeypatch.setattr(sys, "stderr", _Terminal())
    assert progress.shows_bars(quiet=False) and not progress.shows_bars(quiet=True)


def test_stage_bars_show_each_stage_with_its_total(monkeypatch):
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    bars = progress.StageBars(quiet=False)
    for done in range(1, 5):
        bars("PSO LPTN", done, 4, 1.0 / done)
    bars("LM Hammerstein", 1, 4, 2.0)
    bars.close()
    states = [s for s in re.split(r"[\r\n]+", terminal.getvalue()) if s.strip()]
    assert any(s.startswith("PSO LPTN: 100%") and "4/4" in s for s in states), states
    assert states[-1].startswith("LM Hammerstein:  25%") and "1/4" in states[-1], states


def test_the_replay_bar_counts_rows_of_its_total(monkeypatch):
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    bar = progress.ProgressBar(200, "lockstep", quiet=False)
    for done in (1, 50, 200):
        time.sleep(0.15)   # tqdm redraws at most every 0.1 s
        bar(done, 200)
    bar.close()
    assert re.search(r"lockstep: 100%\|.*\| 200/200 \[", terminal.getvalue()), terminal.getvalue()


def test_a_step_bar_names_each_step_and_moves_its_elapsed_time_while_a_step_runs(monkeypatch):
    """A compiler call says nothing while it runs: the bar shows the steps done of all, the step under way, and
    redraws its elapsed time every TICK_S, so a 10 s compile does not look like a hung one."""
    monkeypatch.setattr(progress, "TICK_S", 0.05)
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    bar = progress.StepBar("firmware hammerstein", quiet=False)
    bar("compiling fw_model.c", 1, 4)
    time.sleep(1.3)                 # one step running: no update from the job, the elapsed time still moves
    bar("linking firmware.elf", 3, 4)
    bar("linked", 4, 4)
    bar.close()
    states = [s for s in re.split(r"[\r\n]+", terminal.getvalue()) if s.strip()]
    compiling = [s for s in states if "compiling fw_model.c" in s]
    assert re.search(r"^firmware hammerstein: +25%\|.*\| 1/4 \[00:00<", compiling[0]), states
    assert any(re.search(r"\| 1/4 \[00:01<", s) for s in compiling), states    # redrawn a second later
    assert any(re.search(r"100%\|.*\| 4/4 .*linked", s) for s in states), states
    assert not [t for t in threading.enumerate() if t.name == "step-bar"]      # the redrawing thread ended


def test_a_step_bar_is_silent_with_quiet_and_into_a_pipe(monkeypatch):
    for stream, quiet in ((_Terminal(), True), (io.StringIO(), False)):
        monkeypatch.setattr(sys, "stderr", stream)
        bar = progress.StepBar("firmware", quiet=quiet)
        bar("compiling startup.c", 0, 2)
        bar("linked", 2, 2)
        bar.close()
        assert stream.getvalue() == ""
        assert not [t for t in threading.enumerate() if t.name == "step-bar"]


@pytest.mark.slow
def test_firmware_build_shows_its_steps_on_a_terminal_and_nothing_with_quiet(tmp_path):
    """`bench firmware build` (10 s of compiling on a loaded machine): each compile and the link on the bar, all
    steps done at the end; with --quiet the terminal gets nothing, into a pipe no carriage return."""
    argv = [sys.executable, "-m", "bench", "firmware", "build", "--out"]
    rc, screen = _on_terminal([*argv, str(tmp_path / "tty")])
    assert rc == 0, screen
    for step in ("compiling startup.c", "compiling fw_model.c", "compiling node.c", "linking firmware.elf"):
        assert re.search(rf"firmware hammerstein: +\d+%\|.*\| [0-3]/4 \[\d\d:\d\d<.*{step}", screen), (step, screen)
    assert re.search(r"firmware hammerstein: 100%\|.*\| 4/4 .*linked", screen), screen
    rc, screen = _on_terminal([*argv, str(tmp_path / "quiet"), "--quiet"])
    assert rc == 0 and screen == "", screen
    piped = subprocess.run([*argv, str(tmp_path / "pipe")], capture_output=True, text=True, timeout=TIMEOUT_S,
                           env=subprocess_env(can_settings=False))
    assert piped.returncode == 0, piped.stderr
    assert "\r" not in piped.stderr and piped.stderr == "compiling the hammerstein model for the Cortex-M4F ...\n"
