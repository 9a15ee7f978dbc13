"""Fault sweep benchmark (prints figures; not a test): every fault kind the bench knows, one `bench run` each, on
both engines, with an observer artifact that uses the new frames (issue 25: Measurements and DriveVoltages, each
node's 1-sigma and the innovations in the replies).

    python tests/benchmarks/bench_fault_sweep.py [--work DIR] [--rows N] [--engines python,firmware] [--parallel 2]
    python tests/benchmarks/bench_fault_sweep.py --quick          # a smoke run: 200 rows, one kind per family
    python tests/benchmarks/bench_fault_sweep.py --model FILE --mapping FILE --data FILE   # an artifact you have

The observer is the IPM example's model (c): the Hammerstein model from `bench identify` on profiles 1-8 with
its stator NTC (offset, lag and gradient from the motor file) and the flux linkage (`bench observer ... --flux`,
two-run tuning: the protocol matters here, not Q and R), run on the held-out profile 9. The kinds come from the
fault registry (`host.faults.spec.KINDS`): a rate per frame or row (`--rate`, default 0.02) for the bus and reply
kinds, a count (`--count`, default 1) for the process kinds (kill, freeze). Each run is
`bench run --faults KIND=V --fault-seed 3 --tolerate-faults --json` in lockstep; per run: exit status, verdict
sentence, injected and detected per kind, deadline misses (and those no injected fault explains, with the log's
evidence for each: how many of the row's sends the target answered and when the first reply came), rows, wall
time and the load average at its start and end. The sweep passes when every run exits 0 and every injected fault
was detected. Writes its record (docs/results/fault_sweep.json; see tests/benchmarks/record.py).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from record import ROOT, Record, add_record_arguments  # noqa: E402

ENGINES = ("python", "firmware")
ROWS = 1000
QUICK_ROWS = 200
RATE = 0.02
COUNT = 1
SEED = 3
PARALLEL_MAX = 2          # the machine has 2 cores: more runs at once only measures the scheduler


def fault_kinds() -> list[str]:
    """Every fault kind the bench knows, in the registry's order (the DBC's FaultKind table, then the reply kinds)."""
    sys.path.insert(0, str(ROOT))
    from host.faults.spec import KINDS

    return list(KINDS)


def quick_kinds() -> list[str]:
    """One kind of each family (frame, row, process, reply), the first the registry lists: a smoke run."""
    sys.path.insert(0, str(ROOT))
    from host.faults.spec import FRAME_KINDS, PROCESS_KINDS, REPLY_KINDS, ROW_KINDS

    return [family[0] for family in (FRAME_KINDS, ROW_KINDS, PROCESS_KINDS, REPLY_KINDS)]


def fault_argument(kind: str, rate: float, count: int) -> str:
    """`KIND=V` for --faults: a count for a process kind, a probability otherwise."""
    from host.faults.spec import PROCESS_KINDS

    return f"{kind}={count}" if kind in PROCESS_KINDS else f"{kind}={rate:g}"


def run_one(engine: str, kind: str, target: dict, work: Path, args: argparse.Namespace) -> dict:
    """One `bench run` with one fault kind: what the summary and the log say."""
    log = work / f"{engine}-{kind}.blf"
    argv = [sys.executable, "-m", "bench", "run", "--model", str(target["model"]), "--data", str(target["data"]),
            *(["--mapping", str(target["mapping"])] if target.get("mapping") else []), "--rows", str(args.rows),
            "--engine", engine, "--faults", fault_argument(kind, args.rate, args.count), "--fault-seed",
            str(args.seed), "--tolerate-faults", "--log", str(log), "--no-report", "--json",
            *(["--reply-timeout", f"{args.reply_timeout:g}"] if args.reply_timeout else [])]
    load_start = os.getloadavg()[0]
    started = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, MPLBACKEND="Agg"))
    out = {"engine": engine, "kind": kind, "fault": fault_argument(kind, args.rate, args.count),
           "exit": done.returncode, "wall_s": round(time.perf_counter() - started, 1),
           "load_average": {"start": round(load_start, 2), "end": round(os.getloadavg()[0], 2)}}
    try:
        summary = json.loads(done.stdout)
    except ValueError:
        return {**out, "verdict": None, "error": done.stderr.strip()[-400:]}
    return {**out, **run_figures(summary, log)}


def run_figures(summary: dict, log: Path | None) -> dict:
    """The figures of one run's JSON summary, and the log's evidence on its unexplained deadline misses."""
    faults = summary.get("faults") or {}
    misses = list(faults.get("unexplained_deadline_miss_rows") or [])
    return {"verdict": summary.get("verdict"), "rows": summary.get("steps_sent"), "replies": summary.get("replies"),
            "missing": summary.get("missing"), "problems": summary.get("problems") or [],
            "injected": faults.get("injected") or {}, "detected": faults.get("detected") or {},
            "deadline_misses": faults.get("deadline_misses"), "retransmitted_rows": faults.get("retransmitted_rows"),
            "late_replies": faults.get("late_replies"), "late_reply_max_ms": faults.get("late_reply_max_ms"),
            "recoveries": len(faults.get("recoveries") or []),
            "unexplained_deadline_misses": faults.get("unexplained_deadline_misses"),
            "unexplained_miss_evidence": miss_evidence(log, misses) if misses and log is not None else []}


def miss_evidence(log: Path, rows: list[int]) -> list[dict]:
    """For each row: how many complete replies (Temperatures2) the log holds for it, how many times the host sent
    it (first send and retransmitted copies), and the first reply's latency after the first send. A row the target
    answered once per send was not lost on the way: its first send reached the target, the reply came late."""
    import can

    from dbc.codec import decode_any
    from dbc.contract import FrameError

    wanted = set(rows)
    sent: Counter = Counter()
    replied: Counter = Counter()
    first_sent: dict[int, float] = {}
    first_reply: dict[int, float] = {}
    with can.BLFReader(str(log)) as reader:
        for msg in reader:
            try:
                frame = decode_any(msg)
            except FrameError:          # a faulted frame: neither a send nor a reply the host took
                continue
            step = frame.signals.get("Step")
            if step not in wanted:
                continue
            if frame.name == "DriveInputs":
                sent[step] += 1
                first_sent.setdefault(step, msg.timestamp)
            elif frame.name == "Temperatures2":
                replied[step] += 1
                first_reply.setdefault(step, msg.timestamp)
    return [{"row": row, "sends": sent[row], "replies": replied[row],
             "first_reply_ms": (round(1e3 * (first_reply[row] - first_sent[row]), 1)
                                if row in first_reply and row in first_sent else None)} for row in rows]


def passed(run: dict) -> bool:
    """Exit 0 and every injected fault detected."""
    return run["exit"] == 0 and bool(run.get("injected")) and run.get("injected") == run.get("detected")


def summarize(runs: list[dict]) -> dict:
    """Per engine: runs, exit 0, all detected, the kinds that did not pass and why; and the sweep's verdict."""
    engines = {}
    for engine in dict.fromkeys(r["engine"] for r in runs):
        mine = [r for r in runs if r["engine"] == engine]
        engines[engine] = {
            "runs": len(mine), "exit_0": sum(r["exit"] == 0 for r in mine),
            "all_detected": sum(bool(r.get("injected")) and r.get("injected") == r.get("detected") for r in mine),
            "injected": sum(sum(r.get("injected", {}).values()) for r in mine),
            "detected": sum(sum(v or 0 for v in r.get("detected", {}).values()) for r in mine),
            "failed": {r["kind"]: (r.get("problems") or [r.get("verdict") or r.get("error")])[0]
                       for r in mine if not passed(r)}}
    return {"engines": engines, "passed": all(passed(r) for r in runs),
            "unexplained_misses": sum(r.get("unexplained_deadline_misses") or 0 for r in runs)}


