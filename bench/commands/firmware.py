"""`bench firmware`: the model as compiled firmware for a Cortex-M4F.

    bench firmware export [--model A] [--out DIR]           portable C99: the model (fw_model.h/.c) and the CAN node
    bench firmware build  [--model A] [--out DIR] [--json]  that C + start-up code + linker script -> firmware.elf,
                                                             firmware.map, and its flash and RAM figures
    bench firmware check  [--model A] [--data F] [--firmware ELF] [--rows N] [--json]
                          the whole validation run through the emulated firmware and through the Python float32
                          reference, every output compared bit for bit; cycles, flash, RAM; exit 1 on a mismatch
    bench firmware a2l    [--model A] [--elf ELF] --out FILE [--json]
                          the A2L an XCP master (pyxcp, CANape, INCA) measures and calibrates the target with
    bench firmware timing [--model A] [--isr-rate HZ] [--rows N] [--search N] [--json]
                          the node and model beside a field-oriented current loop interrupt: response time,
                          interrupt latency and jitter, CPU load by task, WCET bounds (IPET) vs the drive's and an
                          input search's measured maxima

The generated C equals the Python float32 reference bit for bit (bench/firmware/codegen.py); `build` needs the
ziglang package (a dependency), and so does `check` of an artifact other than the packaged ones (which
ship their ELF) unless --firmware names one.
"""
# Each action is an `_add_<action>(actions)` that registers its parser and sets `func`; ACTIONS lists them in the
# order `bench firmware --help` shows them (a new action, e.g. `check`, is one function and one entry).

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.commands.args import declare_files, non_negative_int, positive_int
from bench.commands.common import add_data_arguments, add_output_flags, check_writable, print_json
from bench.errors import BenchError, UsageError

SEARCH_EVALUATIONS = 32     # `timing --search`: a few seconds of emulation per image

DEFAULT_OUT = Path("out/firmware")


