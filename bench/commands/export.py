"""`bench export LOG --out FILE`: a log for other CAN tools: any format python-can writes, only the host's frames,
drive-time timestamps.

    bench export LOG --out FILE [--host-only] [--drive-time [--sample-period S|auto]] [--json] [--quiet]

The output's format follows its suffix as `bench run --log` does (.blf .asc .log .csv, .mf4 with asammdf;
`host.canlog.FrameLog`: written under a temporary name and renamed). `--host-only` keeps the frames the DBC's HOST
node sends (ResetTemps, Control, RestoreState, DriveInputs, DriveTemps, DriveCurrents, BenchEvent), byte for
byte: what `python -m can.player` should send to a new target, without the recorded target's replies.
`--drive-time` sets each frame's timestamp to the drive time of its data row, Step × the data's sample period
(a lockstep run of 7274 s of driving then spans 7274 s, not the seconds it took): the row of DriveInputs,
DriveTemps, DriveCurrents, Temperatures1/2, Timing1-4 and StateCheckpoint is their Step; every other frame (and a
frame that fails its CRC) keeps its place with the time of the row before it (before the first row: the first
row's). Timestamps never go back (a row sent again, a target restored to an earlier row, keeps the latest time).
The sample period is --sample-period, or read from the log: the model step Δt of TargetInfo and the rows after
which the target stepped its model (Timing1), which only one sample period explains.

The start time an .asc or .mf4 header states is the recording's (its first frame's time; with --host-only too),
and MF4 frame times count from it; with --drive-time the start is 0 (1970-01-01 00:00 UTC), so the frame times
are the drive times.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import can

from bench.commands.args import declare_files
from bench.commands.common import add_output_flags, check_writable, print_json, sample_period
from bench.errors import BenchError, UsageError
from dbc import FrameError
from dbc.codec import decode_any
from dbc.contract import nearest_row
from dbc.database import frame_id, host_frame_ids, row_step_messages
from host.canlog import FrameLog, check_log_path, read_log
from target_sim.model import InputAccumulator

MAX_DIGITS = 6   # significant digits of an inferred sample period


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("export", help="a log for other CAN tools: another format, host frames only, "
                                             "drive-time timestamps",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path, help="a bus log written by 'bench run', 'bench replay' or 'bench host'")
    p.add_argument("--out", type=Path, required=True,
                   help="the log to write; format by suffix: .blf .asc .log (candump) .csv .mf4")
    p.add_argument("--host-only", action="store_true",
                   help="keep only the host's frames (what can.player should send to a new target)")
    p.add_argument("--drive-time", action="store_true",
                   help="timestamps = drive time of each frame's data row (Step x the sample period)")
    p.add_argument("--sample-period", type=sample_period, default=None, metavar="S|auto",
                   help="the data's sample period in seconds for --drive-time (default auto: read from the log's "
                        "TargetInfo and Timing1 frames)")
    add_output_flags(p)
    declare_files(p, inputs=('LOG',), outputs=('--out',))
    p.set_defaults(func=run)


def _is_standard(msg: can.Message) -> bool:
    return not (msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame)


def _row_steps(messages: list[can.Message]) -> list[int | None]:
    """Per frame, the Step of the data row it belongs to (None: no row, or a frame that fails validation)."""
    ids = {frame_id(name) for name in row_step_messages()}   # the target's replies carry the row they answer
    steps: list[int | None] = []
    for msg in messages:
        step = None
        if _is_standard(msg) and msg.arbitration_id in ids:
            try:
                step = int(decode_any(msg).signals["Step"])
            except FrameError:
                step = None
        steps.append(step)
    return steps


def _unwrapped(steps: list[int | None]) -> list[int | None]:
    """Steps (16 bits) as row numbers: each the row nearest to the previous one with that Step."""
    rows: list[int | None] = []
    last = None
    for step in steps:
        if step is None:
            rows.append(None)
            continue
        last = step if last is None else nearest_row(step, last)
        rows.append(last)
    return rows


def model_dt(messages: list[can.Message]) -> float | None:
    """The model step Δt the log's TargetInfo states (the first valid one), or None."""
    target_info = frame_id("TargetInfo")
    for msg in messages:
        if _is_standard(msg) and msg.arbitration_id == target_info:
            try:
                dt = float(decode_any(msg).signals["ModelDt"])
            except FrameError:
                continue
            if dt > 0:
                return dt
    return None


