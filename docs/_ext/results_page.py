"""The results page, the README's headline table and the measured tables of the method and own-motor pages, built
from the benchmark records in `docs/results/*.json` (written by `tests/benchmarks/*.py` through
`tests/benchmarks/record.py`), so no measured figure is typed by hand.

One renderer per benchmark (`SECTIONS`), each a plain function of its records; a benchmark without a record gets a
line saying how to measure it. Every section opens with its provenance: when, on what machine, under what load, on
which code, with which command. A benchmark with one record writes only its body; `single_record` gives it that
opening.
"""

from __future__ import annotations

import functools
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

DOCS = Path(__file__).resolve().parents[1]
RESULTS = DOCS / "results"
Record = dict[str, Any]

README_BEGIN = "<!-- headline results: generated from docs/results by docs/check_generated.py --write; do not edit -->"
README_END = "<!-- end of headline results -->"


# ---------------------------------------------------------------------------------------------- reading
def load_records(directory: Path = RESULTS) -> dict[str, list[Record]]:
    """The records by benchmark name, each list ordered by variant."""
    found: dict[str, list[Record]] = {}
    for path in sorted(directory.glob("*.json")):
        record = json.loads(path.read_text(encoding="utf-8"))
        record["_file"] = path.name
        found.setdefault(record["benchmark"], []).append(record)
    return found


def _one(records: dict[str, list[Record]], name: str) -> Record | None:
    return records.get(name, [None])[0]


# ---------------------------------------------------------------------------------------------- formatting
def _n(value: float | None, digits: int = 0) -> str:
    """A number as the pages write it: thousands apart by a space, `–` for none."""
    if value is None:
        return "–"
    return f"{value:,.{digits}f}".replace(",", " ")


def _e(value: float | None) -> str:
    return "–" if value is None else f"{value:.1e}"


def _date(record: Record) -> str:
    return record["date"][:10]


def provenance(record: Record) -> str:
    """One paragraph: the command, when, on what, under what load, on which code."""
    m, code, load = record["machine"], record["code"], record["load_average"]
    commit = f" at `{code['commit']}`" + (" with local changes" if code.get("dirty") else "") if code.get("commit") \
        else ""
    return (f"*Measured {record['date'].replace('T', ' ').replace('Z', ' UTC')} by `{record['command']}` "
            f"({_n(record['wall_s'], 0)} s) on {m['cpu']}, {m['cpus']} CPUs, {m['memory_GB']} GB, {m['os']}, "
            f"Python {m['python']}, numpy {m['numpy']}; load average {load['start']} at the start, {load['end']} at "
            f"the end; code {code['version']}{commit}.*")


def _span(values: list[float], digits: int, unit: str) -> str:
    low, high = _n(min(values), digits), _n(max(values), digits)
    return f"{low} {unit}" if low == high else f"{low}–{high} {unit}"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _missing(name: str) -> list[str]:
    """The line standing for benchmark `name`'s record while there is none: the script that writes it."""
    return [f"Not measured yet: `python tests/benchmarks/bench_{name}.py` writes the record this section is built "
            "from.", ""]


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(row) + " |" for row in rows), ""]


# ---------------------------------------------------------------------------------------------- sections
Section = Callable[[dict[str, list[Record]]], list[str]]


def single_record(name: str, title: str) -> Callable[[Callable[[Record], list[str]]], Section]:
    """A section built from benchmark `name`'s one record: the decorated body gives the lines after the heading and the
    provenance; without a record the section is its heading and the line saying how to measure it."""
    def decorate(body: Callable[[Record], list[str]]) -> Section:
        @functools.wraps(body)
        def section(records: dict[str, list[Record]]) -> list[str]:
            record = _one(records, name)
            lines = [f"## {title}", ""]
            if record is None:
                return lines + _missing(name)
            return lines + [provenance(record), "", *body(record)]
        return section
    return decorate


@single_record("accuracy", "Accuracy")
def section_accuracy(record: Record) -> list[str]:
    lines = ["The built-in motor's Table 5 analogue:", "", *table5(record), ""]
    if "ipm" in record["figures"]:
        lines += ["The IPM example ([your own motor](tutorials/own-motor.md)):", "", *ipm_table(record)]
    if "ipm_priors" in record["figures"]:
        lines += ["", "The IPM example identified from three priors (held-out profiles, pooled, float32):", "",
                  *ipm_priors_table(record)]
    return lines


def ipm_priors_table(record: Record) -> list[str]:
    """Issue 24's table: per prior, winding and PM RMSE / max of both kinds, parameters on a bound, the ridge."""
    def figure(model: dict | None, node: str) -> str:
        if not model:
            return "–"
        return f"{_n(model[node]['rmse_C'], 2)} / {_n(model[node]['max_abs_C'], 1)}"

    rows = []
    for row in record["figures"]["ipm_priors"]:
        lti, ham = row["models"].get("lti-lptn"), row["models"].get("hammerstein")
        rows.append([row["prior"], figure(lti, "winding"), figure(lti, "pm"), figure(ham, "winding"),
                     figure(ham, "pm"), ", ".join(row["on_bounds"]) or "none", str(len(row["frozen"])),
                     "–" if row["ridge_factor"] is None else f"{row['ridge_factor']:g}",
                     "–" if row.get("stator_weight") is None else _n(row["stator_weight"], 3),
                     ", ".join(_n(v, 2) for v in row["prior_scales"].values()) if row.get("prior_scales") else "–",
                     _moved_paths(row.get("prior_paths")),
                     f"{_n(row['identify_s'], 1)} ({_n(row['identify_cpu_s'], 1)} CPU)"])
    return [*_table(["prior", "LTI winding", "LTI PM", "Hammerstein winding", "Hammerstein PM", "on a bound",
                     "frozen", "ridge factor", "stator weight", "prior scaled (R, C stator; R, C rotor)",
                     "paths moved > 2×", "`bench identify` s"], rows),
            f"(°C, RMSE / max \\|error\\|; `table1 0.5-2` is what `bench motor template` gives, "
            f"{_adaptation(record)}; the ridge factor and stator weight are the Hammerstein step's, chosen by "
            f"cross-validation; measured {_date(record)}.)"]


def _adaptation(record: Record) -> str:
    """How the table's named prior was used: adapted to the data first (a 'prior scaled' column), or as named."""
    adapted = any(row.get("prior_scales") for row in record["figures"]["ipm_priors"])
    return ("adapted to the data first: common factors, then each path" if adapted else
            "searched as named (`--adapt-prior no`, the default)")


def _moved_paths(paths: dict[str, float] | None) -> str:
    """The adapted prior's paths that moved by more than 2× from the scaled prior, or – without adaptation."""
    if not paths:
        return "–"
    moved = [f"{name} × {_n(factor, 2)}" for name, factor in paths.items() if not 0.5 <= factor <= 2.0]
    return ", ".join(moved) or "none"


def _rmse(model: dict | None, node: str) -> str:
    return _n(model["nodes"][node]["rmse_C"], 3) if model else "–"


def _winding_pm(model: dict) -> str:
    return f"{_rmse(model, 'winding')} / {_rmse(model, 'pm')} °C"


def table5(record: Record) -> list[str]:
    """The Table 5 analogue: RMSE of winding and PM per Δt, LTI LPTN and Hammerstein, float32 as deployed."""
    builtin = record["figures"]["builtin"]
    by_dt: dict[float, dict[str, Any]] = {}
    for row in builtin["table5"]:
        by_dt.setdefault(row["dt_s"], {})[row["kind"]] = row
    rows = []
    for dt, kinds in sorted(by_dt.items()):
        lti, ham = kinds.get("lti-lptn"), kinds.get("hammerstein")
        rows.append([f"{dt:g}", _rmse(lti, "winding"), _rmse(ham, "winding"), _rmse(lti, "pm"), _rmse(ham, "pm"),
                     _e(max(r["max_abs_f32_minus_f64_C"] for r in kinds.values()))])
    balanced = builtin["balanced_max_abs_f32_minus_f64_C"]
    return [*_table(["Δt (s)", "winding RMSE LTI LPTN", "winding RMSE Hammerstein", "PM RMSE LTI LPTN",
                     "PM RMSE Hammerstein", "max \\|float32 − float64\\|"], rows),
            f"(°C, float32 of the deployed realization on the 40 °C validation run ({builtin['validation']}); "
            f"the balanced realization's largest \\|float32 − float64\\| at Δt 0.5 s: "
            + ", ".join(f"{kind} {_e(v)}" for kind, v in balanced.items())
            + f". `bench evaluate` took {_n(builtin['evaluate_s'], 1)} s; measured {_date(record)}.)"]


def ipm_table(record: Record) -> list[str]:
    """The IPM example on its held-out profiles: each kind and the baselines, per node, pooled, float32."""
    ipm = record["figures"]["ipm"]
    nodes = ("winding", "pm", "yoke", "tooth")
    header = ["estimator"] + [f"{node} {what}" for node in nodes for what in ("RMSE", "max")]
    rows = []
    for model in ipm["models"]:
        rows.append([f"{model['kind']} (Δt {model['dt_s']:g} s)"]
                    + [_n(model["nodes"].get(node, {}).get(key), 3 if key == "rmse_C" else 2)
                       for node in nodes for key in ("rmse_C", "max_abs_C")])
    baselines = ipm["models"][0]["baselines"] if ipm["models"] else {}
    names = {"copper_lowpass": "baseline: copper-loss low-pass (fitted on the training files)",
             "coolant": "baseline: coolant temperature"}
    for name, by_node in baselines.items():
        rows.append([names.get(name, f"baseline: {name}")]
                    + [_n(by_node.get(node, {}).get(key), 3 if key == "rmse_C" else 2)
                       for node in nodes for key in ("rmse_C", "max_abs_C")])
    bounds = ipm["parameters_on_bounds"]
    named = ", ".join(str(p.get("name", p)) if isinstance(p, dict) else str(p) for p in bounds)
    return [*_table(header, rows),
            f"(°C, the held-out profiles {' and '.join(ipm['held_out'])} pooled, float32 as the target runs it; "
            f"`bench data` {_n(ipm['data_s'], 1)} s, `bench identify --all-kinds` {_n(ipm['identify_s'], 1)} s, "
            f"`bench evaluate` {_n(ipm['evaluate_s'], 1)} s; {len(bounds)} LPTN parameters ended on a bound"
            + (f": {named}" if named else "") + f"; measured {_date(record)}.)"]


