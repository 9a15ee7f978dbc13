"""The estimator beside the motor control, benchmarked (prints figures; not a test): per packaged kind, the model's
own flash, the WCET bounds against the measured maxima, the model step's response time at 10 and 20 kHz, the
current loop's latency with and without the estimator running, the CPU load by task at 90 and 168 MHz; then the
lockstep throughput of `bench run --engine firmware` without and with the interrupt.

    python tests/benchmarks/bench_firmware_timing.py [--rows N] [--search N] [--lockstep-rows N] [--repeats R]
                                                     [--skip-lockstep] [--skip-observer]

1. Per packaged kind: its model compiled (the shipped ELF's sources): fw_model.o's code and constants from the
   linker map against the paper's 10.13 kB; the timing image (`build_firmware(isr=True)`) and
   `bench.firmware.timing.timing_report` over the first N rows (default 200) of the 40 °C run at 10 and at
   20 kHz: IPET bounds (fw_step, node_on_frame with rows in order, foc_isr) beside the measured maxima of the
   drive and of an input search (`--search` candidates, bench/firmware/adversarial.py) and their ratio, the
   response time (a row's arrival to its temperatures queued) p50/p99/max, node_on_frame's bound with an XCP
   master running the DAQ tables' whole budget beside a drive under that DAQ (`bench.firmware.timing.XCP_MODES`:
   the first bounds are without a master, as the drive runs), the interrupt's latency when it finds
   the core idle (the estimator not running) and when it preempts the node, and the CPU load by task, each at 90
   and 168 MHz; the outputs bit for bit against the node without the interrupt.
   Then an observer of the Hammerstein model's winding node (`bench observer` on the 20 °C run), through
   `bench firmware timing` as a user runs it: fw_obs_step's bound and maxima, node_on_frame's and the handler's.
2. Lockstep `bench run --engine firmware` on the first M rows (default 3000) of the default run: the shipped image
   without the interrupt, the timing image at 10 and at 20 kHz, alternating (R runs each, default 2), rows/s as the
   host measures the replay, every run clean (CAN values bit-equal to the float32 reference); and the firmware
   node alone (no bus) over the same rows, rows per CPU second, which a shared machine's load does not change.
Writes its record (`tests/benchmarks/record.py`).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from record import Record, add_record_arguments  # noqa: E402

from bench.drive.dataset import load_dataset  # noqa: E402
from bench.drive.generate import ensure_default_datasets  # noqa: E402
from bench.firmware.codegen import generate  # noqa: E402
from bench.firmware.images import PACKAGED_KINDS, firmware_for, packaged_elf_path  # noqa: E402
from bench.firmware.timing import timing_report  # noqa: E402
from bench.firmware.toolchain import build_firmware  # noqa: E402
from bench.model.default import default_artifact_path  # noqa: E402
from bench.model.runs import drive_matrix, initial_temperatures  # noqa: E402
from target_sim.artifact import load_artifact  # noqa: E402
from target_sim.firmware import read_elf  # noqa: E402

RATES_HZ = (10_000, 20_000)
TRAIN_ROWS = 3000          # the observer's training rows (its tuning changes no cycle count)
PAPER_MODEL_FLASH_BYTES = 10_130


def _run_figures(run: dict) -> dict:
    keep = ("response_time_us", "isr_latency_cycles", "isr_latency_idle_cycles", "isr_latency_preempting_cycles",
            "isr_wait_caused_by_background_cycles", "isr_lazy_fp_stacking", "cpu_load", "bit_exact",
            "model_steps", "isr_events")
    return {key: run[key] for key in keep}


def _print_wcet(rate: int, table: dict, with_daq: dict) -> None:
    for name, row in table.items():
        print(f"  {rate} Hz {name}: IPET bound {row['bound']}, measured max: drive {row['drive_max']}, input "
              f"search {row['adversarial_max']}; bound / max {row['bound_over_max']}")
    row = with_daq["node_on_frame"]
    print(f"  {rate} Hz node_on_frame with {with_daq['description']}: IPET bound {row['bound']}, measured max "
          f"{row['measured_max']} ({with_daq['daq_packets']} DAQ packets); bound / max {row['bound_over_max']}")


def observer_figures(work: Path, dataset, rows: int, search: int) -> dict:
    """`bench firmware timing` of an observer of the packaged Hammerstein model's winding node (`bench observer`
    on the first TRAIN_ROWS rows of the 20 °C run, a two-run tuning: its Q and R change no cycle count), as a user
    runs it: the observer's model step (fw_obs_step) bounded and searched beside node_on_frame and the handler."""
    from bench_accuracy import bench

    from bench.drive.generate import ensure_default_datasets

    lines = ensure_default_datasets(dataset.path.parent)[20].read_text(encoding="utf-8").splitlines()
    train = work / "train.csv"                 # a user's CSV: the header and the first TRAIN_ROWS rows
    train.write_text("\n".join(lines[: TRAIN_ROWS + 1]) + "\n", encoding="utf-8")
    model = work / "observer.json"
    bench("observer", "--train", str(train), "--evaluations", "2", "--out", str(model))
    out = {"case": "winding sensor observer (hammerstein)"}
    for rate in RATES_HZ:
        report, seconds = bench("firmware", "timing", "--model", str(model), "--data", str(dataset.path), "--rows",
                                str(rows), "--isr-rate", str(rate), "--search", str(search), "--out",
                                str(work / "cache"))
        out[str(rate)] = {"wcet": report["wcet"], "wcet_with_xcp_daq": report["wcet_with_xcp_daq"],
                          "wcet_holds": report["wcet_holds"], "bit_exact": report["bit_exact"],
                          "seconds": round(seconds, 1)}
        print(f"\nobserver at {rate} Hz ({seconds:.0f} s):")
        _print_wcet(rate, report["wcet"], report["wcet_with_xcp_daq"])
    return out


