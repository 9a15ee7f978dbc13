"""Argument types and output helpers shared by the subcommands, and the summary lines of a run or a log that
`bench run` and `bench analyze` share (the pass/fail rule is `bench.analysis.verdict`'s)."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

from bench.errors import UsageError
from bench.fileio import check_writable  # noqa: F401 - the commands import it from here
from bench.run.inputs import data_options  # noqa: F401 - the commands import it from here
from bench.run.request import OPTION, RUN, add_options
from bench.run.values import sample_period  # noqa: F401 - the commands import it from here


def float_list(text: str) -> list[float]:
    """'0.5,1,2' -> [0.5, 1.0, 2.0]; each value must be a positive number."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UsageError(f"{text!r} is not a comma-separated list of numbers, e.g. 0.5,1,2,4") from None
    if not values or any(not math.isfinite(v) or v <= 0 for v in values):
        raise UsageError(f"{text!r} must list positive numbers, e.g. 0.5,1,2,4")
    return values


def choice_list(choices: tuple[str, ...]) -> Callable[[str], list[str]]:
    """An argparse type for a comma-separated subset of `choices`."""
    def parse(text: str) -> list[str]:
        values = [v.strip() for v in text.split(",") if v.strip()]
        bad = [v for v in values if v not in choices]
        if bad or not values:
            raise UsageError(f"{text!r} is not a comma-separated list of {', '.join(choices)}")
        return values
    return parse