@single_record("identify", "Identification")
def section_identify(record: Record) -> list[str]:
    f = record["figures"]
    rows = [["PSO, swarm 220, 100 iterations", _n(f["pso_s"], 1), f"{_n(f['pso_model_runs'])} model runs, cost "
             f"{f['pso_cost']:.4f}"]]
    rows += [[f"LM Hammerstein, {path}", _n(lm["seconds"], 1),
              f"RMS {lm['rms_initial_C']:.4f} → {lm['rms_final_C']:.4f} °C"] for path, lm in f["lm"].items()]
    rows.append(["compiled kernel, first call", _n(f["kernel_first_call_s"], 2), "numba compiles or loads its cache"])
    return [*_table(["step", "seconds", "result"], rows),
            f"Peak resident memory {_n(f['peak_rss_MB'])} MB.", ""]


@single_record("firmware", "Firmware")
def section_firmware(record: Record) -> list[str]:
    f = record["figures"]
    rows = [[f"{r['kind']} ({r['realization']}, {r['dt_s']:g} s)", f"{r['cycles']['p50']} / {r['cycles']['max']}",
             _n(r["exec_us_at_90MHz"]["p50"], 1), _n(r["flash_bytes"]), _n(r["ram_bytes"]), _n(r["stack_used_bytes"]),
             _n(r["emulated_steps_per_s"]), f"{r['mismatches']} of {_n(r['steps'])}",
             f"{_n(r['c28x_estimate']['cycles'])}, {_n(r['c28x_estimate']['flash_bytes'])}, "
             f"{_n(r['c28x_estimate']['ram_bytes'])}"] for r in f["packaged"]]
    lines = [f"`bench firmware check` of the packaged artifacts' shipped ELFs over the 40 °C run "
             f"({_n(record['parameters'].get('data_rows'))} rows); cycles of `fw_step` as the emulator counts them, "
             "flash and RAM of the whole ELF (model and CAN node), mismatches against the Python float32 reference:",
             "", *_table(["kind (realization, Δt)", "Cortex-M4F cycles p50 / max", "µs at 90 MHz", "flash (B)",
                          "RAM (B)", "model stack (B)", "emulated steps/s", "mismatches",
                          "C28x estimate: cycles, flash, RAM (B)"], rows)]
    if f.get("matrix"):
        matrix = [[r["kind"], r["realization"], f"{r['dt_s']:g}", f"{r['cycles']['p50']}", f"{r['mismatches']}",
                   _n(r["build_s"], 1)] for r in f["matrix"]]
        lines += ["Every realization at Δt 0.5, 1, 2, 4 s from the packaged identification (the Hammerstein block "
                  "not refitted), each compiled and checked:", "",
                  *_table(["kind", "realization", "Δt (s)", "cycles", "mismatches", "build (s)"], matrix)]
    if f.get("lockstep"):
        lines += _lockstep_line(f["lockstep"], "the default run over the bus, log written, engines alternating")
    return lines


def _wcet_cells(rate: dict) -> list[str]:
    """Per timed function: bound / drive max / search max (ratio), or bound / measured max in an older record; then
    node_on_frame's with an XCP master running DAQ."""
    if "wcet" not in rate:
        return [*(f"{_n(rate['wcet_cycles'][name])} / {_n(rate['measured_max_cycles'][name])}"
                  for name in ("fw_step", "node_on_frame", "foc_isr")), "not measured"]
    cells = [f"{_n(row['bound'])} / {_n(row['drive_max'])} / {_n(row['adversarial_max'])} "
             f"({_n(row['bound_over_max'], 3)})" for row in rate["wcet"].values()]
    daq = rate.get("wcet_with_xcp_daq", {}).get("node_on_frame")
    return [*cells, f"{_n(daq['bound'])} / {_n(daq['measured_max'])} ({_n(daq['bound_over_max'], 3)})"
            if daq else "not measured"]


@single_record("firmware_timing", "Beside the motor control")
def section_firmware_timing(record: Record) -> list[str]:
    f, params = record["figures"], record["parameters"]
    flash = [[k["kind"], _n(k["model_flash"]["code"]), _n(k["model_flash"]["constants"]),
              _n(k["model_flash"]["bytes"])] for k in f["kinds"]]
    bounds, timing, loads = [], [], []
    for k in f["kinds"]:
        first = k["rates"][str(params["rates_hz"][0])]
        bounds.append([k["kind"], *_wcet_cells(first), "yes" if all(r["wcet_holds"] for r in k["rates"].values())
                       else "NO"])
    if "observer" in f:
        first = f["observer"][str(params["rates_hz"][0])]
        bounds.append([f["observer"]["case"], *_wcet_cells(first), "yes" if first["wcet_holds"] else "NO"])
        for rate, r in k["rates"].items():
            for clock, run in r["runs"].items():
                resp, idle, busy = run["response_time_us"], run["isr_latency_idle_cycles"], \
                    run["isr_latency_preempting_cycles"]
                timing.append([k["kind"], f"{int(rate) // 1000} kHz", clock,
                               f"{_n(resp['p50'], 1)} / {_n(resp['p99'], 1)} / {_n(resp['max'], 1)}",
                               f"{_n(idle['max'])}", f"{_n(busy['p50'])} / {_n(busy['max'])}",
                               "yes" if run["bit_exact"] else "NO"])
                load = run["cpu_load"]
                loads.append([k["kind"], f"{int(rate) // 1000} kHz", clock, _n(100 * load["current_loop_isr"], 2),
                              _n(100 * load["model_step"], 4), _n(100 * load["frame_handling"], 4),
                              _n(100 * load["idle"], 2)])
    lines = [f"The model's own flash (`fw_model.o` in the linker map; the paper's figure "
             f"{_n(params['paper_model_flash_bytes'])} B), each distinct loss-table row stored once:", "",
             *_table(["kind", "code (B)", "constants (B)", "total (B)"], flash),
             "Static WCET bound (IPET) / measured maximum, the drive's and the input search's (cycles; bound over "
             "the larger in parentheses; node_on_frame with rows in order and no XCP master, as the drive runs; the "
             "model step is fw_obs_step for the observer); last, node_on_frame's bound with an XCP master running "
             "the DAQ tables' whole budget / the drive's maximum under that DAQ:", "",
             *_table(["kind", "model step", "node_on_frame", "foc_isr (handler)", "node_on_frame, XCP DAQ running",
                      "bound holds"], bounds),
             f"The node and the model beside the field-oriented current loop's interrupt ({_n(params['rows'])} rows "
             "of the 40 °C run): the model step's response time (the arrival of the row that ends an interval to "
             "its temperatures queued), the interrupt's latency when it finds the core idle (the estimator not "
             "running) and when it preempts the node, the outputs bit for bit against the node without it:", "",
             *_table(["kind", "interrupt", "clock", "response p50 / p99 / max (µs)", "latency idle, max (cycles)",
                      "latency preempting p50 / max (cycles)", "bit exact"], timing),
             "CPU load by task (%):", "",
             *_table(["kind", "interrupt", "clock", "current loop", "model step", "frame handling", "idle"], loads)]
    if f.get("lockstep"):
        lock = f["lockstep"]
        runs = "; ".join(f"{name} {_n(lock['median_rows_per_s'][name])} rows/s median (runs "
                         f"{', '.join(_n(v) for v in values)}{'' if lock['clean'][name] else ', NOT clean'})"
                         for name, values in lock["rows_per_s"].items())
        lines += [f"Lockstep `bench run --engine firmware [--isr-rate HZ]`, {_n(lock['rows'])} rows, variants "
                  f"alternating (load average {_n(record['load_average']['start'], 1)} at the start): {runs}.", ""]
    if f.get("node_throughput"):
        node = f["node_throughput"]
        lines += [f"The firmware node alone (no bus), {_n(node['rows'])} rows: " + "; ".join(
            f"{name} {_n(value)} rows per CPU second" for name, value in node["rows_per_cpu_s"].items()) + ".", ""]
    return lines


def _lockstep_line(lockstep: dict, what: str) -> list[str]:
    runs = "; ".join(f"{engine} {_n(lockstep['median_rows_per_s'][engine])} rows/s median (runs "
                     f"{', '.join(_n(v) for v in values)})" for engine, values in lockstep["rows_per_s"].items())
    return [f"Lockstep throughput, {what}: {runs}.", ""]


@single_record("firmware_observer", "The observer in the firmware")
def section_firmware_observer(record: Record) -> list[str]:
    params = record["parameters"]
    rows = []
    for case in record["figures"]["cases"]:
        plain, closed, added = case["open_loop"], case["observer"], case["added"]
        steady = case.get("steady")
        steady_text = (f"{steady['cycles']['p50']} ({steady['mismatches']} mismatches)" if steady else "not measured")
        rows.append([case["case"], _n(case["states"]), f"{plain['cycles']['p50']} / {plain['cycles']['max']}",
                     f"{closed['cycles']['p50']} / {closed['cycles']['max']}", _n(added["cycles_p50"]), steady_text,
                     f"{closed['mismatches']} of {_n(closed['steps'])} ({_updated(case)})",
                     f"+{_n(added['model_code_bytes'])} / +{_n(added['model_constants_bytes'])}",
                     f"{_n(closed['flash_bytes'])} (+{_n(added['flash_bytes'])})",
                     f"{_n(closed['ram_bytes'])} (+{_n(added['ram_bytes'])})"])
    return ["`bench firmware check` of the Hammerstein model open loop (`fw_step`) and with its observer "
            "(`fw_obs_step`: the model step, the Bierman-Thornton prediction and update; beside it the same "
            "observer deploying its steady-state gain, K_ss at the nominal R), "
            f"{_n(params['rows'])} rows; mismatches against the Python float32 observer (outputs, each "
            "node's 1-sigma, each measurement's innovation and the checkpoint every 20 steps, bit for bit); "
            "what the observer adds to the model's own flash (`fw_model.o`) and to the image (issue 25's goal: "
            "predict + update within "
            f"{_n(params['goal_cycles'])} cycles):", "",
            *_table(["observer", "filter states", "open loop cycles p50 / max",
                     "observer cycles p50 / max", "added cycles", "steady-state gain cycles p50", "mismatches",
                     "fw_model.o code / constants (B)", "flash (B)", "RAM (B)"], rows),
            *_firmware_observer_runs(record["figures"].get("can_runs") or [])]


def _updated(case: dict) -> str:
    """Steps updated, and per measurement when there are several."""
    closed = case["observer"]
    each = closed.get("updates_per_measurement") or []
    names = case["measurement"].split(", ")
    if len(each) < 2:
        return f"{_n(closed['updates'])} updated"
    return f"{_n(closed['updates'])} updated: " + ", ".join(f"{name} {_n(n)}"
                                                             for name, n in zip(names, each, strict=False))