def kind_figures(kind: str, drive, initial, search: int) -> dict:
    artifact = load_artifact(default_artifact_path(kind))
    generated = generate(artifact)
    flash = build_firmware(generated).model_flash
    image = read_elf(build_firmware(generated, isr=True).elf)
    out = {"kind": kind, "model_flash": flash, "rates": {}}
    print(f"\n{kind}: fw_model.o {flash['bytes']} B (code {flash['code']}, constants {flash['constants']}; "
          f"the paper's {PAPER_MODEL_FLASH_BYTES} B)")
    for rate in RATES_HZ:
        report = timing_report(artifact, image, drive, initial, isr_rate_hz=rate, search=search)
        out["rates"][str(rate)] = {
            "wcet": report["wcet"], "wcet_cycles": report["wcet_cycles"],
            "measured_max_cycles": report["measured_max_cycles"], "wcet_with_xcp_daq": report["wcet_with_xcp_daq"],
            "wcet_holds": report["wcet_holds"], "bit_exact": report["bit_exact"],
            "runs": {clock: _run_figures(run) for clock, run in report["runs"].items()}}
        _print_wcet(rate, report["wcet"], report["wcet_with_xcp_daq"])
        for clock, run in report["runs"].items():
            r, idle, busy = run["response_time_us"], run["isr_latency_idle_cycles"], \
                run["isr_latency_preempting_cycles"]
            load = run["cpu_load"]
            print(f"  {rate} Hz at {clock}: response p50/p99/max {r['p50']}/{r['p99']}/{r['max']} µs; latency "
                  f"idle max {idle['max']}, preempting p50/max {busy['p50']}/{busy['max']} cycles; load: current "
                  f"loop {100 * load['current_loop_isr']:.2f} %, model step {100 * load['model_step']:.4f} %, "
                  f"frames {100 * load['frame_handling']:.4f} %; bit exact {run['bit_exact']}")
    return out


def node_throughput(dataset, rows: int) -> dict:
    """Rows per CPU second of the firmware node alone (FirmwareNode.handle, no bus), without and with the interrupt:
    the emulation's own cost, CPU time so the machine's load does not enter (a shared machine's wall clock does)."""
    import time

    from bench.firmware.timing import _frames
    from target_sim.firmware.node_engine import FirmwareNode

    artifact = load_artifact(default_artifact_path())
    drive = drive_matrix(dataset)[:rows]
    frames = _frames(artifact, drive, initial_temperatures(dataset))
    out = {}
    with tempfile.TemporaryDirectory(prefix="bench-fw-node-") as tmp:
        timing_elf = firmware_for(artifact, Path(tmp), isr=True)
        for rate in (0, *RATES_HZ):
            clock = [0.0]
            node = FirmwareNode(artifact, timing_elf if rate else packaged_elf_path("hammerstein"), isr_rate_hz=rate,
                                clock_s=lambda clock=clock: clock[0])
            started = time.process_time()
            for index, group in enumerate(frames):
                for position, frame in enumerate(group):
                    clock[0] = 0.2 * index + 250e-6 * position + 7e-6 * (index % 13)
                    node.handle(frame)
            cpu = time.process_time() - started
            out["no interrupt" if not rate else f"{rate} Hz"] = round(len(drive) / cpu)
            print(f"  node alone, {'no interrupt' if not rate else f'{rate} Hz'}: {len(drive) / cpu:.0f} rows per "
                  "CPU second")
    return {"rows": len(drive), "rows_per_cpu_s": out}