def sweep(target: dict, engines: list[str], kinds: list[str], work: Path, args: argparse.Namespace) -> list[dict]:
    """Every (engine, kind) run, `args.parallel` at a time, in the registry's order."""
    jobs = [(engine, kind) for engine in engines for kind in kinds]

    def one(job: tuple[str, str]) -> dict:
        run = run_one(*job, target, work, args)
        print(line(run), flush=True)
        return run

    with ThreadPoolExecutor(max_workers=args.parallel) as pool:
        return list(pool.map(one, jobs))


def line(run: dict) -> str:
    detected = run.get("detected") or {}
    injected = ", ".join(f"{k} {n}/{detected.get(k)}" for k, n in (run.get("injected") or {}).items())
    return (f"{run['engine']:8s} {run['fault']:24s} exit {run['exit']} in {run['wall_s']:.0f} s (load "
            f"{run['load_average']['start']:.1f}-{run['load_average']['end']:.1f}); injected/detected {injected or '-'}"
            f"; {run.get('verdict') or run.get('error')}")


def ipm_observer(work: Path) -> dict:
    """The IPM example's observer (c), NTC + flux linkage, built in `work` unless it is there already."""
    from bench_accuracy import HELD_OUT, IPM, bench
    from bench_observer import ipm_cases, ntc_sensor

    motor, mapping = str(IPM / "motor.json"), str(IPM / "mapping.json")
    data = work / "ipm"
    train = str(data / "profile_0[1-8].csv")
    held_out = [str(data / f) for f in HELD_OUT]
    if not (data / "model.json").is_file():
        bench("data", "--motor", motor, "--out", str(data), "--quiet")
        bench("identify", "--motor", motor, "--mapping", mapping, "--train", train, "--validate", *held_out,
              "--out", str(data / "model.json"), "--kind", "hammerstein")
    model = work / "ipm-ntc+flux-observer.json"
    if not model.is_file():
        bench("observer", "--model", str(data / "model.json"), "--train", train, "--mapping", mapping,
              *ipm_cases(ntc_sensor())["ntc+flux"], "--evaluations", "2", "--out", str(model))
    return {"model": model, "mapping": Path(mapping), "data": Path(held_out[0]),
            "observer": "IPM example (c): stator NTC + flux linkage"}


