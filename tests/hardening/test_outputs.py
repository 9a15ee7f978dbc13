"""Output paths: a --log that names a directory is refused before anything runs, a log that cannot be put in place
leaves no temporary file, and an output with a legal long name (up to NAME_MAX, 255 bytes) gets a temporary name
that is legal too.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import can
import pytest

from bench.fileio import write_atomically, write_bytes_atomically, write_directory_atomically
from dbc.transport import free_udp_port
from host.canlog import FrameLog, read_log

NAME_MAX = 255


def _files(path: Path) -> list[str]:
    """Every file and directory under `path`, hidden ones included."""
    return sorted(str(p.relative_to(path)) for p in path.rglob("*"))


def _one_line(result, prefix="bench: error: ") -> str:
    assert result.rc != 0, str(result)
    assert "Traceback" not in result.stderr, str(result)
    assert len(result.lines) == 1, str(result)
    assert result.lines[0].startswith(prefix), str(result)
    return result.lines[0]


# ---------------------------------------------------------------- --log naming a directory


def test_run_refuses_a_log_that_is_a_directory_before_it_runs(cli, material, scratch):
    out = scratch / "out"
    (out / "x.blf").mkdir(parents=True)
    result = cli("bench", "run", "--data", material.data, "--model", material.art, "--rows", 50, "--log",
                 out / "x.blf", "--no-report", "--quiet", cwd=scratch)
    assert _one_line(result) == f"bench: error: --log {out / 'x.blf'} is a directory; name a file for --log"
    assert result.rc == 1
    assert _files(out) == ["x.blf"]          # the directory as it was, and no temporary log beside it


def test_host_refuses_a_log_that_is_a_directory_before_it_connects(cli, material, scratch):
    out = scratch / "out"
    (out / "h.blf").mkdir(parents=True)
    result = cli("bench", "host", "--data", material.data, "--model", material.art, "--log", out / "h.blf",
                 "--connect-timeout", 2, "--quiet", "-i", "udp_multicast", "--bus-kwargs", f"port={free_udp_port()}",
                 cwd=scratch)
    assert _one_line(result) == f"bench: error: --log {out / 'h.blf'} is a directory; name a file for --log"
    assert _files(out) == ["h.blf"]


def test_a_log_that_cannot_be_put_in_place_leaves_no_temporary_file(tmp_path):
    """Whatever fails at the end (here the log's name became a directory during the run), the temporary file
    goes: the error is raised, nothing is left behind."""
    path = tmp_path / "run.blf"
    log = FrameLog(path)
    log.write(can.Message(arbitration_id=0x100, data=bytes(8), timestamp=1.0, is_extended_id=False))
    assert log.tmp_path.exists()
    path.mkdir()
    with pytest.raises(IsADirectoryError):
        log.close()
    assert _files(tmp_path) == ["run.blf"]
    assert list(path.iterdir()) == []


# ---------------------------------------------------------------- names up to NAME_MAX


@pytest.mark.parametrize("stem", ["a" * (NAME_MAX - 4), "é" * ((NAME_MAX - 5) // 2)], ids=["ascii", "utf8"])
def test_atomic_writes_take_the_longest_legal_names(tmp_path, stem):
    name = f"{stem}.csv"
    assert len(os.fsencode(name)) <= NAME_MAX
    write_bytes_atomically(tmp_path / name, b"first\n")
    seen = []
    write_atomically(tmp_path / name, lambda tmp: (seen.append(tmp), tmp.write_bytes(b"second\n")))
    assert seen[0].name.startswith(".") and seen[0].suffix == ".csv" and len(os.fsencode(seen[0].name)) <= NAME_MAX
    assert (tmp_path / name).read_bytes() == b"second\n"
    folder = "d" * NAME_MAX
    write_directory_atomically(tmp_path / folder, {"a.txt": b"1"})
    write_directory_atomically(tmp_path / folder, {"a.txt": b"2"}, replaceable=["a.txt"])   # the old one aside
    assert (tmp_path / folder / "a.txt").read_bytes() == b"2"
    assert _files(tmp_path) == sorted([name, folder, f"{folder}/a.txt"])


def test_frame_log_takes_the_longest_legal_name(tmp_path):
    path = tmp_path / ("L" * (NAME_MAX - 4) + ".blf")
    with FrameLog(path) as log:
        assert len(os.fsencode(log.tmp_path.name)) <= NAME_MAX
        log.write(can.Message(arbitration_id=0x100, data=bytes(range(8)), timestamp=1.0, is_extended_id=False))
    assert [bytes(m.data) for m in read_log(path)] == [bytes(range(8))]
    assert _files(tmp_path) == [path.name]


def test_target_stats_take_the_longest_legal_name(tmp_path):
    from target_sim.__main__ import _write_stats

    path = tmp_path / ("s" * (NAME_MAX - 5) + ".json")
    _write_stats(str(path), {"rows_used": 3})
    assert json.loads(path.read_text()) == {"rows_used": 3}
    assert _files(tmp_path) == [path.name]


def test_replay_default_log_name_stays_legal():
    from bench.commands.replay import default_replay_name

    assert default_replay_name(Path("run.blf")) == "run.replay.blf"
    long = default_replay_name(Path("r" * 251 + ".blf"))
    assert long == "r" * (NAME_MAX - len(".replay.blf")) + ".replay.blf" and len(long) == NAME_MAX


def test_run_writes_a_log_and_a_report_with_the_longest_legal_names(cli, material, scratch):
    out = scratch / "out"
    log, report = out / ("x" * (NAME_MAX - 4) + ".blf"), out / ("r" * NAME_MAX)
    result = cli("bench", "run", "--data", material.data, "--model", material.art, "--rows", 50, "--log", log,
                 "--report", report, "--quiet", "--json", cwd=scratch, timeout=90)
    assert result.rc == 0, str(result)
    summary = json.loads(result.stdout)
    assert summary["log"] == str(log) and summary["replies"] == 50
    assert _files(out) == sorted([log.name, report.name] + [f"{report.name}/{f}" for f in
                                                             os.listdir(report)])
    assert (report / "report.md").is_file()
    assert not [p for p in _files(out) if Path(p).name.startswith(".")]


def test_run_with_faults_refuses_a_log_name_its_fault_summary_cannot_follow(cli, material, scratch):
    """`<log>.faults.json` is longer than the log's name: refused before the run, not after it."""
    out = scratch / "out"
    log = out / ("f" * 240 + ".blf")
    result = cli("bench", "run", "--data", material.data, "--model", material.art, "--rows", 50, "--log", log,
                 "--no-report", "--faults", "drop=0.05", "--quiet", cwd=scratch)
    line = _one_line(result)
    assert result.rc == 2
    assert line.endswith("would need a file name of 266 bytes (its temporary name), more than the 255 a name may "
                         "have; shorten the log's name by 11 characters"), line
    assert not out.exists() or _files(out) == []