def add_subparser(subparsers) -> None:
    p = subparsers.add_parser("firmware", help="the model as C firmware for a Cortex-M4F (export, build, check)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    actions = p.add_subparsers(title="actions", dest="action", parser_class=type(p))
    for add in ACTIONS.values():
        add(actions)
    p.set_defaults(func=_no_action)


def _no_action(_args: argparse.Namespace) -> int:
    raise UsageError(f"'bench firmware' needs an action, one of {', '.join(ACTIONS)} "
                     "(see 'bench firmware --help')")


def _common(p: argparse.ArgumentParser, out_help: str) -> None:
    p.add_argument("--model", type=Path, default=None, help="model artifact (default: the packaged hammerstein one)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"{out_help} (default {DEFAULT_OUT})")
    add_output_flags(p)


def _add_export(actions) -> None:
    p = actions.add_parser("export", help="write the artifact's model and the CAN node as portable C99 "
                                          "(fw_model.c, node.c, ...)",
                           description="Write the model of an artifact as portable C99: fw_model.h (the API) and "
                                       "fw_model.c (coefficients, state, step), the same computation as the "
                                       "Python float32 reference, operation for operation.")
    _common(p, "directory for fw_model.h and fw_model.c")
    declare_files(p, inputs=('--model',), outputs=('--out',))
    p.set_defaults(func=run_export)


def _add_build(actions) -> None:
    p = actions.add_parser("build", help="compile the model for a Cortex-M4F: firmware.elf, firmware.map, sizes",
                           description="Generate the C of an artifact's model and cross-compile it with the start-up "
                                       "code for a Cortex-M4F (256 kB flash, 64 kB RAM): firmware.elf and "
                                       "firmware.map, with the sources, in --out; flash and RAM from the ELF.")
    _common(p, "directory for firmware.elf, firmware.map and the sources")
    declare_files(p, inputs=('--model',), outputs=('--out',))
    p.set_defaults(func=run_build)


def _add_check(actions) -> None:
    p = actions.add_parser("check", help="run the validation data through the emulated firmware and the Python "
                                         "float32 reference: bit for bit, cycles, flash, RAM",
                           description="Run a whole dataset (default: the 40 °C validation run in out/data, "
                                       "generated if missing) through the model firmware in the emulated "
                                       "Cortex-M4F and through the Python float32 reference, as the target does "
                                       "(interval means, then a model step), and compare every output bit for "
                                       "bit. A model with an observer ('bench observer') steps through its filter "
                                       "with the data's measured column, and each node's 1-sigma and the "
                                       "innovation are compared too. Reports the counted Cortex-M4 cycles per step "
                                       "(p50, max), the ELF's flash and RAM and the emulated steps per second; exit "
                                       "1 on any mismatch.")
    p.add_argument("--model", type=Path, default=None, help="model artifact (default: the packaged hammerstein one)")
    p.add_argument("--data", type=Path, default=None,
                   help="dataset CSV (default: the 40 °C validation run in out/data, generated if missing)")
    p.add_argument("--firmware", type=Path, default=None, metavar="ELF",
                   help="the model's firmware ELF (default: the packaged one, or built with the compiler)")
    p.add_argument("--rows", type=positive_int, default=None, help="only the first N data rows")
    p.add_argument("--seed", type=int, default=None, help="seed of the generated default datasets")
    add_data_arguments(p)
    add_output_flags(p)
    declare_files(p, inputs=('--model', '--data', '--firmware'))
    p.set_defaults(func=run_check)


def _add_timing(actions) -> None:
    p = actions.add_parser("timing", help="the estimator beside a field-oriented current loop interrupt: response "
                                          "time, interrupt latency, CPU load, WCET bounds",
                           description="Build the node and the model with a field-oriented current loop in a "
                                       "periodic interrupt (bench/firmware/foc_isr.c), run a drive's frames through "
                                       "it in the emulated Cortex-M4F with the interrupt preempting (at 90 and "
                                       "168 MHz) and report the model step's response time, the interrupt's "
                                       "latency and jitter, the CPU load by task, and static WCET bounds (IPET) "
                                       "of the model step, node_on_frame and the handler beside the drive's and "
                                       "an input search's measured maxima; exit 1 "
                                       "if a measured maximum exceeds its bound or an output differs from the "
                                       "run without the interrupt.")
    p.add_argument("--model", type=Path, default=None, help="model artifact (default: the packaged hammerstein one)")
    p.add_argument("--isr-rate", type=positive_int, default=10_000, metavar="HZ",
                   help="the current loop's interrupt rate in Hz (default 10000; inverters run 5000-20000)")
    p.add_argument("--data", type=Path, default=None,
                   help="dataset CSV (default: the 40 °C validation run in out/data, generated if missing)")
    p.add_argument("--rows", type=positive_int, default=200, help="data rows to run (default 200)")
    p.add_argument("--seed", type=int, default=None, help="seed of the generated default datasets")
    p.add_argument("--search", type=non_negative_int, default=SEARCH_EVALUATIONS, metavar="N",
                   help="candidates of the search for the inputs that take the most cycles (the model step; half "
                        f"as many runs of frames for node_on_frame), beside the drive's maximum (default "
                        f"{SEARCH_EVALUATIONS}; 0: no search)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT / "cache",
                   help=f"cache directory for the built timing image (default {DEFAULT_OUT / 'cache'})")
    add_data_arguments(p)
    add_output_flags(p)
    declare_files(p, inputs=('--model', '--data'), outputs=('--out',))
    p.set_defaults(func=run_timing)


def _add_a2l(actions) -> None:
    p = actions.add_parser("a2l", help="the A2L (ASAM MCD-2 MC) an XCP master measures and calibrates the target "
                                       "with",
                           description="Write the A2L of an artifact's target: a MEASUREMENT per state, temperature "
                                       "and observer value, a CHARACTERISTIC per calibratable parameter (with its "
                                       "limits), the XCP-on-CAN IF_DATA with the ids of dbc/xcp.toml. With --elf the "
                                       "addresses are the firmware ELF's symbols (and its DWARF, if any, must type "
                                       "them float); start the Python target with the same ELF (python -m "
                                       "target_sim --xcp-elf ELF) and the A2L fits it address for address.")
    p.add_argument("--model", type=Path, default=None, help="model artifact (default: the packaged hammerstein one)")
    p.add_argument("--elf", type=Path, default=None, metavar="ELF",
                   help="the model's firmware ELF whose symbols place the cells (default: the slave's own pages)")
    p.add_argument("--out", type=Path, required=True, help="the A2L file to write")
    add_output_flags(p)
    declare_files(p, inputs=('--model', '--elf'), outputs=('--out',))
    p.set_defaults(func=run_a2l)


ACTIONS = {"export": _add_export, "build": _add_build, "check": _add_check, "timing": _add_timing, "a2l": _add_a2l}


# ------------------------------------------------------------------------------------------------ helpers


def _load(model: Path | None):
    from bench.model.default import default_artifact_path
    from bench.run.inputs import refuse_engine
    from target_sim.artifact import load_artifact

    path = model or default_artifact_path()
    artifact = load_artifact(path)
    refuse_engine("firmware", artifact)   # what the generated C lacks, in bench run --engine firmware's sentence
    return path, artifact


def _check_out(out: Path, replaceable: tuple[str, ...]) -> None:
    from bench.fileio import foreign_entries

    check_writable(out, "--out", directory=True)
    foreign = foreign_entries(out, replaceable)
    if foreign:
        shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise BenchError(f"--out {out} already holds {shown}, which 'bench firmware' did not write; choose a new or "
                         "empty directory (an earlier firmware output there is replaced)")


def _write(out: Path, contents: dict[str, bytes], replaceable: tuple[str, ...]) -> None:
    from bench.fileio import write_directory_atomically

    try:
        write_directory_atomically(out, contents, replaceable=replaceable)
    except FileExistsError as exc:     # the directory changed since _check_out
        raise BenchError(f"--out {exc}; choose a new or empty directory") from None


def _identity(path: Path, artifact) -> dict:
    return {"model": str(path), "sha256": artifact.sha256, "kind": artifact.kind,
            "realization": artifact.realization, "dt_s": artifact.dt}


def _output_names() -> tuple[str, ...]:
    from bench.firmware import toolchain
    from bench.firmware.nodegen import CONFIG_NAME, PACKERS

    return (toolchain.HEADER_NAME, toolchain.SOURCE_NAME, CONFIG_NAME, *PACKERS, *toolchain.SUPPORT_FILES,
            toolchain.ELF_NAME, toolchain.MAP_NAME)


# ------------------------------------------------------------------------------------------------ actions


def run_export(args: argparse.Namespace) -> int:
    from bench.firmware.codegen import generate

    path, artifact = _load(args.model)
    names = _output_names()
    _check_out(args.out, names)
    from bench.firmware.toolchain import firmware_sources

    sources = firmware_sources(generate(artifact))     # the generated files and node.c, startup.c, firmware.ld
    _write(args.out, {name: text.encode("utf-8") for name, text in sources.items()}, names)
    report = {**_identity(path, artifact), "out": str(args.out), "files": sorted(sources)}
    if args.json:
        print_json(report)
    else:
        print(f"wrote {', '.join(str(args.out / name) for name in sorted(sources))} "
              f"({artifact.kind}, {artifact.realization} realization, dt {artifact.dt:g} s)")
    return 0


def run_build(args: argparse.Namespace) -> int:
    from bench.firmware.codegen import generate
    from bench.firmware.toolchain import ELF_NAME, MAP_NAME, SOURCE_NAME, build_firmware
    from bench.progress import StepBar

    path, artifact = _load(args.model)
    names = _output_names()
    _check_out(args.out, names)
    generated = generate(artifact)
    quiet = args.quiet or args.json
    if not quiet:
        print(f"compiling the {artifact.kind} model for the Cortex-M4F ...", file=sys.stderr)
    bar = StepBar(f"firmware {artifact.kind}", quiet)    # the compiler tells no progress: its steps, their time
    try:
        result = build_firmware(generated, on_step=bar)
    finally:
        bar.close()
    _write(args.out, result.files, names)
    memory = result.memory
    report = {**_identity(path, artifact), "out": str(args.out), "elf": str(args.out / ELF_NAME),
              "map": str(args.out / MAP_NAME), "elf_sha256": result.elf_sha256, "toolchain": result.toolchain,
              "flash_bytes": memory["flash_bytes"], "ram_bytes": memory["ram_bytes"],
              "stack_bytes": memory["stack_bytes"], "sections": memory["sections"],
              "model_flash": result.model_flash}
    if args.json:
        print_json(report)
    else:
        print(f"wrote {report['elf']} and {report['map']} ({artifact.kind}, {artifact.realization} realization, "
              f"dt {artifact.dt:g} s; {result.toolchain})")
        for name, size in memory["sections"].items():
            print(f"  {name:12} {size:7d} bytes")
        print(f"flash {memory['flash_bytes']} bytes (of 256 kB), RAM {memory['ram_bytes']} bytes (of 64 kB, "
              f"{memory['stack_bytes']} of them stack)")
        model = result.model_flash
        print(f"the model's own flash ({SOURCE_NAME.replace('.c', '.o')}): {model['bytes']} bytes (code "
              f"{model['code']}, constants {model['constants']})")
    return 0


def run_check(args: argparse.Namespace) -> int:
    from bench.commands.common import data_options
    from bench.fileio import scratch_dir
    from bench.firmware.check import check_firmware
    from bench.firmware.images import firmware_for
    from bench.model.runs import initial_temperatures
    from bench.progress import ProgressBar
    from bench.run.inputs import check_measurement_data, drive_for, load_data, measurements_for
    from target_sim.observer.node import raw_channels, raw_sources

    path, artifact = _load(args.model)
    mapping, period = data_options(args)
    dataset = load_data(args.data, artifact, args.seed, quiet=args.quiet or args.json, mapping=mapping,
                        sample_period_s=period)
    drive = drive_for(dataset, artifact)   # with the d/q currents for an electrical loss model
    check_measurement_data(dataset, artifact)
    # an observer's raw channels per row, as the target gets them: the host's measurement channels and the row's own
    # values (the flux linkage's currents)
    host = measurements_for(dataset, artifact)
    measurement = raw_channels(raw_sources(artifact), drive, host) if host is not None else None
    if args.rows is not None:
        drive = drive[: args.rows]
        measurement = measurement[: args.rows] if measurement is not None else None
    with scratch_dir("firmware-check") as cache:
        elf = args.firmware or firmware_for(artifact, Path(cache), quiet=args.quiet or args.json)
        bar = ProgressBar(len(drive), "firmware check", quiet=args.quiet or args.json)
        try:
            result = check_firmware(artifact, elf, drive, initial_temperatures(dataset), measurement, bar)
        finally:
            bar.close()
    report = {**_identity(path, artifact), "data": str(dataset.path), "firmware": str(elf), **result}
    if args.json:
        print_json(report)
    else:
        cycles = result["cycles"]
        print(f"{artifact.kind} ({artifact.realization}, dt {artifact.dt:g} s), {result['rows']} rows of "
              f"{dataset.path}: {result['steps']} model steps through {elf}")
        if result["observer"]:
            from target_sim.observer import measurement_entries

            names = [entry["name"] for entry in measurement_entries(artifact.content["observer"])]
            used = ", ".join(f"{name} {n}" for name, n in zip(names, result["updates_per_measurement"], strict=True))
            print(f"observer ({', '.join(names)}): {result['updates']} of {result['steps']} steps updated "
                  f"with a measurement ({used}); outputs, each node's 1-sigma, each innovation and the checkpoint "
                  "compared")
        print(f"mismatches {result['mismatches']} (firmware vs Python float32 reference, bit for bit); Cortex-M4 "
              f"cycles per step p50 {cycles['p50']}, max {cycles['max']} ({result['exec_us_at_90MHz']['p50']} µs "
              f"at 90 MHz); flash {result['flash_bytes']} B, RAM {result['ram_bytes']} B (stack used "
              f"{result['stack_used_bytes']} B); {result['emulated_steps_per_s']:.0f} emulated steps/s")
    if result["mismatches"]:
        first = result["first_mismatch"]
        print(f"bench: error: the firmware differs from the Python float32 reference in {result['mismatches']} of "
              f"{result['steps']} model steps, first at step {first['step']} (row {first['row']}); regenerate the "
              "firmware from this artifact ('bench firmware build') or report the generator bug", file=sys.stderr)
        return 1
    return 0


def run_timing(args: argparse.Namespace) -> int:
    from bench.commands.common import data_options
    from bench.firmware.images import firmware_for
    from bench.firmware.timing import CLOCKS_MHZ, static_bounds, timing_report
    from bench.model.runs import initial_temperatures
    from bench.run.inputs import check_measurement_data, drive_for, load_data, measurements_for
    from target_sim.firmware import read_elf
    from target_sim.firmware.motor_control import isr_rate_problem

    if problem := isr_rate_problem(args.isr_rate):   # before the build: what the arguments alone refuse
        raise UsageError(problem)
    path, artifact = _load(args.model)
    check_writable(args.out, "--out", directory=True)
    elf = firmware_for(artifact, args.out, quiet=args.quiet or args.json, isr=True)
    image = read_elf(elf)
    handler = static_bounds(image, artifact)["foc_isr"] + 60     # + entry, return and lazy FP stacking (< 60 cycles)
    slowest = min(CLOCKS_MHZ) * 1e6
    if args.isr_rate * handler >= slowest / 2:
        raise UsageError(f"--isr-rate {args.isr_rate} leaves the background no time: the current loop's bound of "
                         f"{handler} cycles with its exception overhead allows at most "
                         f"{int(slowest / 2 / handler)} Hz at {min(CLOCKS_MHZ)} MHz (half the core)")
    mapping, period = data_options(args)
    dataset = load_data(args.data, artifact, args.seed, quiet=args.quiet or args.json, mapping=mapping,
                        sample_period_s=period)
    drive = drive_for(dataset, artifact)
    check_measurement_data(dataset, artifact)
    host = measurements_for(dataset, artifact)      # an observer's host channels per row, as `bench run` sends
    measurement = host[: args.rows] if host is not None else None     # the host's channels: its frames
    drive = drive[: args.rows]
    report = {**_identity(path, artifact), "data": str(dataset.path), "rows": int(len(drive)), "firmware": str(elf),
              **timing_report(artifact, image, drive, initial_temperatures(dataset), isr_rate_hz=args.isr_rate,
                              search=args.search, measurement=measurement)}
    if args.json:
        print_json(report)
    else:
        _print_timing(report)
    failed = [] if report["bit_exact"] else ["the model's outputs differ from the run without the interrupt"]
    failed += [f"{name} measured {report['measured_max_cycles'][name]} cycles, above its static bound "
               f"{bound}" for name, bound in report["wcet_cycles"].items()
               if report["measured_max_cycles"][name] > bound]
    daq = report["wcet_with_xcp_daq"]["node_on_frame"]
    if daq["measured_max"] > daq["bound"]:
        failed.append(f"node_on_frame measured {daq['measured_max']} cycles with an XCP master's DAQ running, above "
                      f"its static bound {daq['bound']}")
    for sentence in failed:
        print(f"bench: error: {sentence}", file=sys.stderr)
    return 1 if failed else 0


def _print_timing(report: dict) -> None:
    print(f"{report['kind']} ({report['realization']}), {report['rows']} rows with the current loop at "
          f"{report['isr_rate_hz']:g} Hz, {report['firmware']}")
    for name, row in report["wcet"].items():
        found = "not searched" if row["adversarial_max"] is None else row["adversarial_max"]
        print(f"  {name}: WCET bound {row['bound']} cycles (IPET); measured max: drive {row['drive_max']}, input "
              f"search {found}; bound / measured max {row['bound_over_max']}")
    daq = report["wcet_with_xcp_daq"]
    print(f"  node_on_frame with {daq['description']}: WCET bound {daq['node_on_frame']['bound']} cycles; measured "
          f"max {daq['node_on_frame']['measured_max']} ({daq['daq_packets']} DAQ packets); bound / measured max "
          f"{daq['node_on_frame']['bound_over_max']}")
    for clock, run in report["runs"].items():
        response, latency, load = run["response_time_us"], run["isr_latency_cycles"], run["cpu_load"]
        print(f"  {clock}: model step response p50 {response['p50']} / p99 {response['p99']} / max "
              f"{response['max']} µs; interrupt latency p50 {latency['p50']} / max {latency['max']} cycles "
              f"(idle {run['isr_latency_idle_cycles']['max']}, jitter {latency['jitter']}); CPU load: current loop "
              f"{100 * load['current_loop_isr']:.2f} %, model step {100 * load['model_step']:.4f} %, frame handling "
              f"{100 * load['frame_handling']:.4f} %; outputs bit for bit: {run['bit_exact']}")


def run_a2l(args: argparse.Namespace) -> int:
    from bench.fileio import write_text_atomically
    from bench.firmware.a2l import a2l_text
    from target_sim.artifact import load_artifact

    path = args.model
    if path is None:
        from bench.model.default import default_artifact_path

        path = default_artifact_path()
    check_writable(args.out, "--out")
    artifact = load_artifact(path)
    text = a2l_text(artifact, args.elf)      # an A2lError is a BenchError: one sentence, exit 1
    write_text_atomically(args.out, text, "the A2L")
    report = {**_identity(path, artifact), "out": str(args.out), "elf": None if args.elf is None else str(args.elf),
              "measurements": text.count("/begin MEASUREMENT"), "characteristics": text.count("/begin CHARACTERISTIC")}
    if args.json:
        print_json(report)
    elif not args.quiet:
        print(f"wrote {args.out}: {report['measurements']} measurements, {report['characteristics']} "
              f"characteristics, XCP on CAN ({'addresses of ' + str(args.elf) if args.elf else 'the slave pages'})")
    return 0