def _firmware_observer_runs(runs: list[dict]) -> list[str]:
    """`bench run --engine firmware` of the IPM example's flux-linkage observers."""
    if not runs:
        return []
    rows = [[r["case"], _n(r["rows"]), str(r["exit"]), r["verdict"] or "", _n(r["max_abs_can_minus_float32_C"], 4),
             f"{_n(r['steps_updated'])} of {_n(r['model_steps'])} ("
             + ", ".join(f"{slot} {_n(n)}" for slot, n in r["steps_updated_per_slot"].items()) + ")",
             f"{_n(r['m4_cycles']['p50'])} / {_n(r['m4_cycles']['max'])}", _n(r["load_average"], 1)]
            for r in runs]
    return ["", "`bench run --engine firmware` of the IPM example's observers that read the flux linkage (the "
            "held-out profile over CAN, DriveVoltages with the NTC's Measurements):", "",
            *_table(["observer", "rows", "exit", "verdict", "max \\|CAN − float32\\| (°C)",
                     "steps updated (per slot)", "cycles p50 / max", "load average"], rows)]


@single_record("firmware_node", "The CAN node in firmware")
def section_firmware_node(record: Record) -> list[str]:
    f = record["figures"]
    i = f["identity"]
    lines = [f"A whole session ({_n(record['parameters']['session_rows'])} rows, {_n(i['frames_in'])} host frames) "
             f"into the Python node and the firmware node: {_n(i['frames_compared'])} reply frames compared, "
             f"{i['mismatching_calls']} differing; {_n(i['model_steps'])} model steps.", "",
             *_table(["cycles (Cortex-M4F)", "p50", "max"],
                     [["model step (DWT_CYCCNT)", _n(i["m4_cycles"]["p50"]), _n(i["m4_cycles"]["max"])],
                      ["handling a received frame, model step excluded", _n(i["frame_cycles"]["p50"]),
                       _n(i["frame_cycles"]["max"])],
                      ["building a reply frame", _n(i["reply_cycles"]["p50"]), _n(i["reply_cycles"]["max"])]]),
             f"Flash {_n(i['flash_bytes'])} B, RAM {_n(i['ram_bytes'])} B, stack used {_n(i['stack_used_bytes'])} B, "
             f"transmit queue drops {i['tx_dropped']}.", "",
             "Under frame faults (each kind of `dbc.mutations` at the rate given, on the drive frames):", "",
             *_table(["seed", "rate", "frames in", "replies compared", "differing", "RxErrors counts equal"],
                     [[str(r["seed"]), f"{r['rate']:g}", _n(r["frames_in"]), _n(r["frames_compared"]),
                       str(r["mismatching_calls"]), "yes" if r["rx_errors_equal"] else "no"] for r in f["faults"]])]
    if f.get("lockstep"):
        lines += _lockstep_line(f["lockstep"], "`bench run` with each engine, alternating")
    return lines


@single_record("can", "Bus throughput")
def section_can(record: Record) -> list[str]:
    f = record["figures"]
    lock = f["lockstep"]
    rows = [[f"{r['coolant_C']:g} °C", _n(r["rows"]), _n(r["wall_s"], 2), _n(r["rows_per_s"]),
             f"{_n(r['round_trip_us']['p50'])} / {_n(r['round_trip_us']['p99'])}", str(r["missing"])]
            for r in lock["runs"]]
    lines = [f"Bus: {record['parameters'].get('bus')}.", "",
             "Lockstep, the three-run campaign, each run with its own target process, log written:", "",
             *_table(["run", "rows", "replay (s)", "rows/s", "round trip p50 / p99 (µs)", "missing"], rows),
             f"In all {_n(lock['rows'])} rows, replayed in {_n(lock['replay_s'], 1)} s ({_n(lock['rows_per_s'])} "
             f"rows/s), {_n(lock['with_start_stop_s'], 1)} s with the target processes' start and stop.", ""]
    if f.get("realtime"):
        lines += ["Realtime (send time against plan):", "",
                  *_table(["speed", "rows", "seconds", "send jitter p50 / p99 / max (µs)", "round trip p50 / p99 (µs)",
                           "missing"],
                          [[f"×{r['speed']:g}", _n(r["rows"]), _n(r["wall_s"], 1),
                            " / ".join(_n(r["send_jitter_us"][k], 1) for k in ("p50", "p99", "max")),
                            f"{_n(r['round_trip_us']['p50'])} / {_n(r['round_trip_us']['p99'])}", str(r["missing"])]
                           for r in f["realtime"]])]
    if f.get("default_run"):
        lines += ["`bench run` as the quick start runs it (datasets already made, log and report written):", "",
                  *_table(["run", "exit", "wall (s)", "rows/s", "max \\|CAN − float32\\| (°C)", "verdict"],
                          [[str(n + 1), str(r["exit"]), _n(r["wall_s"], 1), _n(r["rows_per_s"]),
                            _n(_worst(r.get("max_abs_can_minus_float32_C")), 4), str(r["verdict"])]
                           for n, r in enumerate(f["default_run"])])]
    return lines


@single_record("sitting", "Lockstep against the bus's round trip")
def section_sitting(record: Record) -> list[str]:
    """The performance sitting: per round and condition the one-frame ping-pong, `bench run` on each engine (and on
    the baseline's code, if measured), their ratios; the CPU budget of a row; then the medians against the goals."""
    f, p = record["figures"], record["parameters"]
    labels = [label for label in ("python", "firmware", "python_baseline", "firmware_baseline")
              if label in next(iter(f["rounds"].values()))[0]]
    names = {label: label.replace("_baseline", " (baseline)") for label in labels}
    rows_each = "the whole default run" if p.get("rows") is None else f"its first {_n(p['rows'])} rows"
    baseline = f" The baseline is the code at `{p['baseline']}`." if p.get("baseline") else ""
    lines = [f"Bus: {p.get('bus')}; `bench run` lockstep on {rows_each} (log written, no report), "
             f"{_count(p['rounds'], 'round')} alternating, quiet and with {p['hogs']} CPU-bound "
             f"{'process' if p['hogs'] == 1 else 'processes'} "
             f"beside it; the ping-pong {_n(p['pingpong_seconds'])} s each.{baseline}"
             + (f" {p['note']}" if p.get("note") else ""), ""]
    rows = []
    for condition, rounds in f["rounds"].items():
        for n, r in enumerate(rounds):
            rows.append([f"{condition} {n + 1}", _n(r["load_before"], 1), _n(r["pingpong"]["round_trips_per_s"]),
                         *(f"{_n(r[label]['rows_per_s'])} ({_n(r['ratio'][label], 3)})" for label in labels)])
    lines += ["rows/s of each `bench run` (÷ the ping-pong's round trips/s):", "",
              *_table(["round", "load before", "ping-pong round trips/s", *(names[label] for label in labels)], rows)]
    if f.get("budget"):
        lines += _sitting_budget(f["budget"])
    goals, met = p.get("goals", {}), f.get("goals_met", {})
    medians = [[condition, _n(m["pingpong_round_trips_per_s"]),
                *(f"{_n(m[label + '_rows_per_s'])} ({_n(m['ratio_' + label], 3)})" for label in labels),
                _n(m["ratio_firmware_over_python"], 2)] for condition, m in f["medians"].items()]
    lines += ["Medians of the sitting, rows/s (÷ the ping-pong's round trips/s):", "",
              *_table(["condition", "ping-pong round trips/s", *(names[label] for label in labels),
                       "firmware ÷ python"], medians)]
    if goals:
        lines += [f"Goals: python ÷ ping-pong ≥ {goals['quiet']:g} quiet ({'met' if met.get('quiet') else 'not met'}), "
                  f"≥ {goals['loaded']:g} loaded ({'met' if met.get('loaded') else 'not met'}); firmware ÷ python ≥ "
                  f"{goals['firmware_over_python']:g} ({'met' if met.get('firmware_over_python') else 'not met'}).", ""]
    return lines


def _sitting_budget(budget: dict) -> list[str]:
    """Where a row's µs go, per engine: each part of the row in CPU time, both nodes in one thread."""
    engines = list(budget)
    parts = list(budget[engines[0]]["per_row_us"])
    rows = [[part, *(_n(budget[e]["per_row_us"].get(part), 1) for e in engines)] for part in parts]
    rows.append(["**a row in all**", *(f"**{_n(budget[e]['row_us'], 1)}**" for e in engines)])
    rows.append(["the one-frame ping-pong's round trip, the same way",
                 *(_n(budget[e]["pingpong_round_trip_us"], 1) for e in engines)])
    return [f"Where a row's µs go: host and target of {_n(budget[engines[0]]['rows'])} lockstep rows in one thread, "
            "one after the other (no wake-up, no scheduler), each part in the thread's CPU time; the target sends "
            + " and ".join(f"{budget[e]['target_frames_out_per_row']:g} frames a row ({e})" for e in engines) + ".",
            "", *_table(["part of a row (CPU µs)", *(f"{e} engine" for e in engines)], rows)]


def _worst(per_node: dict | None) -> float | None:
    values = [v for v in (per_node or {}).values() if v is not None]
    return max(values) if values else None


@single_record("memory", "Memory")
def section_memory(record: Record) -> list[str]:
    rows = []
    for m in record["figures"]["measurements"]:
        per_row = ", ".join(f"{scale}: {_n(v)}" for scale, v in m["bytes_per_row"].items())
        rows.append([m["step"], m["measure"], per_row, _n(m["marginal_bytes_per_row"]),
                     ", ".join(_n(r["rows"]) for r in m["runs"])])
    return ["Peak growth per data row over a baseline with the modules, model and data loaded, each step in a "
            "fresh process (scale k: the 40 °C run k times over); the marginal cost is the difference of the "
            "peaks over the difference of the rows, which no fixed cost enters:", "",
            *_table(["step", "measure", "bytes per row", "marginal bytes per row", "rows"], rows)]


@single_record("soak", "Soak")
def section_soak(record: Record) -> list[str]:
    p, f = record["parameters"], record["figures"]
    faults = ", ".join(f"{kind} {_n(f['injected'][kind])}/{_n(f['detected'].get(kind, 0))}" for kind in f["injected"])
    gaps = [g for run in f["runs"] for g in run["gaps_s"]]
    return [f"{_count(p['runs'], 'run')} of {_n(p['data_rows'])} rows, each with drop {p['drop']:g} and "
            f"corruption {p['corrupt']:g} per drive frame and {p['kills']} target kill: completed "
            f"{f['completed']}/{p['runs']}, every row answered in {f['answered_all']}/{p['runs']}; "
            f"injected/detected {faults}; "
            f"undetected {f['undetected']}; lost log frames {f['lost_log_frames']}; gaps "
            + (_span(gaps, 2, "s") if gaps else "none")
            + f"; max \\|CAN − restarted float32\\| {_n(f['max_abs_can_minus_restarted_float32_C'], 4)} °C, "
            f"max \\|CAN − clean run\\| {_n(f['max_abs_can_minus_clean_C'], 4)} °C over all rows; "
            f"{_n(f['soak_s'])} s in all; goals {'met' if f['goals_met'] else 'NOT met'}.", ""]


