"""Issue 23, item 1: a row any check flagged as not the target's own answer reaches no figure.

A property over random trials (seeded numpy, many per kind): a clean lockstep log has random rows tampered with in
each way the checks see — another run's replies with valid counters and CRC, a forged value with valid counter and
CRC, frames of another run replayed before the genuine reply (same counter: contested) or after it (stale counter:
replayed), and frames of the same run replayed (the same values: harmless) — and every figure is then over kept
rows whose values are the clean run's: the RMSE equals the clean run's RMSE over the same rows, the plotted CAN
values are the clean ones or absent, and the rows left out are counted by reason beside the figures.
"""

from __future__ import annotations

import json

import can
import numpy as np
import pytest

from bench.analysis.canmetrics import compute
from bench.analysis.logdecode import decode_log
from bench.analysis.report import render_markdown
from bench.analysis.verdict import problems
from dbc import FrameCodec
from dbc.codec import apply_crc, decode_any
from dbc.contract import REPLY_SIGNALS
from target_sim.artifact import load_artifact

from helpers import after_row, replies_by_row, run_cli, session_drive, session_frames, write_frames

ROWS = 240
TRIALS = 12          # per kind of tampering
NODES = ("yoke", "winding", "tooth", "magnet")


@pytest.fixture(scope="module")
def lti(artifacts):
    return load_artifact(artifacts["lti"])


@pytest.fixture(scope="module")
def clean(lti, tmp_path_factory):
    """The clean session: its drive values, frames, decoded record, results and references."""
    values = session_drive(ROWS, 21)
    frames = session_frames(lti, values)
    record = decode_log(write_frames(tmp_path_factory.mktemp("clean") / "clean.blf", frames))
    results, refs = compute(record, lti)
    assert results.figure_rows.excluded == {} and results.figure_rows.kept == ROWS and problems(results) == []
    return values, frames, record, results, refs


@pytest.fixture(scope="module")
def other(lti):
    """The reply frames of another run (other drive values, the same counters row by row)."""
    return replies_by_row(session_frames(lti, session_drive(ROWS, 22)))


def copy(frame: can.Message, data: bytes | None = None) -> can.Message:
    return can.Message(arbitration_id=frame.arbitration_id, is_extended_id=False, dlc=8,
                       data=bytes(frame.data) if data is None else data)


def with_counter_of(frame: can.Message, genuine: can.Message) -> can.Message:
    """`frame` carrying `genuine`'s alive counter, its CRC made valid again: what the host's checks accept in its
    place."""
    data = bytearray(frame.data)
    data[1] = (data[1] & 0xF0) | (genuine.data[1] & 0x0F)
    return copy(frame, apply_crc(frame.arbitration_id, bytes(data)))


def forged(genuine: can.Message, offset: float) -> can.Message:
    """`genuine` with its first temperature moved by `offset`, counter and CRC valid."""
    decoded = decode_any(genuine)
    signals = {k: v for k, v in decoded.signals.items() if not k.endswith(("_CRC", "_Counter"))}
    signal = REPLY_SIGNALS[decoded.name][0][0]
    signals[signal] = round(signals[signal] + offset, 2)
    return with_counter_of(FrameCodec("TARGET").encode(decoded.name, signals), genuine)


def indices(frames: list[can.Message], row: int) -> list[int]:
    """Where row `row`'s reply frames are in `frames`."""
    ids = {f.arbitration_id for f in replies_by_row(frames)[row]}
    out = []
    for i, frame in enumerate(frames):
        if frame.arbitration_id in ids and int(decode_any(frame).signals["Step"]) == row:
            out.append(i)
    return out


def tamper(kind: str, frames: list[can.Message], other: dict, rng: np.random.Generator) -> tuple[list, set[int]]:
    """A tampered copy of `frames` and the rows whose replies now carry values that are not the target's."""
    frames = [copy(f) for f in frames]
    rows = sorted(int(r) for r in rng.choice(np.arange(2, ROWS - 8), int(rng.integers(1, 12)), replace=False))
    touched: set[int] = set()
    for row in sorted(rows, reverse=True):     # from the end: earlier indices stay valid
        if kind == "foreign":                  # another run's replies in place of the genuine ones
            for i, replacement in zip(indices(frames, row), other[row], strict=True):
                frames[i] = with_counter_of(replacement, frames[i])
        elif kind == "forged":
            i = indices(frames, row)[int(rng.integers(0, 2))]
            offset = float(rng.choice([-1, 1]) * rng.uniform(0.01, 5.0))
            frames[i] = forged(frames[i], offset)
        elif kind == "replayed":
            how = rng.choice(["aligned", "late", "same run"])
            if how == "aligned":               # before the genuine reply, with its counter: contested
                at = after_row(frames, row, "drive")
                frames[at:at] = [copy(f) for f in other[row]]
            elif how == "late":                # a few rows later, its stale counter rejected
                at = after_row(frames, row + int(rng.integers(1, 5)))
                frames[at:at] = [copy(f) for f in other[row]]
            else:                              # this run's own frames again, later: nothing to flag
                at = after_row(frames, row + int(rng.integers(1, 5)))
                frames[at:at] = [copy(frames[i]) for i in indices(frames, row)]
                continue
        touched.add(row)
    return frames, touched


def clean_rmse(clean_record, refs, kept: np.ndarray) -> dict[str, float | None]:
    """The clean run's RMSE per node (against the float64 model) over the step rows `kept` keeps."""
    rows = refs.step_rows
    keep = kept[rows]
    out = {}
    for i, node in enumerate(NODES):
        a, b = clean_record.temps[rows][keep, i], refs.f64[keep, i]
        ok = np.isfinite(a) & np.isfinite(b)
        out[node] = float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2))) if ok.any() else None
    return out


