"""`bench compare`: the three model kinds through the CAN bench, side by side (the paper's Table 6 analogue).

    bench compare [--data FILE] [--dt 0.5] [--rows N] [--models A.json,B.json,C.json] [--out DIR]
                  [--engine firmware|python] [--json] [--quiet] [-i INTERFACE] [-c CHANNEL] [--bus-kwargs K=V ...]

Each artifact runs on its own target process in lockstep over the dataset (default the 40 °C validation run;
--rows N shortens it), and its log is analyzed like `bench run`'s. The target runs the firmware engine by default
(the model compiled for a Cortex-M4F, in the emulated core; the packaged artifacts ship their ELF, others are
built into <out>/firmware-cache with the compiler). Columns: measured step time on the target process, estimated
C28x cycles and µs at 90 MHz beside the measured Cortex-M4F cycles (p50, max) and µs at 90 MHz, CPU utilization
at Δt (C28x estimate), flash and RAM of the Cortex-M4F ELF beside the C28x estimates, RMSE of the CAN winding and
PM temperatures against the measurement (over the rows the bench's rule keeps; the JSON's "rows_excluded" counts
those a check flagged, by reason), and the agreement with the offline float32 model. With --engine python
the measured Cortex-M4F columns stay empty.
Without --models the three packaged identified artifacts are compared (LTI LPTN ZOH balanced, PV LPTN Euler,
Hammerstein balanced); at another --dt they are re-discretized from the identified parameters and the
Hammerstein model is refitted.
Exit status 0 only when every model's run is clean as `bench run` judges one: a model whose estimate the target had
to clamp (the `original` realization in float32, Fig. 6) is still in the table, and the comparison exits 1 naming
it (file, kind, realization) and its problems in one sentence.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from bench.commands.args import bus_from_args, declare_files, positive_float, positive_int
from bench.commands.common import add_engine_argument, add_output_flags, check_writable, fmt, print_json
from bench.errors import UsageError
from bench.fileio import write_text_atomically
from bench.run.inputs import load_data, load_model, refuse_over_can
from dbc.transport import add_bus_arguments
from target_sim.artifact import ModelArtifact, dumps
from target_sim.kinds import MODEL_KINDS

if TYPE_CHECKING:  # the CLI builds every subcommand's parser at start: the results when a comparison runs
    from bench.analysis.results import RunResults

KINDS = MODEL_KINDS.names()


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("compare", help="run the three model kinds through the bench (Table 6 analogue)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, default=None, help="dataset CSV (default: the 40 °C validation run)")
    p.add_argument("--dt", type=positive_float, default=0.5, help="model step of the built artifacts (default 0.5)")
    p.add_argument("--rows", type=positive_int, default=None, help="replay only the first N data rows")
    p.add_argument("--models", default=None,
                   help="comma-separated artifacts to compare instead of the built ones")
    p.add_argument("--out", type=Path, default=Path("out/compare"),
                   help="logs and built artifacts (default out/compare)")
    p.add_argument("--seed", type=int, default=None, help="seed of the generated default datasets")
    add_engine_argument(p, default="firmware")
    add_output_flags(p)
    add_bus_arguments(p)
    declare_files(p, inputs=('--data',), outputs=('--out',))
    p.set_defaults(func=run)


def build_default_artifacts(dt: float, out_dir: Path) -> list[Path]:
    """The packaged identified artifacts (LTI LPTN, PV LPTN, Hammerstein); rebuilt at another Δt if asked.

    At a Δt other than the packaged one the LTI and PV LPTN are re-discretized from the identified parameters
    and the Hammerstein model is refitted at that Δt (Levenberg-Marquardt on the default 20/60 °C datasets, as
    `bench evaluate` does).
    """
    import numpy as np

    from bench.model.artifact_values import artifact_loss_model, artifact_parameters
    from bench.model.builder import ModelSpec, build_artifact
    from bench.model.default import default_artifact_path
    from bench.model.evaluate import hammerstein_models, reference_of
    from bench.model.pipeline import load_campaign

    packaged = {kind: default_artifact_path(kind) for kind in KINDS}
    reference, _ = load_model(packaged["hammerstein"])
    if np.isclose(dt, reference.dt):
        return list(packaged.values())
    params = artifact_parameters(reference)
    maps, motor = artifact_loss_model(reference)
    note = {"derived_from": reference.sha256, "note": f"re-discretized at {dt:g} s for bench compare"}
    deployed = {"realization": reference.realization, "reference_C": reference_of(reference)}
    specs = {
        "lti-lptn": ModelSpec("lti-lptn", params, dt, "zoh", loss_maps=maps, motor=motor, provenance=note, **deployed),
        "pv-lptn": ModelSpec("pv-lptn", params, dt, "euler", "physical", maps, motor, provenance=note),
    }
    block, sigmoid = hammerstein_models(reference, load_campaign(None), [dt])[dt]
    specs["hammerstein"] = ModelSpec("hammerstein", params, dt, "zoh", loss_maps=maps, motor=motor, sigmoid=sigmoid,
                                     **deployed,
                                     linear_block=block, provenance={**note, "note": note["note"] + ", refitted"})
    paths = []
    for kind, spec in specs.items():
        path = out_dir / f"{kind}-dt{dt:g}.json"
        write_text_atomically(path, dumps(build_artifact(spec)))
        paths.append(path)
    return paths


def compare_models(model_paths: list[Path], dataset, bus, *, rows: int | None, out_dir: Path,
                   quiet: bool = True, engine: str = "firmware") -> list[dict]:
    """Run each artifact through the bench; one table row per artifact (plug identified artifacts in here)."""
    from bench.analysis.report import analyze_log
    from bench.model.artifact_eval import artifact_drive
    from bench.model.runs import initial_temperatures
    from bench.progress import ProgressBar
    from bench.run.execute import run_with_target
    from bench.run.inputs import firmware_for_engine, measurements_for
    from bench.run.leftovers import clear_and_say

    # every ELF first (built where not packaged): a missing compiler stops the comparison before any run
    loaded = [load_model(path) for path in model_paths]
    elves = [firmware_for_engine(engine, artifact, out_dir / "firmware-cache", quiet=quiet)
             for artifact, _ in loaded]
    table = []
    for (artifact, model_path), firmware in zip(loaded, elves, strict=True):
        drive = artifact_drive(artifact, dataset)[:rows] if rows else artifact_drive(artifact, dataset)
        measurements = measurements_for(dataset, artifact)   # an observer's measurement, sent in Measurements
        if measurements is not None:
            measurements = measurements[: len(drive)]
        log_path = out_dir / f"{model_path.stem}.blf"
        clear_and_say(log_path, quiet)
        bar = ProgressBar(len(drive), artifact.kind, quiet)
        try:
            outcome = run_with_target(model_path, artifact, bus, drive, initial_temperatures(dataset),
                                      sample_period_s=dataset.sample_period_s, log_path=log_path, progress=bar,
                                      firmware=firmware, measurements=measurements)
        finally:
            bar.close()
        results, found = analyze_log(log_path, artifact, dataset, bitrate=bus.nominal_bitrate, xcp_elf=firmware)
        # the host and the log analysis may both see one problem (a clamped value): report it once
        table.append(table_row(artifact, model_path, results, list(dict.fromkeys(outcome.result.problems() + found))))
    return table


def table_row(artifact: ModelArtifact, path: Path, m: RunResults, found: list[str]) -> dict:
    timing, memory, accuracy = m.timing, m.memory, m.accuracy
    firmware = timing.engine == "firmware"
    return {
        "model": str(path), "kind": artifact.kind, "realization": artifact.realization, "dt_s": artifact.dt,
        "model_id": f"{artifact.model_id:08x}", "steps": m.counts.steps_sent, "model_steps": m.counts.model_steps,
        "missing": m.counts.missing,
        "measured_step_us_p50": timing.step_time_us.p50, "measured_step_us_p99": timing.step_time_us.p99,
        "est_cycles": timing.est_cycles, "est_exec_us_90MHz": timing.est_exec_time_us,
        "m4_cycles_p50": timing.m4_cycles and timing.m4_cycles.p50,
        "m4_cycles_max": timing.m4_cycles and timing.m4_cycles.max,
        "m4_exec_us_90MHz": timing.m4_exec_time_us and timing.m4_exec_time_us.p50,
        "cpu_load_percent": timing.cpu_load_percent, "engine": timing.engine,
        "est_flash_bytes": memory.est_flash_bytes, "est_ram_bytes": memory.est_ram_bytes,
        "m4_flash_bytes": memory.flash_bytes if firmware else None,
        "m4_ram_bytes": memory.ram_bytes if firmware else None,
        # what TargetInfo carried: the ELF's figures with the firmware engine, else the estimate
        "flash_bytes": memory.flash_bytes, "ram_bytes": memory.ram_bytes,
        "rmse_winding_C": accuracy.rmse_C.winding, "rmse_magnet_C": accuracy.rmse_C.magnet,
        "rmse_reference": accuracy.rmse_reference.winding,
        # the rows those figures are over, and those a check flagged as not the target's own answer (by reason)
        "rows_kept": m.figure_rows.kept, "rows_excluded": m.figure_rows.excluded,
        "figure_rows": m.figure_rows.text(),
        "max_abs_can_minus_float32_C": m.agreement.max_abs_can_minus_float32_C.worst(),
        "max_abs_float32_minus_float64_C": accuracy.max_abs_float32_minus_float64_C.worst(),
        "throughput_steps_per_s": m.throughput.throughput_steps_per_s, "problems": found, "notes": m.notes,
    }


def _kb(value) -> str:
    return "–" if value is None else fmt(value / 1024, 2)


def print_table(table: list[dict]) -> None:
    header = (f"{'kind':12} {'realization':11} {'step µs':>8} {'C28x cyc':>8} {'C28x µs':>7} {'M4 cyc':>6} "
              f"{'M4 max':>6} {'M4 µs':>6} {'CPU %':>7} {'flash kB':>8} {'M4 flash':>8} {'RAM kB':>6} "
              f"{'M4 RAM':>6} {'RMSE w':>7} {'RMSE PM':>7} {'|CAN-f32|':>9} {'missing':>7}")
    print(header)
    for r in table:
        print(f"{r['kind']:12} {r['realization']:11} {fmt(r['measured_step_us_p50'], 1):>8} "
              f"{r['est_cycles'] if r['est_cycles'] is not None else '–':>8} {fmt(r['est_exec_us_90MHz'], 1):>7} "
              f"{fmt(r['m4_cycles_p50'], 0):>6} {fmt(r['m4_cycles_max'], 0):>6} {fmt(r['m4_exec_us_90MHz'], 1):>6} "
              f"{fmt(r['cpu_load_percent'], 4):>7} {_kb(r['est_flash_bytes']):>8} {_kb(r['m4_flash_bytes']):>8} "
              f"{_kb(r['est_ram_bytes']):>6} {_kb(r['m4_ram_bytes']):>6} {fmt(r['rmse_winding_C'], 3):>7} "
              f"{fmt(r['rmse_magnet_C'], 3):>7} {fmt(r['max_abs_can_minus_float32_C'], 4):>9} {r['missing']:>7}")
    print("step µs: measured p50 wall time of a step on the target process (Python or emulated); C28x cyc, "
          "C28x µs (at 90 MHz), CPU %, flash kB, RAM kB: the C28x cost-table estimate; M4 cyc (p50), M4 max, "
          "M4 µs (at 90 MHz), M4 flash, M4 RAM: "
          "measured on the Cortex-M4F firmware in the emulated core and its ELF (firmware engine); RMSE against "
          + (table[0]["rmse_reference"] if table else "measured") + " (°C).")
    for r in table:
        if r["rows_excluded"]:
            print(f"{r['kind']} ({r['realization']}): {r['figure_rows']}")


def run(args: argparse.Namespace) -> int:
    quiet = args.quiet or args.json
    check_writable(args.out, "--out", directory=True)
    if args.models:
        paths = [Path(p.strip()) for p in args.models.split(",") if p.strip()]
        if not paths:
            raise UsageError("--models needs comma-separated artifact files")
    else:
        paths = build_default_artifacts(args.dt, args.out)
    # every artifact is checked before the first run, so a bad one leaves no logs of the others behind
    artifacts = [load_model(path)[0] for path in paths]
    for artifact in artifacts:   # an observer whose readings no frame carries
        refuse_over_can(artifact)
    dataset = load_data(args.data, artifacts[0], args.seed, quiet=quiet)
    bus = bus_from_args(args)
    table = compare_models(paths, dataset, bus, rows=args.rows, out_dir=args.out, quiet=quiet, engine=args.engine)
    if args.json:
        print_json({"data": str(dataset.path), "rows": args.rows, "models": table})
    else:
        print_table(table)
    bad = [f"{Path(r['model']).name} ({r['kind']}, {r['realization']}): {'; '.join(r['problems'])}"
           for r in table if r["problems"]]
    if bad:
        print("bench: error: not clean: " + " | ".join(bad), file=sys.stderr)
        return 1
    return 0