def section_campaigns(records: dict[str, list[Record]]) -> list[str]:
    lines = ["## Campaigns", ""]
    campaigns = records.get("campaign", [])
    if not campaigns:
        return lines + _missing("campaign")
    rows = []
    for r in campaigns:
        p, f = r["parameters"], r["figures"]
        counts = ", ".join(f"{n} {k}" for k, n in f["campaign"]["counts"].items())
        rows.append([f"`{Path(p['spec']).name}`" + (f", rows {p['rows']}" if p.get("rows") else ""), str(p["runs"]),
                     f"{_n(f['campaign']['wall_s'], 1)} s on {p['workers']} workers", _n(f["serial"]["wall_s"], 1)
                     + " s", f"{f['speed_up']:.2f}×", counts, _date(r)])
    lines += ["The runs of a spec through `bench campaign run` on local Dask workers against the same `bench run` "
              "invocations one after the other, in one sitting:", "",
              *_table(["spec", "runs", "campaign", "serial loop", "speed-up", "campaign outcome", "measured"], rows)]
    for r in campaigns:
        lines += [provenance(r), ""]
    return lines


@single_record("speed", "Speed of identification and observer tuning")
def section_speed(record: Record) -> list[str]:
    """Issue 40: `bench identify --all-kinds` per prior and `bench observer` on about 100 000 training rows."""
    f, p = record["figures"], record["parameters"]
    stage = {"pso": "swarm", "standard_errors": "standard errors", "polish": "polish", "lm": "Hammerstein LM"}
    rows = [[f"identify --all-kinds, {prior} prior", _n(run["seconds"]), _n(run["cpu_s"]),
             f"{run['load_average']}", ", ".join(f"{stage.get(k, k)} {_n(v)} s" for k, v in run["stages_s"].items()),
             "yes" if run["goal_met"] else "no"] for prior, run in f.get("identify", {}).items()]
    if "observer" in f:
        o = f["observer"]
        rows.append([f"observer, {o['evaluations']} filter runs", _n(o["seconds"]), _n(o["cpu_s"]),
                     f"{o['load_average'][0]}, {o['load_average'][1]}", "", "yes" if o["goal_met"] else "no"])
    missing = [f"identify with the {prior} prior" for prior in p["priors"] if prior not in f.get("identify", {})]
    missing += [] if "observer" in f else ["the observer"]
    return [f"{f.get('training_rows', 0):,}".replace(",", " ") + f" training rows in {f.get('training_files')} files "
            f"(the suite's {p['motor']} with longer copies of its training profiles), 2 cores "
            f"([method](method.md#identification))"
            + (f", the LM fits' factorization {p['lm_factorization']}" if p.get("lm_factorization") else "")
            + ". CPU seconds are the work; on a shared machine the wall time is the load's.", "",
            *_table(["command", "wall s", "CPU s", "load", "stages (wall)", f"≤ {p['goal_s']:g} s"], rows),
            *([f"Not measured in this record (the run was stopped): {', '.join(missing)}.", ""] if missing else [])]


@single_record("data", "Datasets")
def section_data(record: Record) -> list[str]:
    f = record["figures"]
    rows = [[f"{c} °C", _n(d["seconds"], 2), f"`{d['sha256'][:16]}…`"] for c, d in f["datasets"].items()]
    return [*_table(["coolant", "seconds", "sha256"], rows),
            f"All three in {_n(f['total_s'], 2)} s (goal: under {f['goal_s']} s).", ""]


@single_record("plant_distributed", "Distributed virtual plant")
def section_plant_distributed(record: Record) -> list[str]:
    f, p = record["figures"], record["parameters"]
    return [f"One {p['duration_s'] / 3600:.0f}-hour profile of examples/suite/ipm-60kw-distributed "
            f"({f['steps']} exact steps of {p['step_s']:g} s, {f['corners']} tabulated grid corners) in "
            f"{_n(f['seconds'], 2)} s (goal: under {f['goal_s']:g} s).", ""]


@single_record("observer", "Observer")
def section_observer(record: Record) -> list[str]:
    lines = ["The built-in motor, the winding thermocouple as the measurement "
             "([method](method.md#closed-loop-the-observer-first-part)):", "", *observer_builtin_table(record),
             ""]
    if "ipm" in record["figures"]:
        lines += ["The IPM example, held-out profiles:", "", *observer_ipm_table(record), ""]
    lines += ["Covariance forms in float32:", "", *observer_forms_table(record), ""]
    return lines


def _seconds(value: float | None) -> str:
    """A recovery time as the pages write it: `never` when the magnet was not within the band by the end."""
    return "never" if value is None else f"{_n(value)} s"


def _rmse_max(metrics: dict) -> str:
    return f"{_n(metrics['rmse_C'], 3)} / {_n(metrics['max_abs_C'], 2)}"


def _recovery(file: dict, offset: float, which: str) -> str:
    return next((_seconds(r[which]) for r in file["recovery"] if r["offset_K"] == offset), "–")


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:]


def _tuning(run: dict) -> str:
    """A tuning criterion and what it found: Q per node (°C² per step) and R (°C²)."""
    t = run["tuning"]
    q = ", ".join(f"{node} {v:.2g}" for node, v in t["q_C2_per_step"].items())
    default = " (default)" if run["criterion"] == DEFAULT_CRITERION else ""
    return f"`{run['criterion']}`{default}: q {q}; R {t['R_C2']:.2g}"


def observer_builtin_table(record: Record) -> list[str]:
    """Open loop against each tuning on the built-in motor's validation run: winding (the measured node), magnet,
    and the time until a magnet started ±30 K off stays within 2 K."""
    builtin = record["figures"]["builtin"]
    runs = builtin["runs"]
    first = runs[0]["files"][0]

    def cells(f: dict, which: str) -> list[str]:
        return [_rmse_max(f["nodes"]["winding"][which]), _rmse_max(f["nodes"]["pm"][which]),
                _recovery(f, 30.0, f"{which}_s"), _recovery(f, -30.0, f"{which}_s")]

    rows = [["open loop", *cells(first, "open_loop")]]
    rows += [[_tuning(run), *cells(run["files"][0], "observer")] for run in runs]
    by = {r["criterion"]: r["files"][0]["nodes"]["pm"] for r in runs}
    notes = []
    if "magnet" in by:
        shift = abs(by["magnet"]["observer"]["rmse_C"] - by["magnet"]["open_loop"]["rmse_C"])
        notes.append(f"the magnet-tuned observer's magnet RMSE is {_n(shift, 3)} °C from the open loop's")
    if "likelihood" in by:
        worst, open_worst = by["likelihood"]["observer"]["max_abs_C"], by["likelihood"]["open_loop"]["max_abs_C"]
        notes.append(f"the likelihood-tuned one's magnet is off by up to {_n(worst, 1)} °C ({_n(worst / open_worst, 0)}"
                     "× the open loop's largest error)")
    timing = ", ".join(f"`{r['criterion']}` {_n(r['observer_s'], 1)} s" for r in runs)
    return [*_table(["tuning", "winding RMSE / max (measured)", "magnet RMSE / max", "magnet +30 K: within 2 K after",
                     "magnet −30 K"], rows),
            f"(°C, float32, {first['measured_node']} measured by `{runs[0]['column']}`, `{runs[0]['form']}` form, on "
            f"{builtin['validation']}; Q and R as tuned on the 20 and 60 °C runs. " + _sentence("; ".join(notes))
            + f". `bench observer` took {timing}; measured {_date(record)}.)"]


DEFAULT_CRITERION = "magnet"   # `bench observer --criterion`'s default
IPM_CASES = {"ntc": "(a) stator NTC", "flux": "(b) flux linkage", "ntc+flux": "(c) NTC + flux linkage",
             "res": "(d) winding resistance", "flux+res": "(e) flux linkage + winding resistance"}


def observer_ipm_table(record: Record) -> list[str]:
    """Open loop against the observer with each measurement on the IPM example's held-out profiles: magnet RMSE and
    max, and the time until a magnet started ±30 K off stays within 2 K."""
    ipm = record["figures"]["ipm"]
    runs = ipm["runs"]
    files = runs[0]["files"]
    names = [Path(f["file"]).stem.removeprefix("profile_") for f in files]

    def cells(per_file: list[dict], which: str) -> list[str]:
        return ([_rmse_max(f["nodes"]["pm"][which]) for f in per_file]
                + [" / ".join(_recovery(f, offset, f"{which}_s") for f in per_file) for offset in (30.0, -30.0)])

    rows = [["open loop", *cells(files, "open_loop")]]
    criteria = list(dict.fromkeys(run["criterion"] for run in runs))
    rows += [[IPM_CASES.get(run.get("case"), run.get("case") or _tuning(run))
              + (f", `{run['criterion']}`" if len(criteria) > 1 else ""), *cells(run["files"], "observer")]
             for run in runs]
    worse = [f"{run.get('case')} profile {Path(f['file']).stem.removeprefix('profile_')}" for run in runs
             for f in run["files"] if f["nodes"]["pm"]["observer"]["rmse_C"] > f["nodes"]["pm"]["open_loop"]["rmse_C"]]
    winding = "; ".join(f"{run.get('case')}{' ' + run['criterion'] if len(criteria) > 1 else ''} "
                        + ", ".join(_n(f["nodes"]["winding"]["observer"]["rmse_C"], 2) for f in run["files"])
                        for run in runs)
    open_winding = ", ".join(_n(f["nodes"]["winding"]["open_loop"]["rmse_C"], 2) for f in files)
    sensor = ipm["sensor"]
    flux = next((m for run in runs for m in run["tuning"].get("measurements", [])
                 if m.get("kind") == "flux-linkage"), None)
    calibration = ""
    if flux:
        calibration = (f" Flux linkage calibrated on profiles 1–8 at or above {_n(flux['speed_min_rpm'])} rpm: ψ_0 "
                       f"{flux['psi_0_Vs']:.5f} Vs, α_B {flux['alpha_B_per_K'] * 100:.4f} %/K, L_d "
                       f"{flux['L_d_H'] * 1e6:.1f} µH, R_s {flux['R_s_ohm'] * 1e3:.2f} mΩ (fitted: "
                       f"{', '.join(flux['fitted'])}); residual RMS {_n(flux['residual_rms_K'], 2)} K, max "
                       f"{_n(flux['residual_max_K'], 1)} K per 1 s step.")
    resistance = next((m for run in runs for m in run["tuning"].get("measurements", [])
                       if m.get("kind") == "winding-resistance"), None)
    if resistance:
        calibration += (f" Winding resistance calibrated on profiles 1–8 at or below "
                        f"{_n(resistance['speed_max_rpm'])} rpm with |i_d| ≥ {_n(resistance['current_min_A'])} A "
                        f"({_n(resistance['steps'])} steps): R_s0 {resistance['R_s_ohm'] * 1e3:.2f} mΩ, L_q "
                        f"{resistance['L_q_H'] * 1e6:.1f} µH (fitted: {', '.join(resistance['fitted'])}); residual "
                        f"RMS {_n(resistance['residual_rms_K'], 2)} K, max {_n(resistance['residual_max_K'], 1)} K "
                        "per 1 s step.")
    return [*_table(["measurement", *(f"magnet RMSE / max, profile {n}" for n in names),
                     f"+30 K within 2 K ({' / '.join(names)})", f"−30 K ({' / '.join(names)})"], rows),
            f"(°C, float32, `{runs[0]['form']}` form, tuned with the {' and '.join(f'`{c}`' for c in criteria)} "
            f"criterion{'s' if len(criteria) > 1 else ''}; NTC: `--measure "
            f"{sensor['column']} --offset {sensor['offset_C']:g} --lag {sensor['lag_s']:g} --gradient "
            f"{sensor['gradient']:g}` (a lag state); \"never\": not within 2 K by the end of the profile. The "
            f"observer's magnet RMSE is worse than the open loop's in {len(worse)} of "
            f"{sum(len(r['files']) for r in runs)} cases{' (' + ', '.join(worse) + ')' if worse else ''}; winding "
            f"RMSE (profiles {', '.join(names)}): open loop {open_winding}; {winding}.{calibration} "
            f"`bench identify` {_n(ipm['identify_s'], 1)} s, `bench observer` "
            + ", ".join(f"{r.get('case')}{' ' + r['criterion'] if len(criteria) > 1 else ''} "
                        f"{_n(r['observer_s'], 1)} s" for r in runs)
            + f"; measured {_date(record)}.)"]