def describe(target: dict) -> dict:
    """What the record says of the artifact: its measurements and form."""
    sys.path.insert(0, str(ROOT))
    from target_sim.artifact import load_artifact

    section = load_artifact(target["model"]).content.get("observer")
    if not section:
        sys.exit(f"{target['model']} has no observer; the sweep needs an artifact that uses the measurement frames")
    return {"observer": target.get("observer") or Path(target["model"]).name,
            "measurements": [m["name"] for m in section["measurements"]], "form": section.get("form"),
            "data": Path(target["data"]).name}


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help=f"smoke run: {QUICK_ROWS} rows, one kind per family, the python engine; no record "
                             "unless --json")
    parser.add_argument("--rows", type=int, default=None, help=f"rows per run (default {ROWS})")
    parser.add_argument("--engines", default=None, help=f"comma-separated (default {','.join(ENGINES)})")
    parser.add_argument("--kinds", default=None, help="comma-separated subset of the registry's kinds (default all)")
    parser.add_argument("--rate", type=float, default=RATE, help=f"probability of a rate kind (default {RATE:g})")
    parser.add_argument("--count", type=int, default=COUNT, help=f"kills / freezes per run (default {COUNT})")
    parser.add_argument("--seed", type=int, default=SEED, help=f"--fault-seed of every run (default {SEED})")
    parser.add_argument("--reply-timeout", type=float, default=None, help="pass --reply-timeout (default: bench's)")
    parser.add_argument("--parallel", type=int, default=PARALLEL_MAX, choices=range(1, PARALLEL_MAX + 1),
                        help=f"runs at once (at most {PARALLEL_MAX}; default {PARALLEL_MAX})")
    parser.add_argument("--work", type=Path, default=None, help="keep the IPM files, the artifact and the logs here")
    parser.add_argument("--model", type=Path, default=None, help="an observer artifact instead of building (c)")
    parser.add_argument("--data", type=Path, default=None, help="its data file (with --model)")
    parser.add_argument("--mapping", type=Path, default=None, help="its mapping (with --model)")
    add_record_arguments(parser)
    args = parser.parse_args()
    if (args.model is None) != (args.data is None):
        parser.error("--model and --data go together")
    args.rows = args.rows or (QUICK_ROWS if args.quick else ROWS)
    if args.quick and args.json is None:     # a smoke run does not replace the committed record
        args.no_json = True
    return args


def main() -> int:
    args = parse_args()
    sys.path.insert(0, str(ROOT))
    from host.faults.spec import canonical_kind

    kinds = ([canonical_kind(k) for k in args.kinds.split(",")] if args.kinds else
             quick_kinds() if args.quick else fault_kinds())
    engines = args.engines.split(",") if args.engines else (["python"] if args.quick else list(ENGINES))
    if unknown := [e for e in engines if e not in ENGINES]:
        sys.exit(f"unknown engine {unknown[0]!r}; use {' or '.join(ENGINES)}")
    record = Record("fault_sweep", args, variant="quick" if args.quick else None, parameters={
        "rows": args.rows, "rate": args.rate, "count": args.count, "seed": args.seed, "engines": engines,
        "kinds": kinds, "parallel": args.parallel, "reply_timeout_s": args.reply_timeout, "mode": "lockstep"})
    with tempfile.TemporaryDirectory() as tmp:
        work = (args.work or Path(tmp)).resolve()
        work.mkdir(parents=True, exist_ok=True)
        target = ({"model": args.model.resolve(), "data": args.data.resolve(),
                   "mapping": args.mapping.resolve() if args.mapping else None} if args.model else ipm_observer(work))
        record.parameters["artifact"] = artifact = describe(target)
        print(f"fault sweep: {len(kinds)} kinds x {len(engines)} engines, {args.rows} rows, "
              f"{artifact['observer']} ({', '.join(artifact['measurements'])})")
        (work / "logs").mkdir(exist_ok=True)
        runs = sweep(target, engines, kinds, work / "logs", args)
    record.figures["runs"] = runs
    record.figures["summary"] = summary = summarize(runs)
    for engine, s in summary["engines"].items():
        print(f"{engine}: {s['exit_0']} of {s['runs']} runs exit 0, {s['all_detected']} with every fault detected "
              f"({s['detected']} of {s['injected']}); not passed: {s['failed'] or 'none'}")
    print("the sweep " + ("passes" if summary["passed"] else "does NOT pass"))
    record.write()
    return 0 if summary["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