def add_output_flags(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def add_engine_argument(parser, default: str = "python") -> None:
    """--engine as `bench run` has it (`bench.run.request`), with this command's default."""
    option = OPTION["engine"]
    parser.add_argument(option.flag, dest=option.key, **{**option.argparse_kwargs(RUN), "default": default,
                                                         "help": option.help_for(RUN, default)})


def finite_or_none(value):
    """JSON has no infinity or NaN: those become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_or_none(v) for v in value]
    return value


def print_json(obj) -> None:
    json.dump(finite_or_none(obj), sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")


# the order a summary line shows the nodes in: the hot spots a model is deployed for first
SHOWN_NODES = ("winding", "magnet", "yoke", "tooth")


def fmt(value, digits: int = 3) -> str:
    """A number for a summary line, '–' for none."""
    return "–" if value is None else f"{value:.{digits}f}"


def print_summary(m: RunResults, problems: list[str], faults: HostFaults | FaultResults | None = None) -> None:
    """The lines `bench run` and `bench analyze` print without --json (`faults`: the run's, else the log's)."""
    temps = SHOWN_NODES
    model, agreement, accuracy, timing = m.model, m.agreement, m.accuracy, m.timing
    print(f"model {model.id} {model.kind} ({model.realization}, dt {model.dt_s:g} s)")
    print(f"steps sent {m.counts.steps_sent}, answered {m.counts.replies}, missing {m.counts.missing}, "
          f"model steps {m.counts.model_steps}")
    print(f"max |CAN - {agreement.can_reference}| (°C): "
          + ", ".join(f"{t} {fmt(agreement.max_abs_can_minus_float32_C.get(t), 4)}" for t in temps))
    if agreement.rows_lost_on_the_bus:
        print(f"{agreement.rows_lost_on_the_bus} rows never reached the target intact; max |CAN - clean run| (°C): "
              + ", ".join(f"{t} {fmt(agreement.max_abs_can_minus_clean_C.get(t), 4)}" for t in temps))
    print("max |float32 - float64| (°C): " + ", ".join(
        f"{t} {fmt(accuracy.max_abs_float32_minus_float64_C.get(t), 4)}" for t in temps))
    print("RMSE (°C): " + ", ".join(f"{t} {fmt(accuracy.rmse_C.get(t))} (vs {accuracy.rmse_reference.get(t)})"
                                    for t in temps))
    print(m.figure_rows.text("RMSE and every figure"))
    st, rtt = timing.step_time_us, m.throughput.round_trip_us
    print(f"step time on the target process p50/p99/max: {fmt(st.p50, 1)}/{fmt(st.p99, 1)}/{fmt(st.max, 1)} µs;"
          f" estimated C28x: {timing.est_cycles} cycles = {fmt(timing.est_exec_time_us, 1)} µs at 90 MHz "
          f"({fmt(timing.cpu_load_percent, 4)} % CPU), flash {m.memory.est_flash_bytes} B, "
          f"RAM {m.memory.est_ram_bytes} B")
    if timing.engine == "firmware":
        cycles, exec_us = timing.m4_cycles, timing.m4_exec_time_us
        print(f"firmware engine, measured Cortex-M4F (emulated): {cycles and cycles.p50} cycles p50, "
              f"{cycles and cycles.max} max = {fmt(exec_us and exec_us.p50, 1)} µs at {timing.m4_clock_mhz:g} MHz; "
              f"ELF flash {m.memory.flash_bytes} B, RAM {m.memory.ram_bytes} B")
        if timing.response_time_us is not None:
            response = timing.response_time_us
            print(f"beside the current loop's interrupt: model step response time p50/p99/max {fmt(response.p50, 1)}/"
                  f"{fmt(response.p99, 1)}/{fmt(response.max, 1)} µs, interrupt CPU load "
                  f"{fmt(timing.isr_load_percent, 2)} %")
    print(f"throughput {fmt(m.throughput.throughput_steps_per_s, 0)} steps/s, round trip p50/p99 "
          f"{fmt(rtt.p50, 0)}/{fmt(rtt.p99, 0)} µs, bus load at the data rate "
          f"{fmt(m.bus_load.data_rate_percent, 2)} %")
    if m.observer is not None:   # open loop and observer side by side; the measured node's error is not an estimate's
        obs = m.observer
        print(f"observer measuring the {obs.measured_node} node ({obs.slot} slot): {obs.model_steps_updated} of "
              f"{obs.model_steps} model steps updated; RMSE open loop / observer (°C): " + ", ".join(
                  f"{t} {fmt(obs.open_loop_rmse_C.get(t))}/{fmt(obs.observer_rmse_C.get(t))}" for t in temps
                  if obs.open_loop_rmse_C.get(t) is not None)
              + "; final 1-sigma (°C): " + ", ".join(f"{t} {fmt(obs.sigma_final_C.get(t))}" for t in temps))
        if len(obs.measurements) > 1:
            print("observer measurements: " + ", ".join(
                f"{slot} ({m.measured_node}) used in {m.model_steps_updated} steps"
                for slot, m in obs.measurements.items()))
    faults = faults or m.faults
    if faults:
        detected = faults.detected or {}
        print("faults injected/detected: " + ", ".join(
            f"{k} {n}/{'?' if detected.get(k) is None else detected[k]}" for k, n in faults.injected.items())
            + f"; {faults.retransmitted_rows} rows retransmitted, {len(faults.gaps)} gap(s)"
            + "".join(f" rows {g.rows[0]}-{g.rows[1]}" for g in faults.gaps[:5]))
    print(f"log {m.integrity.log}" + (f", report {m.report}" if m.report else ""))
    for note in m.notes:
        print(f"note: {note}")
    if problems:
        print("NOT clean: " + "; ".join(problems))
    elif faults and faults.injected_total:
        print(f"{faults.injected_total} faults injected, "
              + ("all detected" if faults.undetected == 0 else "detection not verified")
              + ", nothing else went wrong")
    else:
        print("clean")


# ---------------------------------------------------------------- a user's data: --mapping and --sample-period

if TYPE_CHECKING:  # the CLI imports every subcommand at start: the loader only when a command runs
    from bench.analysis.results import FaultResults, HostFaults, RunResults


def add_data_arguments(parser) -> None:
    """--mapping FILE and --sample-period S|auto, how a user's own data files are read (see bench.drive.mapping)."""
    add_options(parser, RUN, ("mapping", "sample_period"))