def _moved(entry: dict) -> str:
    if entry["diverged"]:
        return "diverged"
    spread = f" ± {entry['spread_C']:.3f}" if entry.get("spread_C") else ""    # none: a deterministic case
    return f"{entry['d_rmse_C']:+.3f}{spread} °C"


def _top_rows(studies: list[dict], node: str) -> list[list[str]]:
    """One row per study: its clean RMSE of `node` and the perturbations that move `node` most."""
    rows = []
    for study in studies:
        top = study["top"].get(node) or []
        clean = (study["clean_rmse_C"] or {}).get(node)
        rows.append([study["name"], _n(clean, 3), *(f"{r['perturbation']} at {r['magnitude']:g} {r['unit']}: "
                                                    f"{_moved(r)}" for r in top), *[""] * (3 - len(top))])
    return rows


@single_record("robustness", "Robustness")
def section_robustness(record: Record) -> list[str]:
    p, f = record["parameters"], record["figures"]
    builtin = f["builtin"]
    scope = (f"the first {_n(p['rows'])} rows of each file" if p.get("rows") else "whole files") + (
        f", {p['seeds']} seeds per random case" if p.get("seeds") else ", the default seeds")
    header = ["model on data", "clean RMSE °C", "1st", "2nd", "3rd"]
    lines = [f"`bench robustness` with its default spec ({scope}): the three perturbations that move the magnet "
             "estimate most (Δ RMSE against the clean run at the magnitude that moves it most, ± the Monte Carlo "
             "spread; the target's float32 code):", "",
             *_table(header, _top_rows(builtin["studies"] + f.get("ipm", {}).get("studies", []), "pm"))]
    two = builtin["workers_2"]
    timing = (f"The built-in study ({builtin['cases']} cases, {builtin['diverged']} diverged) took "
              f"{_n(two['study_wall_s'], 1)} s on 2 workers (peak memory of the process tree {_n(two['peak_tree_MiB'])}"
              " MiB)")
    if "serial" in builtin:
        serial = builtin["serial"]
        timing += (f" against {_n(serial['study_wall_s'], 1)} s in a serial loop ({_n(serial['peak_tree_MiB'])} MiB) "
                   f"in the same sitting: {builtin['speedup']:.2f}×; the two tables "
                   + ("agree case for case" if builtin["tables_agree"] else "DIFFER"))
    lines += [timing + ".", ""]
    if "ipm" in f:
        ipm = f["ipm"]
        lines += [f"The IPM example's Hammerstein model (identified on profiles 1–8 in {_n(ipm['identify_s'], 1)} s) "
                  f"on the held-out {', '.join(ipm['held_out'])}: {ipm['cases']} cases in {_n(ipm['wall_s'], 1)} s on "
                  f"2 workers, {ipm['diverged']} diverged.", ""]
    if "ipm_observer" in f:
        lines += _observer_side_by_side(f["ipm_observer"])
    return lines


def _observer_side_by_side(ipm: dict) -> list[str]:
    """The IPM example's observer study: per observer, the magnet's clean RMSE and its three largest movers, open
    loop and observer."""
    lines = [f"Open loop and observer side by side (`{ipm['spec']}`, {ipm['seeds']} seeds per random case, the "
             "observer's measurement channels perturbed like any input, a dropped reading meaning no reading): the "
             f"IPM example's Hammerstein model with each observer `bench observer` tunes, on the held-out "
             f"{', '.join(ipm['data'])}; {ipm['cases']} cases in {_n(ipm['wall_s'], 1)} s on 2 workers, "
             f"{ipm['diverged']} diverged. The three perturbations that move the magnet estimate most:", ""]
    rows = []
    for study in ipm["observers"]:
        measured = ", ".join(f"{m['kind']} ({', '.join(m['columns'])}) of the {m['node']}"
                             for m in study["measurements"])
        for part, label in (("open_loop", "open loop"), ("observer", "observer")):
            top = study["top"][part]
            rows.append([f"{measured}, on {study['data']}", label, _n(study["clean_rmse_C"][part], 3),
                         *(f"{r['perturbation']} at {r['magnitude']:g} {r['unit']}: {_moved(r)}" for r in top),
                         *[""] * (3 - len(top))])
    return lines + _table(["observer measures", "estimate", "clean RMSE °C", "1st", "2nd", "3rd"], rows)


def _closer(ratio: float, form: str) -> str:
    if 0.5 <= ratio <= 2.0:
        return f"about as closely as {form} ({ratio:.2f}×)"
    return f"{ratio:.0f}× closer than {form}" if ratio >= 1 else f"{1 / ratio:.0f}× further than {form}"


def observer_forms_table(record: Record) -> list[str]:
    """`bench numerics --observer`: each covariance form over the whole validation run in float32."""
    figures = record["figures"]
    numerics = figures["ipm"]["numerics"] if "numerics" in figures.get("ipm", {}) else figures["builtin"]["numerics"]
    names = {"conventional": "conventional", "joseph": "Joseph", "ud": "UD (Bierman–Thornton)",
             "steady": "steady-state gain"}
    rows = []
    for r in numerics["rows"]:
        label = names.get(r["form"], r["form"]) + (" (deployed)" if r["form"] == numerics["deployed_form"] else "")
        p = " (P_ss)" if r["form"] == "steady" else ""      # the steady gain keeps no covariance of its own
        symmetry = _e(r["max_symmetry_error"]) if r["max_symmetry_error"] else "0"
        rows.append([label, f"{r['min_eigenvalue']:.4g}{p}" if r["finite"] else "not finite", symmetry,
                     _e(r["max_abs_f32_minus_f64_C"])])
    by = {r["form"]: r for r in numerics["rows"]}
    deployed = by.get(numerics["deployed_form"])
    ratios = [_closer(by[f]["max_abs_f32_minus_f64_C"] / deployed["max_abs_f32_minus_f64_C"], names[f])
              for f in ("conventional", "joseph") if f in by and deployed and f != deployed["form"]
              and deployed["max_abs_f32_minus_f64_C"] > 0]
    definite = all(r["finite"] and r["min_eigenvalue"] > 0 for r in numerics["rows"])
    header = ["form", "smallest eigenvalue of P", "max \\|P − Pᵀ\\| / \\|P\\|", "max \\|f32 − f64\\| (°C)"]
    return [*_table(header, rows),
            f"(`{numerics.get('case', numerics['criterion'])}` filter on {numerics['data']}, "
            f"{numerics['realization']} realization, "
            f"Δt {numerics['dt_s']:g} s; P's eigenvalue in the state coordinates, its symmetry in the filter's own "
            "(node coordinates). "
            + ("Every form kept P positive definite" if definite else "A form LOST definiteness")
            + (f"; the deployed form follows the float64 filter {' and '.join(ratios)}" if ratios else "")
            + f". {_n(numerics['seconds'], 1)} s; measured {_date(record)}.)"]


@single_record("fault_sweep", "Fault sweep")
def section_fault_sweep(record: Record) -> list[str]:
    params, figures = record["parameters"], record["figures"]
    artifact, summary = params["artifact"], figures["summary"]
    engines = params["engines"]
    by_kind: dict[str, dict[str, dict]] = {}
    for run in figures["runs"]:
        by_kind.setdefault(run["kind"], {})[run["engine"]] = run
    rows = [[f"`{next(iter(runs.values()))['fault']}`", *(_sweep_cell(runs.get(e)) for e in engines)]
            for kind, runs in by_kind.items()]
    totals = "; ".join(f"{engine}: {s['exit_0']} of {s['runs']} runs exit 0, {_n(s['detected'])} of "
                       f"{_n(s['injected'])} injected faults detected" for engine, s in summary["engines"].items())
    failed = [f"{engine} {kind}: {why}" for engine, s in summary["engines"].items()
              for kind, why in s["failed"].items()]
    lines = [f"`bench run --faults KIND=V --fault-seed {params['seed']} --tolerate-faults` (lockstep, "
             f"{_n(params['rows'])} rows of `{artifact['data']}`) for {len(params['kinds'])} fault kinds of the "
             "registry (`host.faults.spec.KINDS`), each on its own, "
             f"with {artifact['observer']} (measurements {', '.join(artifact['measurements'])}, form "
             f"{artifact['form']}), whose rows carry Measurements and DriveVoltages and whose replies carry each "
             f"node's 1-sigma and the innovations; {params['parallel']} runs at a time. Per run: exit status, "
             "injected / detected, deadline misses (explained by a fault; late replies, answered at every send; "
             "unexplained), wall time and the load average at its start and end.", "",
             *_table(["fault", *engines], rows),
             f"{totals}. **The sweep {'passes' if summary['passed'] else 'does not pass'}**"
             + (": " + "; ".join(failed) if failed else "") + ".", "", _sweep_verdicts(figures["runs"])]
    return lines


def _sweep_verdicts(runs: list[dict]) -> str:
    """The runs' verdict sentences, alike ones (differing only in their counts) once with how many runs said them."""
    said: dict[str, int] = {}
    for run in runs:
        sentence = re.sub(r"\d+", "N", run.get("verdict") or run.get("error") or "no verdict")
        said[sentence] = said.get(sentence, 0) + 1
    return "Verdicts: " + "; ".join(f"\"{sentence}\" ({_count(n, 'run')})" for sentence, n in said.items()) + "."


