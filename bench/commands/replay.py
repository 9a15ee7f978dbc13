"""`bench replay LOG`: re-send the host frames of a recorded log and compare the new replies with the recorded ones.

    bench replay LOG [--speed X | --as-fast-as-possible] [--model FILE] [--no-start-target] [--log FILE]
                     [--engine python|firmware] [--xcp-elf ELF] [--reply-timeout S] [--json] [--quiet]
                     [--wait-for-listener SECONDS] [-i INTERFACE] [-c CHANNEL] [--bus-kwargs K=V ...]
                     [--criteria FILE] [--baseline FILE] [--junit-xml FILE]

The host frames (ResetTemps, Control, DriveInputs, DriveTemps) go out byte for byte, counters and CRCs as recorded,
with the recorded timing (`can.MessageSync`, scaled by --speed) or as fast as possible in lockstep (each row waits
for its replies). A target is started with the log's model (default: the packaged artifact, which must have the
log's model id; --model names another) unless --no-start-target, which talks to a target already running on the
given bus; the started target runs the engine the log's target ran (a log with Timing4 frames: the firmware engine)
unless --engine says otherwise. The new session is logged (default out/replay/<log name>.replay.blf). Exit 0 when
every recorded reply came back identical: both logs are decoded (`bench.analysis.logdecode`) and each data row's
final reply is compared, so a row the recorded run sent twice counts once. The comparison is over the rows the
bench's one rule keeps (`bench.analysis.rowfilter`, with the log's offline float32 reference as `bench analyze`
makes it): a recorded row a check flagged as not the target's own answer (contested, replayed, off the reference)
is left out and counted ("recorded_excluded", by reason), and such a log is not reproduced (exit 1), for those
rows were never the target's to reproduce; a replayed row flagged the same way counts in "replayed_excluded".

Acceptance criteria (--criteria, --baseline, --junit-xml) as `bench run`'s, judged on the figures of the new
session's log (against the measurement of a dataset in out/data whose rows match, else the float64 model): each
check's figure, limit and verdict in the JSON ("acceptance"), exit status 1 when any fails; the JUnit testcase
"clean" is "reproduced".

A log with XCP calibrations (a master's DOWNLOADs during the run) replays calibrated: the master's commands go out
in their logged place among the rows, each waiting for its answer as the master did, and the started target's
cells sit where the recorded target's were: the ELF --xcp-elf names, else the one the log's note names
(`<log>.elf.json`, written by `bench run`/`bench replay` on the firmware engine; refused in one sentence when gone
or changed), else a firmware log's packaged ELF, runs on the firmware engine, or lays out the Python engine's
cells; a Python target's calibrated log (its cells in the Python slave's pages) is refused on the firmware engine.
A DOWNLOAD the new target answers otherwise than the recorded one (its cells elsewhere) makes the replay not
reproduced.

A log of a run with bus faults (`bench run --faults drop=...`) replays as it was made: its faulty frames go out
again byte for byte (those on the unknown_id fault's ids too), the target rejects the same frames, and the replay
is reproduced only if its rejection counters (RxErrors) also equal the recorded ones. A log with process faults
(kill, freeze: the target was lost and restored from its StateCheckpoint mid-run) replays too: the replay's
target is not killed, it receives the recorded RestoreState and RESTORE and, since a restore is exact, answers
every row as recorded; its rejection counters are not compared (the recorded ones are the last process's).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bench.acceptance.cli import add_acceptance_arguments, finish, prepare
from bench.commands.args import (
    add_listener_argument,
    announce_logger,
    bus_from_args,
    declare_files,
    positive_float,
    refuse_same,
)
from bench.commands.common import add_output_flags, check_writable, print_json
from bench.errors import BenchError
from bench.run.elfnote import check_given_elf, recorded_layout
from bench.run.inputs import firmware_for_engine, load_model
from bench.run.leftovers import clear_and_say
from bench.run.prepare import check_log_names
from dbc import FrameError, frame_id
from dbc.codec import decode_any
from dbc.contract import DEFAULT_REPLY_TIMEOUT_S
from dbc.files import fitted_name
from dbc.transport import add_bus_arguments
from dbc.xcp import cmd_id, res_id
from host.canlog import check_log_path, read_log
from host.replay import count_rows, host_frames
from target_sim.engines import ENGINES

if TYPE_CHECKING:  # the CLI builds every subcommand's parser at start: the log decoder when a replay runs
    from bench.analysis.logdecode import BusRecord
    from bench.analysis.results import ReplyComparison, RunResults
    from bench.analysis.rowfilter import RowSelection

PROCESS_FAULTS = ("kill", "freeze")


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("replay", help="re-send a recorded log's host frames and compare the replies",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path, help="a bus log written by 'bench run' or the host")
    timing = p.add_mutually_exclusive_group()
    timing.add_argument("--speed", type=positive_float, default=1.0,
                        help="replay the recorded timing this many times faster (default 1)")
    timing.add_argument("--as-fast-as-possible", action="store_true",
                        help="ignore the recorded timing: lockstep, each row waits for its replies")
    p.add_argument("--model", type=Path, default=None, help="artifact for the target (default: the packaged one)")
    p.add_argument("--no-start-target", action="store_true",
                   help="do not start a target: use the one running on the given bus")
    p.add_argument("--log", dest="new_log", type=Path, default=None,
                   help="log of the new session (default out/replay/<name>.replay.blf)")
    p.add_argument("--reply-timeout", type=positive_float, default=DEFAULT_REPLY_TIMEOUT_S,
                   help=f"seconds to wait for a row's replies (default {DEFAULT_REPLY_TIMEOUT_S:g})")
    p.add_argument("--engine", choices=ENGINES, default=None,
                   help="what the started target runs: the Python model or the firmware in the emulated core "
                        "(default: what the log's target ran)")
    p.add_argument("--xcp-elf", type=Path, default=None, metavar="ELF",
                   help="for a log with XCP calibrations: the firmware ELF whose addresses the recorded target's XCP "
                        "cells had (default: the ELF the log's note names, else a firmware target's packaged ELF, "
                        "else the Python slave's pages); the started target's cells are laid out by it")
    add_output_flags(p)
    add_acceptance_arguments(p)
    add_listener_argument(p)
    add_bus_arguments(p)
    declare_files(p, inputs=('LOG', '--model', '--xcp-elf'), outputs=(('--log', 'new_log'),))
    p.set_defaults(func=run)


def default_replay_name(path: Path) -> str:
    """`<stem>.replay.blf`, the stem shortened (counted in bytes) so that the name stays a legal one."""
    return fitted_name(path.stem, lambda stem: f"{stem}.replay.blf")


def log_model_id(messages) -> int | None:
    status = frame_id("Status")
    for msg in messages:
        if msg.arbitration_id == status and not msg.is_extended_id:
            try:
                return int(decode_any(msg).signals["ModelId"])
            except FrameError:
                continue
    return None


def process_faults(record: BusRecord) -> dict[str, int]:
    """The kills and freezes marked in a log (with its target-lost marks: a target lost for another reason)."""
    kinds = Counter(m.fault for m in record.marks if m.fault in PROCESS_FAULTS)
    lost = sum(1 for m in record.marks if m.event == "target-lost")
    if lost > sum(kinds.values()):
        kinds["lost"] = lost - sum(kinds.values())
    return dict(kinds)


def injected_faults(record: BusRecord) -> dict[str, int]:
    """The faults marked in a log (BenchEvent FAULT marks) per kind."""
    return dict(Counter(m.fault for m in record.marks if m.event == "fault" and m.fault))


def download_answers(record: BusRecord) -> list[int]:
    """The packet identifier (RES or ERR) that answered each XCP DOWNLOAD of a log, in order (-1: none logged)."""
    from target_sim.xcp.codes import PID_ERR, PID_RES, Cmd

    command, response = cmd_id(), res_id()
    answers: list[int] = []
    waiting = False
    for fid, dlc, data in zip(record.frame_ids.tolist(), record.frame_dlc.tolist(), record.frame_data, strict=True):
        if fid == command and dlc:
            waiting = data[0] == Cmd.DOWNLOAD     # one command outstanding: a new one ends the wait for the last
            answers += [-1] if waiting else []
        elif fid == response and waiting and dlc and data[0] in (PID_RES, PID_ERR):     # not a DAQ packet
            answers[-1], waiting = int(data[0]), False
    return answers


def downloads_answered_otherwise(recorded: BusRecord, replayed: BusRecord) -> int:
    """How many of the recorded log's XCP DOWNLOADs the replay's target answered otherwise (accepted one the
    recorded target refused or the reverse, or did not answer): its cells were not where the recorded target's."""
    ours, theirs = download_answers(replayed), download_answers(recorded)
    return sum(a != b for a, b in zip(ours, theirs, strict=False)) + abs(len(ours) - len(theirs))