def infer_sample_period(step_rows: list[int], dt: float) -> float | None:
    """The data sample period that makes exactly the rows `step_rows` (after which the target stepped its model,
    Δt `dt`) the ends of their model steps' intervals: the estimate Δt × steps / rows, rounded to the fewest
    significant digits that reproduce those rows (a Timing1 frame or two may be missing), or None."""
    rows = sorted(set(step_rows))
    if len(rows) < 2 or dt <= 0:
        return None
    estimate = dt * (len(rows) - 1) / (rows[-1] - rows[0])
    slack = max(2, len(rows) // 100)
    for digits in range(1, MAX_DIGITS + 1):
        candidate = float(f"{estimate:.{digits}g}")
        rule = InputAccumulator(candidate, dt)         # the target's rule of when a model step is due
        if rule.sample_us <= 0 or not all(rule.ends_interval(n) for n in rows):
            continue
        predicted = sum(1 for n in range(rows[0], rows[-1] + 1) if rule.ends_interval(n))
        if len(rows) <= predicted <= len(rows) + slack:
            return candidate
    return None


def drive_times(rows: list[int | None], period_s: float) -> list[float]:
    """Per frame, the drive time of its row (row × period); a frame without one gets the previous frame's time
    (before the first row, the first row's); never decreasing."""
    first = next((r for r in rows if r is not None), 0)
    current = first * period_s
    out = []
    for row in rows:
        if row is not None:
            current = max(current, row * period_s)
        out.append(current)
    return out


def _period(args, messages: list[can.Message], rows: list[int | None], timing1: list[bool], path: Path) \
        -> tuple[float, str]:
    if args.sample_period is not None:
        return args.sample_period, "--sample-period"
    dt = model_dt(messages)
    step_rows = [r for r, is_timing in zip(rows, timing1, strict=True) if is_timing and r is not None]
    period = infer_sample_period(step_rows, dt) if dt is not None else None
    if period is None:
        what = ("no TargetInfo frame with the model step" if dt is None else
                f"no sample period that fits the {len(set(step_rows))} rows its Timing1 frames name at Δt {dt:g} s")
        raise BenchError(f"log {path} has {what}, so the data's sample period cannot be read from it; pass "
                         "--sample-period S with --drive-time")
    return period, f"the log (TargetInfo Δt {dt:g} s, Timing1 rows)"


def run(args: argparse.Namespace) -> int:
    if args.sample_period is not None and not args.drive_time:
        raise UsageError("--sample-period sets the period of --drive-time; pass --drive-time too, or drop it")
    path = check_log_path(args.log, for_reading=True)
    out = check_log_path(args.out)
    check_writable(out, "--out")
    messages = list(read_log(path))
    period = source = None
    times = None
    if args.drive_time:
        rows = _unwrapped(_row_steps(messages))
        timing1 = [_is_standard(m) and m.arbitration_id == frame_id("Timing1") for m in messages]
        period, source = _period(args, messages, rows, timing1, path)
        times = drive_times(rows, period)
    host_ids = host_frame_ids()
    keep = [i for i, m in enumerate(messages)
            if not args.host_only or (_is_standard(m) and m.arbitration_id in host_ids)]
    if not keep:
        raise BenchError(f"log {path} has no host frames to export; is it a log of this bench?")
    # the recording's start in the .asc/.mf4 header (not the export's time); drive time counts from 0
    with FrameLog(out, start_time=0.0 if times is not None else messages[0].timestamp) as log:
        for i in keep:
            msg = messages[i]
            if times is not None:
                msg.timestamp = times[i]
            log.write(msg)
    first, last = messages[keep[0]].timestamp, messages[keep[-1]].timestamp
    summary = {"log": str(path), "out": str(out), "frames_read": len(messages), "frames_written": len(keep),
               "host_only": args.host_only, "drive_time": args.drive_time, "sample_period_s": period,
               "sample_period_source": source, "first_timestamp": first, "last_timestamp": last}
    if args.json:
        print_json(summary)
    else:
        what = "host frames" if args.host_only else "frames"
        timing = (f"; drive time, {period:g} s per row (from {source}): {first:g} to {last:g} s"
                  if args.drive_time else "")
        print(f"wrote {len(keep)} {what} of {len(messages)} to {out}{timing}")
    return 0