def _sweep_cell(run: dict | None) -> str:
    """exit, injected/detected, misses (late, unexplained), seconds and load of one run."""
    if run is None:
        return "–"
    injected = sum((run.get("injected") or {}).values())
    detected = sum(v or 0 for v in (run.get("detected") or {}).values())
    late = f", {run['late_replies']} late (max {_n(run['late_reply_max_ms'])} ms)" if run.get("late_replies") else ""
    load = run["load_average"]
    return (f"exit {run['exit']}, {injected}/{detected}; misses {_n(run.get('deadline_misses'))}{late}, "
            f"{_n(run.get('unexplained_deadline_misses'))} unexplained; {_n(run['wall_s'])} s, load "
            f"{load['start']:.1f}–{load['end']:.1f}")


SUITE_NODES = (("winding", "winding"), ("pm", "magnet"), ("yoke", "yoke"), ("tooth", "tooth"))


def _mse_max(figures: dict | None) -> str:
    return "–" if not figures else f"{figures['mse_K2']:.2f} / {figures['max_K']:.2f}"


def section_suite(records: dict[str, list[Record]]) -> list[str]:
    """The suite's records: the table of the defaults as they are (the record without a variant), the defaults'
    comparison (`bench_suite.py --defaults`, variant "defaults") and the model class's floor (`--floor`, variant
    "floor"), each with its provenance."""
    found = {r.get("variant"): r for r in records.get("suite", [])}
    lines = ["## The motor suite", ""]
    if not found:
        return lines + _missing("suite")
    main = found.get(None) or next(iter(found.values()))
    lines += [provenance(main), "", *suite_tables(main)]
    compared = found.get("defaults")
    if compared is not None:
        lines += ["Each default against its alternatives (`python tests/benchmarks/bench_suite.py --defaults`):", "",
                  provenance(compared), "", *suite_defaults(compared)]
    for variant in sorted(v for v in found if v and v.startswith("folds")):
        folded = found[variant]
        lines += ["The identify defaults by the decision rule of the method page (`python "
                  "tests/benchmarks/bench_suite.py --defaults --folds 3 --hold-test`): the mean over three folds of "
                  "the nine non-test profiles, each fold trained on six and scored on the three it holds out:", "",
                  provenance(folded), "", *suite_defaults(folded)]
    rejudged = found.get("rejudged")
    if rejudged is not None:
        lines += ["The seeded comparisons judged again by the decision rule's standard-error form (`python "
                  "tests/benchmarks/bench_suite.py --rejudge RECORD ...`; per motor the nine fold × seed "
                  "differences alternative − default, their mean and standard error, t against t0 = 2.306):", "",
                  provenance(rejudged), "", *suite_rejudged(rejudged)]
    bound = found.get("floor")
    if bound is not None:
        lines += ["The four-node model class's floor (`python tests/benchmarks/bench_suite.py --floor`): the "
                  "designer's prior identified on all twelve profiles, the test ones included, and scored on the "
                  "test profiles in-sample (MSE K² / max K). A bound, not a result, and nothing is chosen on it: "
                  "where even it misses the goal, no prior and no default of this model can meet it.", "",
                  provenance(bound), "", *suite_floor(bound)]
    return lines


def section_lag_bank(records: dict[str, list[Record]]) -> list[str]:
    """The motor suite's diagnostic: would more states close the gap to the goal on these data?"""
    lines = ["### More states or more data?", ""]
    banks = records.get("lag_bank", [])
    if not banks:
        return lines + _missing("lag_bank")
    for bank in banks:
        lines += [f"`python tests/benchmarks/bench_lag_bank.py --prior {bank['parameters']['prior']}`: the deployed "
                  "model of the suite's table plus a bank of first-order lags of the node losses and the coolant "
                  f"(time constants {', '.join(f'{t:g}' for t in bank['parameters']['taus_s'])} s: 20 extra states "
                  "per node) fitted to its errors by ridge least squares on the nine non-test profiles (held out) or "
                  "on all twelve (in-sample, a bound); test profiles, float64, MSE K² / max K. A diagnostic: nothing "
                  "is chosen on it.", "", provenance(bank), "", *lag_bank_table(bank)]
    return lines


def lag_bank_table(record: Record) -> list[str]:
    rows = [[m["motor"], name, *(_mse_max(m[node][key]) for key in ("model", "bank_held_out", "bank_in_sample"))]
            for m in record["figures"]["motors"] for node, name in (("winding", "winding"), ("pm", "magnet"))]
    return _table(["motor", "node", "model", "with the bank, fitted held out", "with the bank, in-sample"], rows)


def suite_floor(record: Record) -> list[str]:
    """Per motor and kind, the in-sample test figures of the fit to every profile."""
    rows = []
    for m in record["figures"]["motors"]:
        bound = m.get("floor") or {}
        if "failed" in bound or not bound:
            rows.append([m["motor"], "–", "failed", "", "", "", ""])
            continue
        for kind, figures in bound["test_in_sample"].items():
            reachable = ("yes" if bound["goal_reachable"] else "no") if kind == "hammerstein" else ""
            rows.append([m["motor"], kind, *(_mse_max(figures.get(node)) for node, _ in SUITE_NODES), reachable])
    return _table(["motor", "kind", *(name for _, name in SUITE_NODES), "goal reachable"], rows)


def suite_tables(record: Record) -> list[str]:
    """Every suite motor: identification from each prior on its test profiles (never chosen on), and the observer."""
    goal = "goal: winding and magnet MSE ≤ 2.0 K² and max ≤ 4.7 K, Hammerstein, designer's and auto prior"
    lines = ["Each motor of `examples/suite/` identified with `bench identify --all-kinds --bounds 0.1,10` on its "
             "training profiles and evaluated on its test profiles (pooled, float32, MSE K² / max K; "
             f"{goal}). \"Worse on validation\": the nodes where the Hammerstein model is worse than its LTI "
             "network on the validation profiles; \"(deployed)\": the kind `--kind auto` wrote to `--out`, the "
             "smallest winding + magnet MSE on the validation profiles.", ""]
    if not record["figures"].get("complete", True):
        lines += ["*This record is partial: the run stopped before every motor was measured.*", ""]
    motors = record["figures"]["motors"]
    lines += _table(["motor", "prior", "kind", *(name for _, name in SUITE_NODES), "worse on validation",
                     "identify s"], [r for m in motors for r in _suite_rows(m)])
    observed = [m for m in motors if m.get("observer")]
    if observed:
        lines += ["The observer on the designer's Hammerstein model with the motor's end-winding sensor (`ntc_C`), its "
                  "lag, gradient and offset estimated by `bench observer` or taken from the motor file; test profiles, "
                  "open loop → observer, MSE K²:", ""]
        lines += _table(["motor", "sensor", "winding", "magnet", "observer s"],
                        [r for m in observed for r in _observer_rows(m)])
    return lines


def suite_defaults(record: Record) -> list[str]:
    """Each default of `bench identify` and `bench observer` against its alternatives on the validation profiles."""
    motors = record["figures"]["motors"]
    compared = [m for m in motors if isinstance(m.get("defaults"), dict) and "failed" not in m["defaults"]]
    lines = []
    if compared:
        folds = record["parameters"].get("folds")
        where = (f"mean of {folds} folds' held-out profiles" if folds else "on the validation profiles")
        lines += [f"`bench identify` (Hammerstein winding / magnet MSE K², {where}; the default as the record's code "
                  "had it, a setting in brackets held by both sides):", ""]
        lines += _table(["setting", *(m["motor"] for m in compared)], _default_rows(compared))
        lines += _verdicts({name: {m["motor"]: _identify_sums(m["defaults"].get(name)) for m in compared}
                            for name in compared[0]["defaults"]})
        lines += _seeded_verdicts(compared)
    observed = [m for m in motors if isinstance(m.get("observer_defaults"), dict)
                and "failed" not in m["observer_defaults"]]
    if observed:
        lines += ["`bench observer` on the designer's Hammerstein model, the end-winding NTC estimated (winding / "
                  "magnet MSE K² on the validation profiles, open loop first):", ""]
        lines += _table(["setting", *(m["motor"] for m in observed)], _observer_default_rows(observed))
        lines += _verdicts({name: {m["motor"]: _observer_sums(m["observer_defaults"].get(name)) for m in observed}
                            for name in observed[0]["observer_defaults"]})
    return lines


def _identify_sums(row: dict | None) -> tuple[str, dict[str, float]] | None:
    """An identify default's row: the default's name and each setting's Hammerstein winding + magnet MSE."""
    if not row:
        return None
    settings = {"default": row["default"], **row["alternatives"]}
    return "default", {name: fig["hammerstein"]["winding"] + fig["hammerstein"]["pm"]
                       for name, fig in settings.items() if fig and "hammerstein" in fig}


def _observer_sums(row: dict | None) -> tuple[str, dict[str, float]] | None:
    """An observer default's row: the default's name and each setting's winding + magnet MSE with the filter."""
    if not row:
        return None
    return row["default"], {name: fig["winding"]["observer_mse_K2"] + fig["pm"]["observer_mse_K2"]
                            for name, fig in row["scores"].items() if fig and "winding" in fig and "pm" in fig}


def _verdicts(sums: dict[str, dict[str, tuple[str, dict[str, float]] | None]]) -> list[str]:
    """Per default: on how many motors it has the smallest winding + magnet MSE, and what won elsewhere."""
    lines = []
    for name, motors in sums.items():
        measured = {motor: v for motor, v in motors.items() if v and v[0] in v[1]}
        if not measured:
            continue
        best = {motor: min(scores, key=scores.get) for motor, (_, scores) in measured.items()}
        held = [motor for motor, (default, scores) in measured.items() if scores[default] <= min(scores.values())]
        # a setting with no effect there (every alternative within 0.1 % of the default) decides nothing
        inert = [motor for motor, (default, scores) in measured.items()
                 if max(scores.values()) - min(scores.values()) <= 1e-3 * scores[default]]
        lost = "; ".join(f"{best[motor]} on {motor} ({measured[motor][1][best[motor]]:.2f} against "
                         f"{measured[motor][1][measured[motor][0]]:.2f})" for motor in measured if motor not in held)
        lines.append(f"- {name}: the default has the smallest winding + magnet MSE on {len(held)} of {len(measured)} "
                     f"motors" + (f" (no effect on {len(inert)}: every setting within 0.1 %)" if inert else "")
                     + (f"; better: {lost}" if lost else ""))
    return [*lines, ""] if lines else []