def engine_layout(log: Path, recorded: BusRecord, engine: str, layout: Path | None) -> tuple[Path | None, Path | None]:
    """(firmware, xcp_elf) of the target a replay starts, so that a log's XCP DOWNLOADs reach the cells they
    reached: `layout`, the ELF whose addresses the recorded target's cells had, is the firmware engine's ELF or the
    Python engine's --xcp-elf. (None, None) for a log without calibrations (the engine's defaults); BenchError (one
    sentence) for a Python target's calibrated log (its cells in the Python slave's pages) on the firmware engine."""
    if not recorded.xcp_downloads:
        return None, None
    if engine == "python":
        return None, layout
    if layout is None:
        raise BenchError(f"log {log} calibrated a Python target over XCP ({recorded.xcp_downloads} DOWNLOADs) at the "
                         "Python slave's own addresses, where the firmware has no cells; replay it with --engine "
                         "python, or give the ELF whose addresses the target had with --xcp-elf")
    return layout, None


def compare_replies(recorded: BusRecord, recorded_rows: RowSelection, new: BusRecord,
                    new_rows: RowSelection) -> ReplyComparison:
    """Each row's final reply of the replay against the recorded one, over the rows the rule keeps in both (a row
    the replay answered but a check flagged is neither compared nor missing: it counts in replayed_excluded)."""
    from bench.analysis.results import ReplyComparison

    rows = min(recorded.rows, new.rows)
    recorded_ok, new_ok = recorded_rows.kept[:rows], new_rows.kept[:rows]
    both = recorded_ok & new_ok
    same = np.all(recorded.temps[:rows] == new.temps[:rows], axis=1) & both
    diff = np.abs(recorded.temps[:rows] - new.temps[:rows])[both]
    return ReplyComparison(rows_recorded=recorded.rows, rows_replayed=new.rows,
                           recorded_answered=int(np.count_nonzero(recorded.answered)),
                           replayed_answered=int(np.count_nonzero(new.answered)),
                           compared=int(np.count_nonzero(both)), identical=int(np.count_nonzero(same)),
                           different=int(np.count_nonzero(both & ~same)),
                           missing_in_replay=int(np.count_nonzero(recorded_ok & ~new.answered[:rows])),
                           max_abs_difference_C=float(diff.max()) if diff.size else 0.0,
                           recorded_excluded=dict(recorded_rows.counts.excluded),
                           replayed_excluded=dict(new_rows.counts.excluded))


