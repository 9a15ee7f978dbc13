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
from host.canlog import FrameLog, LogError, read_log

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
    with pytest.raises(LogError) as info:
        log.close()
    assert str(info.value) == (f"cannot write the log {path} (Is a directory); check that the path exists and is of "
                               "the right kind, or choose another")
    assert _files(tmp_path) == ["run.blf"]
    assert list(path.iterdir()) == []


# ---------------------------------------------------------------- refused before any work, named when it fails


def test_run_refuses_a_report_directory_of_other_files_before_it_starts_a_target(cli, material, scratch):
    """Decided by the arguments: refused before the data is read and the target started (no logger line, which
    comes just before the target starts), and no log is left."""
    out = scratch / "out"
    busy = out / "rep"
    busy.mkdir(parents=True)
    (busy / "notes.txt").write_text("mine\n")
    result = cli("bench", "run", "--data", material.data, "--model", material.art, "--rows", 50, "--log",
                 out / "x.blf", "--report", busy, "-i", "udp_multicast", "--bus-kwargs", f"port={free_udp_port()}",
                 cwd=scratch)
    assert _one_line(result) == (f"bench: error: --report {busy} holds notes.txt, which is not a report this bench "
                                 "wrote; choose an empty or new directory for --report")
    assert result.rc == 1
    assert _files(out) == ["rep", "rep/notes.txt"]


def test_kill_faults_in_real_time_advise_the_mode_that_was_not_given(cli, material, scratch):
    result = cli("bench", "run", "--data", material.data, "--model", material.art, "--faults", "kill=1", "--mode",
                 "realtime", "--no-report", cwd=scratch)
    assert result.rc == 2, str(result)
    assert _one_line(result) == ("bench: error: kill and freeze faults need lockstep mode (a lost target's rows cannot "
                                 "be sent again on a real-time clock); drop them from --faults/--fault or use --mode "
                                 "lockstep")


def test_replay_refuses_to_overwrite_the_log_it_replays(cli, material, scratch):
    copy = scratch / "run.blf"
    copy.write_bytes(material.log.read_bytes())
    result = cli("bench", "replay", copy, "--model", material.art, "--log", copy, cwd=scratch)
    assert result.rc == 2, str(result)
    assert _one_line(result) == (f"bench: error: --log {copy} is the same file as LOG {copy} (an input of this "
                                 "command, which it would overwrite); choose another --log")
    assert copy.read_bytes() == material.log.read_bytes()


FULL_DISK = ("No space left on device); free space on its file system (or raise the quota), or write it elsewhere")


@pytest.mark.parametrize("suffix", [".blf", ".log", ".asc"])
def test_a_full_disk_while_the_log_is_written_names_the_log(tmp_path, suffix):
    """/dev/full under the log's writer (every write fails with ENOSPC): the error names the log, the temporary
    file goes, and a discarded log does not hide that error behind a second one from its last flush."""
    path = tmp_path / f"run{suffix}"
    log = FrameLog(path)
    frame = can.Message(arbitration_id=0x100, data=bytes(8), timestamp=1.0, is_extended_id=False)
    log.write(frame)
    binary = suffix == ".blf"
    log._writer.file = open("/dev/full", "wb" if binary else "w", buffering=-1 if binary else 1)  # noqa: SIM115
    with pytest.raises(LogError) as info:
        for i in range(100_000):   # the BLF writer flushes its compressed blocks now and then
            log.write(can.Message(arbitration_id=0x100, data=bytes(8), timestamp=1.0 + i, is_extended_id=False))
        log.close()
    assert str(info.value) == f"cannot write the log {path} ({FULL_DISK}"
    log.close(commit=False)
    assert _files(tmp_path) == []


def test_a_full_disk_while_an_output_is_written_names_the_output(tmp_path):
    def full(tmp: Path) -> None:
        with open("/dev/full", "wb") as handle:
            handle.write(b"x")
            handle.flush()

    path = tmp_path / "model.json"
    with pytest.raises(OSError) as info:   # an OutputError: the bench's sentence, still an OSError for callers
        write_atomically(path, full, "the model artifact")
    assert str(info.value) == f"cannot write the model artifact {path} ({FULL_DISK}"
    assert info.value.filename == str(path)
    assert _files(tmp_path) == []


def test_a_full_disk_in_a_report_directory_names_the_file(tmp_path, monkeypatch):
    def full(self, data):
        raise OSError(28, "No space left on device")   # what a write to a full disk raises: no file name

    monkeypatch.setattr(Path, "write_bytes", full)
    with pytest.raises(OSError) as info:
        write_directory_atomically(tmp_path / "rep", {"report.md": b"# r\n"})
    assert str(info.value) == f"cannot write the file {tmp_path / 'rep' / 'report.md'} ({FULL_DISK}"
    assert _files(tmp_path) == []


def test_the_last_resort_sentence_advises_by_the_reason():
    from bench.cli import _os_error_sentence

    assert _os_error_sentence(OSError(28, "No space left on device")) == (
        "a file the command used: No space left on device; free space on its file system (or raise the quota), or "
        "write it elsewhere")
    assert _os_error_sentence(PermissionError(13, "Permission denied", "/x/y")) == (
        "/x/y: Permission denied; make its directory writable, or write it elsewhere")


# ---------------------------------------------------------------- what a killed bench left


def _dead_pid() -> int:
    """The id of a process that has exited and been reaped."""
    import subprocess

    child = subprocess.Popen(["true"])
    child.wait()
    return child.pid


def test_stale_partial_logs_of_dead_processes_go_and_live_ones_stay(tmp_path):
    from bench.run.leftovers import clear_leftovers, remove_stale_partials
    from host.canlog import partial_name

    log = tmp_path / "bench.blf"
    dead, alive = _dead_pid(), os.getppid()
    for pid in (dead, alive):
        (tmp_path / partial_name(log, pid)).write_bytes(b"LOGG")
    (tmp_path / partial_name(tmp_path / "other.blf", dead)).write_bytes(b"LOGG")   # another log's: not ours
    (tmp_path / f".bench.{dead}.partial.asc").write_bytes(b"x")   # another format of the name: not this log's
    assert remove_stale_partials(log) == {dead: tmp_path / partial_name(log, dead)}
    assert _files(tmp_path) == sorted([partial_name(log, alive), partial_name(tmp_path / "other.blf", dead),
                                       f".bench.{dead}.partial.asc"])
    assert [n for n in clear_leftovers(log) if "partial log" in n] == []   # nothing more to remove


def test_stale_scratch_dirs_of_dead_processes_go_and_live_ones_stay(tmp_path):
    from bench.run.leftovers import remove_stale_scratch

    dead, alive = _dead_pid(), os.getpid()
    gone = tmp_path / f"bench-target-{dead}-abc_123"
    (gone / "inner").mkdir(parents=True)
    (gone / "inner" / "target-stats.json").write_text("{}")
    kept = [tmp_path / f"bench-target-{alive}-x1", tmp_path / f"bench-firmware-check-{alive}-y2",
            tmp_path / "bench-target-q8w7e6r5", tmp_path / "bench-notes"]   # live, an older name, not ours
    for path in kept:
        path.mkdir()
    assert remove_stale_scratch(tmp_path) == [gone]
    assert _files(tmp_path) == sorted(p.name for p in kept)


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