def _seeded_verdicts(motors: list[dict]) -> list[str]:
    """With several swarm seeds (`bench_suite.py --seeds N`): per default and alternative, where it wins under the
    decision rule its record was judged by (the paired standard-error test, or before 2026-12-08 the seeds'
    spread as a margin), where it loses, and where the rule cannot tell."""
    lines = []
    for name in motors[0]["defaults"]:
        rows = {m["motor"]: (m["defaults"].get(name) or {}).get("verdict") or {} for m in motors}
        for alt in sorted({alt for verdicts in rows.values() for alt in verdicts}):
            said = {motor: verdicts[alt] for motor, verdicts in rows.items() if "default_K2" in verdicts.get(alt, {})}
            if not said:
                continue
            paired = all("t" in v for v in said.values())
            parts = [f"{motor} {v['default_K2']:.2f} → {v['alternative_K2']:.2f} ("
                     + (f"d {v['mean_difference_K2']:+.2f} ± {v['standard_error_K2']:.2f}, t {v['t']:+.2f}"
                        if paired else f"margin {v['margin_K2']:.2f}") + f": {v['verdict']})"
                     for motor, v in said.items()]
            wins = sum(v["verdict"] == "alternative" for v in said.values())
            losses = sum(v["verdict"] == "default" for v in said.values())
            rule = "beyond t0 standard errors of the paired differences" if paired else "beyond the seeds' spread"
            lines.append(f"- {name}, {alt} against the default, {rule}: better on {wins}, worse on "
                         f"{losses} of {len(said)} motors; " + "; ".join(parts))
    return [*lines, ""] if lines else []


def suite_rejudged(record: Record) -> list[str]:
    """The seeded folds records judged again under today's rule (`bench_suite.py --rejudge`)."""
    rows = [[j["record"].removeprefix("suite-folds-").removesuffix(".json"), j["motor"], j["prior"],
             f"{j['default']}: {j['alternative']}",
             "–" if "t" not in j else f"{j['default_K2']:.2f} → {j['alternative_K2']:.2f}",
             "–" if "t" not in j else f"{j['mean_difference_K2']:+.2f} ± {j['standard_error_K2']:.2f} "
                                      f"(t {j['t']:+.2f})",
             j["verdict"], j.get("verdict_then") or "–"] for j in record["figures"]["rejudged"]]
    return _table(["comparison", "motor", "prior", "default: alternative", "default → alternative K²",
                   "mean difference ± SE", "verdict", "verdict of its day"], rows)


def _observer_default_rows(motors: list[dict]) -> list[list[str]]:
    def cell(scores: dict | None, side: str) -> str:
        w, m = (scores or {}).get("winding"), (scores or {}).get("pm")
        return "–" if not (w and m) else f"{w[side + '_mse_K2']:.2f} / {m[side + '_mse_K2']:.2f}"

    first = motors[0]["observer_defaults"]
    name, setting = next(iter(first.items()))
    rows = [["open loop", *(cell(m["observer_defaults"][name]["scores"][setting["default"]], "open_loop")
                            for m in motors)]]
    for name, setting in first.items():
        for alt in setting["scores"]:
            mark = " (default)" if alt == setting["default"] else ""
            rows.append([f"{name}: {alt}{mark}", *(cell(m["observer_defaults"].get(name, {}).get("scores", {})
                                                        .get(alt), "observer") for m in motors)])
    return rows


def _suite_rows(motor: dict) -> list[list[str]]:
    rows = []
    for row in motor["priors"]:
        if "failed" in row:
            rows.append([motor["motor"], row["prior"], "failed", _sentence(row["failed"])[:80], "", "", "", "", ""])
            continue
        deployed = row.get("deployed_kind")     # records before --kind auto have none
        for kind in dict.fromkeys(("hammerstein", "lti-lptn", deployed or "hammerstein")):
            test = row["test"].get(kind, {})
            ham = kind == "hammerstein"
            name = f"{kind} (deployed)" if kind == deployed else kind
            rows.append([motor["motor"], row["prior"], name, *(_mse_max(test.get(node)) for node, _ in SUITE_NODES),
                         (", ".join(row["hammerstein_worse_on_validation"]) or "–") if ham else "",
                         _n(row["identify_s"]) if ham else ""])
    return rows


def _observer_rows(motor: dict) -> list[list[str]]:
    rows = []
    for run in motor["observer"]:
        if "failed" in run:
            rows.append([motor["motor"], "failed", _sentence(run["failed"])[:80], "", ""])
            continue
        cells = []
        for node, _ in SUITE_NODES[:2]:
            fig = (run.get("pooled") or {}).get(node) or {}
            cells.append("–" if not fig else f"{fig['open_loop_mse_K2']:.2f} → {fig['observer_mse_K2']:.2f}")
        rows.append([motor["motor"], run["how"], *cells, _n(run["observer_s"])])
    return rows


def _default_rows(motors: list[dict]) -> list[list[str]]:
    def cell(figures: dict | None) -> str:
        ham = (figures or {}).get("hammerstein")
        return "–" if not ham else f"{ham['winding']:.2f} / {ham['pm']:.2f}"

    rows = []
    for name in motors[0]["defaults"]:
        first = motors[0]["defaults"][name]
        held = f" ({' '.join(first['held'])})" if first.get("held") else ""
        rows.append([f"{name}{held}: default", *(cell(m["defaults"].get(name, {}).get("default")) for m in motors)])
        for alt in first["alternatives"]:
            rows.append([f"{name}: {alt}",
                         *(cell(m["defaults"].get(name, {}).get("alternatives", {}).get(alt)) for m in motors)])
    return rows


@single_record("xcp", "XCP slave (Python node and firmware)")
def section_xcp(record: Record) -> list[str]:
    f = record["figures"]
    rows = [[name, _n(v["p50"], 1), _n(v["p99"], 1), _n(v["max"], 1)] for name, v in f["handler_us"].items()]
    rows.append(["DAQ sample, 4 ODTs, per model step", _n(f["daq_sample_us"]["p50"], 1),
                 _n(f["daq_sample_us"]["p99"], 1), _n(f["daq_sample_us"]["max"], 1)])
    for name, v in f["row_with_step_us"].items():
        rows.append([f"a row with its model step and replies, {name.replace('_', ' ')}", _n(v["p50"], 1),
                     _n(v["p99"], 1), _n(v["max"], 1)])
    lines = [f"In-process, against the model step period of {_n(f['dt_us'])} µs (commands run between frames, DAQ "
             f"after the step's replies; {_n(f['daq_packets'])} DAQ packets for {_n(f['model_steps'])} model steps):",
             "", *_table(["µs", "p50", "p99", "max"], rows)]
    run = f.get("daq_run")
    if run:
        why = run["host_stderr"].removeprefix("bench: host: ")
        verdict = "clean." if run["host_exit"] == 0 else f"NOT clean ({why})."
        lines += [f"A run recorded by DAQ (pyxcp on the bus, `bench host` replaying {_n(run['rows'])} rows of the "
                      f"40 °C validation run): {_n(run['model_steps'])} model steps, "
                      f"{', '.join(_n(n) for n in run['daq_packets_per_odt'])} DAQ packets per ODT, "
                      f"{run['lost']} lost, "
                      f"max \\|DAQ − CAN reply\\| {_n(run['max_abs_daq_minus_can_C'], 4)} °C (the replies carry "
                      f"0.01 °C); `bench host` " + verdict]
    fw = f.get("firmware")
    if fw:
        lines += ["", *_xcp_firmware(fw)]
    return lines


def _xcp_firmware(fw: dict) -> list[str]:
    """The firmware's C slave: cycles per command and DAQ sample, WCET bounds and sections beside its baseline."""
    rows = [[name, _n(v["p50"]), _n(v["max"])] for name, v in fw["handler_cycles"].items()]
    rows.append(["DAQ sample, 4 ODTs, per model step", _n(fw["daq_sample_cycles"]["p50"]),
                 _n(fw["daq_sample_cycles"]["max"])])
    rows.append(["the model step itself (Timing4)", _n(fw["model_step_cycles"]["p50"]),
                 _n(fw["model_step_cycles"]["max"])])
    lines = [f"The firmware node's C slave ({fw['elf']} in the emulated Cortex-M4F; cycles, whatever the machine's "
             f"load; a command's cycles are node_on_frame's whole call):", "",
             *_table(["cycles", "p50", "max"], rows)]
    base = fw.get("baseline")
    daq = fw.get("wcet_cycles_daq", {})
    bound_rows = [[f"WCET bound of {name}, cycles",
                   _n(base["wcet_cycles"].get(name)) if base and name in base["wcet_cycles"] else "–",
                   _n(cycles), _n(daq.get(name))] for name, cycles in fw["wcet_cycles"].items()]
    section_rows = [[f"{name}, bytes", _n(base["sections"].get(name, 0)) if base else "–", _n(size), ""]
                    for name, size in fw["sections"].items()]
    before = f"revision {base['revision']}, before the slave" if base else "before"
    lines += ["The timing image's WCET bounds (IPET, rows in order) without an XCP master and with the DAQ tables "
              "full (16 lists, 16 ODTs of 7 bytes), and the shipped ELF's sections:", "",
              *_table(["", before, "with the slave", "with the DAQ tables full"], bound_rows + section_rows)]
    return lines


@single_record("xcp_observer", "XCP: an observer's cells in the firmware")
def section_xcp_observer(record: Record) -> list[str]:
    """An observer's firmware serving its XCP cells, beside the baseline revision's firmware of the same artifact."""
    f = record["figures"]
    base = f.get("baseline") or {}

    def cell(figures: dict, key: str, name: str) -> str:
        value = figures.get(key, {}).get(name)
        return "no bound" if isinstance(value, str) else _n(value)     # a loop without a stated bound

    rows = [[f"WCET bound of {name}" + (", DAQ tables full" if key == "wcet_cycles_daq" else ""),
             cell(base, key, name), cell(f, key, name)]
            for key in ("wcet_cycles", "wcet_cycles_daq") for name in f[key]
            if key == "wcet_cycles" or name in ("node_on_frame", "node_on_xcp", "xcp_event")]
    for key, label in (("model_step_cycles", "the model step (Timing4)"), ("daq_sample_cycles", "a DAQ sample")):
        rows.append([f"{label}, p50 / max", *(f"{_n(g[key]['p50'])} / {_n(g[key]['max'])}" if g.get(key) else "–"
                                              for g in (base, f))])
    rows += [[f"{name}, p50", _n(base.get("handler_cycles", {}).get(name, {}).get("p50")), _n(v["p50"])]
             for name, v in f["handler_cycles"].items()]
    rows += [[f"{name}, bytes", _n(base.get("sections", {}).get(name)), _n(size)]
             for name, size in f["sections"].items()]
    before = f"revision {base['revision']}" if base else "before"

    def entries(figures: dict) -> str:
        return ", ".join(n for odt in figures.get("daq_entries", []) for n in odt)

    other = (f" (the baseline, which does not serve them, over {entries(base)})"
             if base and entries(base) != entries(f) else "")
    return [f"The observer {record['parameters']['model']}'s firmware in the emulated Cortex-M4F (cycles, whatever the "
            f"machine's load), a {_n(record['parameters']['rows'])}-row session with a DAQ list of three ODTs over "
            f"{entries(f)}{other}:", "", *_table(["cycles", before, "serving the observer's cells"], rows)]