@pytest.mark.parametrize("kind", ["foreign", "forged", "replayed"])
def test_no_flagged_value_reaches_a_figure(kind, lti, clean, other, tmp_path):
    values, frames, clean_record, clean_results, clean_refs = clean
    rng = np.random.default_rng({"foreign": 1, "forged": 2, "replayed": 3}[kind])
    reasons_seen: set[str] = set()
    for trial in range(TRIALS):
        tampered, touched = tamper(kind, frames, other, rng)
        record = decode_log(write_frames(tmp_path / f"{kind}{trial}.blf", tampered))
        results, refs = compute(record, lti)
        kept, rows = refs.kept, results.figure_rows
        where = f"{kind} trial {trial}, rows {sorted(touched)}"
        # every kept row's value is the clean run's, every other row is drawn as nothing
        np.testing.assert_array_equal(record.temps[kept], clean_record.temps[kept], err_msg=where)
        changed = np.zeros(ROWS, dtype=bool)
        both = record.answered
        changed[both] = np.any(record.temps[both] != clean_record.temps[both], axis=1)
        assert not (changed & kept).any(), where
        step_rows = refs.step_rows
        np.testing.assert_array_equal(refs.can, np.where(kept[step_rows, None], clean_record.temps[step_rows],
                                                         np.nan), err_msg=where)
        # the RMSE over the kept rows is the clean run's over the same rows
        expected = clean_rmse(clean_record, clean_refs, kept)
        for node in NODES:
            assert results.accuracy.rmse_C.get(node) == pytest.approx(expected[node], rel=1e-12, abs=0), where
        deviation = results.agreement.max_abs_can_minus_clean_C.worst() or 0.0
        assert deviation <= (clean_results.agreement.max_abs_can_minus_clean_C.worst() or 0.0), where
        # counted beside the figures: every row is kept, without a reply or excluded for a reason
        assert rows.kept + rows.without_reply + rows.excluded_total == ROWS, where
        assert rows.kept == int(np.count_nonzero(kept)), where
        reasons_seen |= set(rows.excluded)
        if touched and rows.excluded_total:
            assert not problems(results) == [], where
            text = render_markdown(results, problems(results), None, {})
            assert rows.text("the RMSE and every figure") in text, where
        assert results.to_json()["figure_rows"]["excluded"] == rows.excluded, where
    expected_reasons = {"foreign": {"off_reference"}, "forged": {"off_reference"},
                        "replayed": {"contested", "replayed"}}[kind]
    assert reasons_seen == expected_reasons


def test_the_replayed_rows_log_counts_its_excluded_rows_and_keeps_the_clean_rmse(lti, clean, other, tmp_path):
    """The issue's example: ten rows' replies replayed from another run right after them (stale counters) and
    three right before the genuine reply (contested): the ten are excluded as replayed, the three as contested, and
    rmse_C is the clean run's over the rows kept."""
    values, frames, clean_record, clean_results, clean_refs = clean
    frames = [copy(f) for f in frames]
    late, aligned = list(range(20, 220, 20)), [55, 156, 205]
    for row in sorted(late + aligned, reverse=True):
        at = after_row(frames, row + 1) if row in late else after_row(frames, row, "drive")
        frames[at:at] = [copy(f) for f in other[row]]
    record = decode_log(write_frames(tmp_path / "replayed.blf", frames))
    results, refs = compute(record, lti)
    rows = results.figure_rows
    assert rows.excluded == {"contested": len(aligned), "replayed": len(late)}
    assert np.flatnonzero(record.replayed).tolist() == late
    expected = clean_rmse(clean_record, clean_refs, refs.kept)
    for node in NODES:
        assert results.accuracy.rmse_C.get(node) == pytest.approx(expected[node], rel=1e-12, abs=0)
    found = problems(results)
    assert f"{len(late)} rows got, in a frame the host's counter check rejected, other temperatures than the " \
           "answer used (a replayed frame): they are left out of every figure" in found
    assert rows.text().startswith(f"figures over {rows.kept} of {ROWS} rows")
    assert rows.text().endswith(f"{len(late) + len(aligned)} rows excluded: contested {len(aligned)}, "
                                f"replayed {len(late)}")


def test_bench_replay_leaves_the_flagged_rows_of_a_log_out_and_says_so(artifacts, lti, clean, tmp_path, udp_bus):
    """`bench replay` of a log with five forged replies: the comparison is over the rows kept, the five are counted
    by reason, and the log is not reproduced (exit 1, one sentence)."""
    values, frames, *_ = clean
    frames = [copy(f) for f in frames]
    rows = [30, 60, 90, 120, 150]
    for row in rows:
        i = indices(frames, row)[0]
        frames[i] = forged(frames[i], 0.5)
    log = write_frames(tmp_path / "forged.blf", frames)
    done = run_cli("-m", "bench", "replay", str(log), "--model", str(artifacts["lti"]), "--as-fast-as-possible",
                   "--log", str(tmp_path / "again.blf"), "--json", *udp_bus.to_argv())
    assert done.returncode == 1, done.stderr
    result = json.loads(done.stdout)
    assert result["recorded_excluded"] == {"off_reference": len(rows)} and result["replayed_excluded"] == {}
    assert (result["compared"], result["identical"], result["different"]) == (ROWS - len(rows),) * 2 + (0,)
    assert result["max_abs_difference_C"] == 0.0 and not result["reproduced"]
    assert (f"the recorded log has {len(rows)} rows a check flagged as not the target's own answer (off_reference "
            f"{len(rows)}): they are left out of the comparison, and the log is not reproduced") in result["problems"]