def figure_rows(record: BusRecord, artifact, xcp_elf: Path | None = None) -> RowSelection:
    """The rows of a log the rule keeps, judged against the log's offline float32 reference as `bench analyze`
    judges them (`canmetrics.compute`, the twin that replays its XCP calibrations laid out by `xcp_elf`); a log
    that cannot be compared with the model (no complete RESET, no currents for an electrical loss model) by the
    log's own checks only."""
    from bench.analysis.canmetrics import AGREEMENT_TOLERANCE_C, compute
    from bench.analysis.rowfilter import RowSelection, kept_rows

    try:
        _, refs = compute(record, artifact, xcp_elf=xcp_elf)
    except ValueError:
        return kept_rows(record, tolerance=AGREEMENT_TOLERANCE_C)
    return RowSelection(refs.kept, refs.figure_rows)


def replay_figures(record: BusRecord, artifact, xcp_elf: Path | None = None) -> tuple[RunResults | None, str]:
    """The figures of the replay's log as `bench analyze` makes them (against a dataset in out/data whose rows
    match, else the float64 model; its calibrations' cells laid out by `xcp_elf`), for the acceptance criteria;
    (None, why) when it cannot be compared."""
    from bench.analysis.canmetrics import compute
    from bench.run.inputs import matching_dataset

    try:
        return compute(record, artifact, matching_dataset(record.drive, artifact), xcp_elf=xcp_elf)[0], ""
    except ValueError as exc:
        return None, f"the replay's log cannot be compared with the model ({exc})"