@single_record("listeners", "CAN tools attached to a run")
def section_listeners(record: Record) -> list[str]:
    """Which of python-can's logger and viewer and cantools' monitor saw every frame of a run, per pacing."""
    f = record["figures"]

    def share(value: float | None) -> str:
        return "–" if value is None else f"{100 * min(value, 1.0):.1f} %"

    rows = []
    for label, summary in f["summary"].items():
        seen = summary["share_min"]
        rows.append([label, _n(summary["rows_per_s"]), _n(summary["frames_per_s"]), share(seen["logger"]),
                     share(seen["viewer"]), share(seen["monitor"])])
    repeats = record["parameters"]["repeats"]
    return [f"`bench run --rows {record['parameters']['rows']}` on udp_multicast with the three tools attached, "
            f"{repeats} run(s) per pacing, alternating; the least share of the run's own log's frames a tool saw "
            "over those runs (a share above 100 %, the target's heartbeats around the run, is shown as 100 %):",
            "", *_table(["pacing", "rows/s", "frames/s", "can.logger", "can.viewer", "cantools monitor"], rows)]


# Each benchmark (a script `tests/benchmarks/bench_<name>.py`, its records' "benchmark") and its section, in page order.
SECTIONS: dict[str, Section] = {
    "accuracy": section_accuracy, "firmware": section_firmware, "firmware_node": section_firmware_node,
    "firmware_timing": section_firmware_timing, "firmware_observer": section_firmware_observer,
    "can": section_can, "sitting": section_sitting, "memory": section_memory, "soak": section_soak,
    "campaign": section_campaigns,
    "identify": section_identify, "data": section_data, "plant_distributed": section_plant_distributed,
    "observer": section_observer, "speed": section_speed,
    "robustness": section_robustness, "fault_sweep": section_fault_sweep, "suite": section_suite,
    "lag_bank": section_lag_bank, "xcp": section_xcp,
    "xcp_observer": section_xcp_observer, "listeners": section_listeners}
BENCHMARKS = tuple(SECTIONS)


def render_results(records: dict[str, list[Record]] | None = None) -> str:
    records = load_records() if records is None else records
    lines = ["<!-- generated from docs/results/*.json by docs/_ext/results_page.py; do not edit -->", ""]
    for section in SECTIONS.values():
        lines += section(records)
    return "\n".join(lines).rstrip() + "\n"


def render_table5(records: dict[str, list[Record]] | None = None) -> str:
    record = _one(load_records() if records is None else records, "accuracy")
    return "\n".join(table5(record) if record else _missing("accuracy")) + "\n"


def render_ipm(records: dict[str, list[Record]] | None = None) -> str:
    record = _one(load_records() if records is None else records, "accuracy")
    if record is None or "ipm" not in record["figures"]:
        return "\n".join(_missing("accuracy")) + "\n"
    return "\n".join(ipm_table(record)) + "\n"


def _observer_fragment(table: Callable[[Record], list[str]], part: str | None = None) -> Callable[..., str]:
    """A renderer of one observer table for the method page (the line saying how to measure it without a record)."""
    def render(records: dict[str, list[Record]] | None = None) -> str:
        record = _one(load_records() if records is None else records, "observer")
        if record is None or (part and part not in record["figures"]):
            return "\n".join(_missing("observer")) + "\n"
        return "\n".join(table(record)) + "\n"
    render.__doc__ = table.__doc__
    return render


render_observer = _observer_fragment(observer_builtin_table)
render_observer_ipm = _observer_fragment(observer_ipm_table, "ipm")
render_observer_forms = _observer_fragment(observer_forms_table)


# ---------------------------------------------------------------------------------------------- the README
def render_headline(records: dict[str, list[Record]] | None = None) -> str:
    """The README's table of headline results (links relative to the repository root)."""
    records = load_records() if records is None else records
    rows = []
    accuracy, firmware, can, soak = (_one(records, n) for n in ("accuracy", "firmware", "can", "soak"))
    if accuracy:
        t5 = {(r["kind"], r["dt_s"]): r for r in accuracy["figures"]["builtin"]["table5"]}
        ham, lti = t5.get(("hammerstein", 0.5)), t5.get(("lti-lptn", 0.5))
        if ham and lti:
            rows.append(["accuracy, 40 °C validation run, Δt 0.5 s (winding / PM RMSE)",
                         f"Hammerstein {_winding_pm(ham)}, LTI LPTN {_winding_pm(lti)}",
                         "[accuracy](docs/results.md#accuracy)"])
            balanced = accuracy["figures"]["builtin"]["balanced_max_abs_f32_minus_f64_C"].get("hammerstein")
            rows.append(["float32 against float64, whole run (deployed realization)",
                         f"{_e(ham['max_abs_f32_minus_f64_C'])} °C (balanced realization: {_e(balanced)} °C)",
                         "[method](docs/method.md#numerical-conditioning-tables-24)"])
    if can and can["figures"].get("default_run"):
        runs = can["figures"]["default_run"]
        worst = max((_worst(r.get("max_abs_can_minus_float32_C")) or 0.0) for r in runs)
        rows.append(["CAN temperatures against the offline float32 reference (default run)",
                     f"max {_n(worst, 4)} °C, {sum(r.get('missing') or 0 for r in runs)} rows missing, verdict "
                     + ", ".join(sorted({str(r['verdict']) for r in runs})), "[bus](docs/results.md#bus-throughput)"])
        rows.append(["`bench run`, the default run, lockstep",
                     " and ".join(f"{_n(r['rows_per_s'])} rows/s ({_n(r['wall_s'], 1)} s)" for r in runs),
                     "[bus](docs/results.md#bus-throughput)"])
    if firmware:
        ham = next((r for r in firmware["figures"]["packaged"] if r["kind"] == "hammerstein"), None)
        if ham:
            rows.append(["Hammerstein step as Cortex-M4F firmware",
                         f"{_n(ham['cycles']['p50'])} cycles ({_n(ham['exec_us_at_90MHz']['p50'], 1)} µs at 90 MHz), "
                         f"{ham['mismatches']} mismatches with Python; flash {_n(ham['flash_bytes'])} B, RAM "
                         f"{_n(ham['ram_bytes'])} B", "[firmware](docs/results.md#firmware)"])
    if soak:
        f, p = soak["figures"], soak["parameters"]
        rows.append([f"{_count(p['runs'], 'run')} with {p['drop'] * 100:g} % drop, {p['corrupt'] * 100:g} % "
                     f"corruption, {p['kills']} target kill each",
                     f"{f['undetected']} faults undetected, max \\|CAN − clean run\\| "
                     f"{_n(f['max_abs_can_minus_clean_C'], 4)} °C", "[soak](docs/results.md#soak)"])
    if accuracy and "ipm" in accuracy["figures"]:
        ham = next((m for m in accuracy["figures"]["ipm"]["models"] if m["kind"] == "hammerstein"), None)
        if ham:
            rows.append(["your own motor: 60 kW IPM example, held-out profiles (winding / PM RMSE)",
                         f"Hammerstein {_winding_pm(ham)}", "[your own motor](docs/tutorials/own-motor.md)"])
    suite = next((r for r in records.get("suite", []) if r.get("variant") is None), None)
    if suite:
        cells = []
        for motor in suite["figures"]["motors"]:
            row = next((r for r in motor["priors"] if r.get("prior") == "designer" and "test" in r), None)
            if row:   # the model `bench identify` deployed (--kind auto), its kind named where not Hammerstein
                kind = row.get("deployed_kind", "hammerstein")
                got = row.get("test_deployed") or row["test"]["hammerstein"]
                named = "" if kind == "hammerstein" else f" ({kind})"
                cells.append(f"{motor['motor']} {got['winding']['mse_K2']:.1f} / {got['pm']['mse_K2']:.1f}{named}")
        if cells:
            rows.append(["motors the model cannot be: the suite's test profiles, the model `bench identify` deploys "
                         "from the designer's prior (winding / magnet MSE K², goal ≤ 2.0)", ", ".join(cells),
                         "[suite](docs/results.md#the-motor-suite)"])
        observed = _suite_output_bias(suite)
        if observed:
            rows.append(["... with the end-winding NTC and the observer's output bias (its lag, gradient and offset "
                         "estimated; winding MSE K² open loop → observer, the magnet the open loop's)",
                         ", ".join(observed), "[suite](docs/results.md#the-motor-suite)"])
    dates = sorted(_date(r) for rs in records.values() for r in rs)
    machines = sorted({f"{r['machine']['cpu']}, {r['machine']['cpus']} CPUs" for rs in records.values() for r in rs})
    when = dates[0] if dates and dates[0] == dates[-1] else f"{dates[0]} to {dates[-1]}" if dates else ""
    loads = [v for rs in records.values() for r in rs for v in r["load_average"].values()]
    intro = (f"Measured {when} on {'; '.join(machines)}, a machine shared with other jobs (load average up to "
             f"{max(loads):.1f}), by the scripts in `tests/benchmarks/`; the [results page](docs/results.md) holds "
             "each one's conditions and the full tables.") if dates else \
        "Not measured yet: run the scripts in `tests/benchmarks/`."
    return "\n".join([README_BEGIN, "", intro, "", *_table(["what", "result", "details"], rows), README_END]) + "\n"


def _suite_output_bias(suite: Record) -> list[str]:
    """Per suite motor, the observer run with an output bias (as its `bench observer` JSON says it tuned):
    winding MSE open loop → observer."""
    from target_sim.artifact import OUTPUT_BIAS_KINDS

    cells = []
    for motor in suite["figures"]["motors"]:
        run = next((o for o in motor.get("observer") or []
                    if (o.get("tuning") or {}).get("bias") in OUTPUT_BIAS_KINDS), None)
        winding = ((run or {}).get("pooled") or {}).get("winding")
        if winding:
            cells.append(f"{motor['motor']} {winding['open_loop_mse_K2']:.1f} → {winding['observer_mse_K2']:.2f}")
    return cells


def splice_readme(readme: str, headline: str) -> str:
    """The README with its headline block replaced by `headline` (ValueError when the markers are missing)."""
    start, end = readme.find(README_BEGIN), readme.find(README_END)
    if start < 0 or end < start:
        raise ValueError("README.md has no headline-results markers")
    return readme[:start] + headline + readme[end + len(README_END) + 1:]