def lockstep(dataset, rows: int, repeats: int) -> dict:
    from bench.run.execute import run_with_target
    from dbc.transport import BusConfig, resolve

    artifact_path = default_artifact_path()
    artifact = load_artifact(artifact_path)
    drive = drive_matrix(dataset)[:rows]
    print(f"\nlockstep bench run --engine firmware, {len(drive)} rows, load average {os.getloadavg()[0]:.2f}")
    variants = {"no interrupt": 0, **{f"{rate} Hz": rate for rate in RATES_HZ}}
    rates: dict[str, list[float]] = {name: [] for name in variants}
    clean: dict[str, bool] = dict.fromkeys(variants, True)
    with tempfile.TemporaryDirectory(prefix="bench-fw-timing-") as tmp:
        for repeat in range(repeats):
            order = list(variants) if repeat % 2 == 0 else list(reversed(variants))
            for name in order:
                rate = variants[name]
                firmware = firmware_for(artifact, Path(tmp), isr=True) if rate else packaged_elf_path("hammerstein")
                bus = resolve(BusConfig("auto"), session_unique=True)
                outcome = run_with_target(artifact_path, artifact, bus, drive, initial_temperatures(dataset),
                                          sample_period_s=dataset.sample_period_s,
                                          log_path=Path(tmp) / f"{rate}-{repeat}.blf", firmware=firmware,
                                          isr_rate_hz=rate)
                r = outcome.result
                rates[name].append(r.rows_per_s)
                clean[name] = clean[name] and not r.problems()
                print(f"  {name:12} run {repeat + 1}: {r.rows_per_s:.0f} rows/s, missing {r.missing}, problems "
                      f"{r.problems() or 'none'} (load {os.getloadavg()[0]:.2f})")
    return {"rows": len(drive), "rows_per_s": {k: [round(v) for v in values] for k, values in rates.items()},
            "median_rows_per_s": {k: round(statistics.median(v)) for k, v in rates.items()}, "clean": clean}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=200, help="rows of the timing runs (default 200)")
    parser.add_argument("--lockstep-rows", type=int, default=3000, help="rows of the lockstep runs (default 3000)")
    parser.add_argument("--repeats", type=int, default=2, help="lockstep runs per variant (default 2)")
    parser.add_argument("--skip-lockstep", action="store_true")
    parser.add_argument("--search", type=int, default=64, help="input-search candidates per image (default 64)")
    parser.add_argument("--skip-observer", action="store_true")
    parser.add_argument("--data", type=Path, default=ROOT / "out" / "data")
    add_record_arguments(parser)
    args = parser.parse_args()
    record = Record("firmware_timing", args, parameters={
        "rows": args.rows, "lockstep_rows": args.lockstep_rows, "repeats": args.repeats, "rates_hz": list(RATES_HZ),
        "paper_model_flash_bytes": PAPER_MODEL_FLASH_BYTES, "search": args.search})
    dataset = load_dataset(ensure_default_datasets(args.data)[40])
    drive, initial = drive_matrix(dataset)[: args.rows], initial_temperatures(dataset)
    record.figures["kinds"] = [kind_figures(kind, drive, initial, args.search) for kind in PACKAGED_KINDS]
    if not args.skip_observer:
        with tempfile.TemporaryDirectory(prefix="bench-fw-observer-") as tmp:
            record.figures["observer"] = observer_figures(Path(tmp), dataset, args.rows, args.search)
    if not args.skip_lockstep:
        record.figures["node_throughput"] = node_throughput(dataset, args.lockstep_rows)
        record.figures["lockstep"] = lockstep(dataset, args.lockstep_rows, args.repeats)
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