def run(args: argparse.Namespace) -> int:
    from bench.acceptance.junit import CleanCase
    from bench.analysis.logdecode import decode_log
    from bench.analysis.results import Percentiles, Rejections, ReplayResults
    from bench.analysis.verdict import counts_text
    from bench.progress import ProgressBar
    from bench.run.execute import replay_with_target

    started = time.perf_counter()
    acceptor = prepare(args)   # a bad criteria or baseline file: one sentence, exit status 2, before any work
    path = check_log_path(args.log, for_reading=True)
    new_log = args.new_log or Path("out/replay") / default_replay_name(path)
    check_log_path(new_log)   # the arguments' refusals before the log is read
    check_writable(new_log, "--log")
    check_log_names(new_log, None, firmware=True)     # the note of an ELF it may write beside it
    if args.new_log is None:   # the default beside nothing the user named: `bench.cli` checked the options given
        refuse_same("--log", new_log, "LOG", path)
    messages = list(read_log(path))
    frames = host_frames(messages)
    if count_rows(frames) == 0:
        raise BenchError(f"log {path} has no DriveInputs frames to replay; is it a log of this bench?")
    recorded = decode_log(path)
    restarted = process_faults(recorded)
    faults = injected_faults(recorded)
    recorded_id = log_model_id(messages)
    artifact, model_path = load_model(args.model)
    if recorded_id is not None and recorded_id != artifact.model_id:
        raise BenchError(f"log {path} was recorded with model {recorded_id:08x}, but {model_path} is "
                         f"{artifact.model_id:08x}; pass the log's artifact with --model")
    if args.xcp_elf is not None:
        check_given_elf(args.xcp_elf, artifact, path)
    bus = bus_from_args(args)
    quiet = args.quiet or args.json
    engine = args.engine or ("firmware" if len(recorded.timing.get("m4_cycles", ())) else "python")
    # the ELF whose addresses the recorded target's XCP cells had (None: the Python slave's pages, or no calibration)
    layout = (args.xcp_elf or recorded_layout(path, recorded, artifact)) if recorded.xcp_downloads else None
    firmware, xcp_elf = None, None
    if not args.no_start_target:
        firmware, xcp_elf = engine_layout(path, recorded, engine, layout)
        firmware = firmware or firmware_for_engine(engine, artifact, new_log.parent / "firmware-cache", quiet=quiet)
    if not quiet:
        print(f"bench: replaying {recorded.rows} rows of {path} "
              f"({'as fast as possible' if args.as_fast_as_possible else f'recorded timing x{args.speed:g}'}) "
              f"over {bus.describe()}", file=sys.stderr)
    clear_and_say(new_log, quiet)   # what a killed replay left beside this log and in the temporary directory
    announce_logger(bus, args.quiet, wait_s=args.wait_for_listener)
    bar = ProgressBar(count_rows(frames), "replay", quiet)
    try:
        outcome = replay_with_target(None if args.no_start_target else model_path, artifact, bus, messages,
                                     timed=not args.as_fast_as_possible, speed=args.speed, log_path=new_log,
                                     reply_timeout_s=args.reply_timeout, progress=bar, firmware=firmware,
                                     xcp_elf=xcp_elf)
    finally:
        bar.close()
    result = outcome.result
    replayed = decode_log(Path(result.log_path))
    recorded_rows = figure_rows(recorded, artifact, layout)
    comparison = compare_replies(recorded, recorded_rows, replayed, figure_rows(replayed, artifact, layout))
    excluded = recorded_rows.counts.excluded_total
    # the target must reject what it rejected then; a target that ran before (--no-start-target) counted before,
    # and the recorded counters of a log whose target restarted are only those of its last process
    compare_rejections = bool(faults) and not args.no_start_target and not restarted
    same_rejections = not compare_rejections or replayed.rx_errors == recorded.rx_errors
    unlike = downloads_answered_otherwise(recorded, replayed)
    reproduced = (comparison.different == 0 and comparison.missing_in_replay == 0 and not excluded
                  and comparison.compared == recorded_rows.counts.kept and same_rejections and not unlike)
    # of a faulted log, the passes the faults left unanswered and the target's rejections are expected
    problems = (replace(result, missing=0, target_rx_errors={}) if faults else result).problems()
    if not same_rejections:
        problems.append(f"the target's rejections {replayed.rx_errors} differ from the recorded "
                        f"{recorded.rx_errors}")
    if unlike:
        problems.append(f"the replay's target answered {unlike} of the log's {recorded.xcp_downloads} XCP DOWNLOADs "
                        "otherwise than the recorded target (its calibration cells are not where the recorded "
                        "target's were: give the ELF whose addresses they had with --xcp-elf)")
    if excluded:
        problems.append(f"the recorded log has {excluded} rows a check flagged as not the target's own answer "
                        f"({counts_text(recorded_rows.counts.excluded)}): they are left out of the comparison, and "
                        "the log is not reproduced")
    acceptance = None
    if acceptor.gate is not None:
        figures, why = replay_figures(replayed, artifact, layout)
        acceptance = acceptor.judge(figures, why)
    summary = ReplayResults(
        log=str(path), replay_log=result.log_path, reproduced=reproduced, comparison=comparison,
        engine=None if args.no_start_target else engine, m4_cycles=result.m4_cycles, faults_in_log=faults or None,
        rejections_compared=compare_rejections,
        target_rejections=Rejections(recorded=recorded.rx_errors, replayed=replayed.rx_errors),
        mode=result.mode, speed=result.speed, wall_time_s=result.wall_time_s, rows_per_s=result.rows_per_s,
        round_trip_us=Percentiles(**result.round_trip_us), problems=problems, acceptance=acceptance)
    if args.json:
        print_json(summary.to_json())
    else:
        print(f"replayed {comparison.rows_replayed} rows in {result.wall_time_s:.2f} s: "
              f"{comparison.identical} of {comparison.recorded_answered} recorded replies identical, "
              f"{comparison.different} different (max {comparison.max_abs_difference_C:.4f} °C), "
              f"{comparison.missing_in_replay} missing; "
              f"{recorded_rows.counts.text('compared')}")
        if faults:
            print(f"faults in the log: {', '.join(f'{k} {n}' for k, n in faults.items())}; target rejections "
                  f"recorded {recorded.rx_errors}, replayed {replayed.rx_errors}")
        print(f"new log {result.log_path}")
        print("reproduced" if reproduced else "NOT reproduced" + "".join(f"; {p}" for p in problems))
    status = 0 if reproduced else 1
    sentence = "reproduced" if reproduced else "not reproduced: " + ("; ".join(problems) or
                                                                     f"{comparison.different} rows differ")
    return finish(acceptor, acceptance, command="bench replay", subject="the replay", status=status,
                  clean=CleanCase(reproduced, sentence, tuple(problems)),
                  elapsed_s=time.perf_counter() - started, quiet=quiet,
                  properties={"model": f"{artifact.model_id:08x}", "engine": summary.engine, "bus": bus.describe(),
                              "recorded_log": str(path), "log": result.log_path},
                  attachments=[str(path), result.log_path])
