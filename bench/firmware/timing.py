"""`bench firmware timing`: the estimator beside the motor control on the emulated core.

The image is the node and the model with the field-oriented current loop's interrupt (bench/firmware/foc_isr.c,
`build_firmware(isr=True)`), run in `InterruptedFirmware`: the interrupt every clock/rate cycles, the node in the
background handling a drive's frames as the bus delivers them (RESET, START, then each row's frames; a row every
`data_sample_period`, its frames 250 µs apart, each frame's arrival phase against the PWM drawn uniformly from a
seeded generator: the bus and the PWM timer are not synchronised). Before each interrupt the ADC's DMA leaves new
samples (`foc_adc`: a rotating current vector with noise, the angle advancing at a 200 Hz electrical frequency)
and the references step now and then so the PI controllers saturate and the anti-windup acts.

Measured: the response time of every frame that ran a model step (its arrival -> node_on_frame returned with the
temperatures queued) and of the other frames; each interrupt's latency (release -> the handler's first
instruction), how much of it the background caused (the instruction in progress at the release) and the lazy FP
stacking the background's FP context costs it; the CPU load of each task; the model's outputs bit for bit against
the same node without the interrupt. The static bounds (`target_sim.firmware.wcet`: implicit path enumeration) of
the model step (fw_step, or an observer's fw_obs_step), node_on_frame (rows in order) and the handler are set
beside two measured maxima: the drive's, and that of a search for the inputs that take the most cycles
(`bench.firmware.adversarial`), so the gap between bound and truth is shown from both ends.

The bounds are per XCP mode (`XCP_MODES`): a drive run has no XCP master, so the slave's DAQ sampling and sending
(bench/firmware/xcp.c: xcp_event, xcp_flush) cannot run, which the C states as facts the analysis takes (its DAQ
loops 0 times, the globals no master ever set at their power-on 0, so the tests of them decide their branches);
node_on_frame's bound with a master running the DAQ tables' whole budget is reported beside it, against a run of
the drive under that DAQ (`bench.firmware.daqload`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.errors import BenchError
from dbc import Command
from dbc.codec import FrameCodec
from dbc.contract import RESET_SIGNALS, split_temperatures
from host.replay import encode_row
from target_sim.artifact import ModelArtifact
from target_sim.firmware.elf import ElfImage, FirmwareError
from target_sim.firmware.interrupts import InterruptedFirmware
from target_sim.firmware.motor_control import HANDLER, motor_control_core, start_motor_control
from target_sim.firmware.node_engine import FirmwareNode
from target_sim.firmware.wcet import WcetError, loop_facts, value_facts, wcet
from target_sim.xcp.daq import MAX_DAQ_LISTS, MAX_ODTS

FRAME_SPACING_S = 250e-6          # between the frames of one row (a 500 kbit/s bus with other traffic)
CLOCKS_MHZ = (90, 168)


@dataclass(frozen=True)
class XcpMode:
    """What an XCP master does during a run, as the WCET analysis takes it: the DAQ lists and ODTs it configured
    (`loop_facts`' daq) and the C's `wcet-value(name)` facts (the globals that keep a value all run long)."""

    name: str
    description: str
    daq: tuple[int, int]


XCP_MODES = (
    XcpMode("no_master", "no XCP master since power-on (a drive run)", (0, 0)),
    XcpMode("master_daq", f"an XCP master running the DAQ tables' whole budget ({MAX_DAQ_LISTS} lists, {MAX_ODTS} "
            "ODTs)", (MAX_DAQ_LISTS, MAX_ODTS)),
)
DRIVE_MODE, DAQ_MODE = XCP_MODES


def _percentiles(values: list[int] | np.ndarray, scale: float = 1.0) -> dict:
    if len(values) == 0:
        return {"p50": None, "p99": None, "max": None}
    data = np.asarray(values, dtype=float) * scale
    return {"p50": round(float(np.percentile(data, 50)), 3), "p99": round(float(np.percentile(data, 99)), 3),
            "max": round(float(data.max()), 3)}


def _frames(artifact: ModelArtifact, drive: np.ndarray, initial, measurement: np.ndarray | None = None) -> list[list]:
    """The host's frames: [RESET's frames, START], then one list per row (with `measurement`, an observer's host
    channels per row, the row's measurement frames first)."""
    codec = FrameCodec("HOST")
    reset = [codec.encode(name, {"Step": 0, **signals}) for name, signals in
             split_temperatures([round(float(v), 2) for v in initial], RESET_SIGNALS).items()]
    reset.append(codec.encode("Control", {"Command": int(Command.RESET), "Step": 0}))
    start = [codec.encode("Control", {"Command": int(Command.START), "Step": 0})]
    return [reset, start, *(encode_row(codec, row, [float(v) for v in values],
                                       None if measurement is None else [float(v) for v in measurement[row]])
                            for row, values in enumerate(drive))]


def _reference_outputs(artifact: ModelArtifact, image: ElfImage, frames: list[list]) -> list[bytes]:
    node = FirmwareNode(artifact, image)
    return [bytes(reply.data) for group in frames for frame in group for reply in node.handle(frame)
            if reply.arbitration_id in _TEMPERATURE_IDS]


_TEMPERATURE_IDS: set[int] = set()


def _temperature_ids() -> set[int]:
    from dbc.contract import REPLY_MESSAGES
    from dbc.database import frame_id

    return {frame_id(name) for name in REPLY_MESSAGES}


@dataclass
class FrameRun:
    """A drive's frames through the node beside the interrupt: the core, the node, the jobs of the frames that
    ran a model step and of the others, the temperatures' reply bytes, the cycle the run started at."""

    fw: InterruptedFirmware
    node: FirmwareNode
    step_jobs: list
    other_jobs: list
    outputs: list[bytes]
    origin: int


def run_frames(artifact: ModelArtifact, image: ElfImage, drive: np.ndarray, initial, *, isr_rate_hz: float,
               clock_mhz: float, seed: int = 0, measurement: np.ndarray | None = None) -> FrameRun:
    """The drive's frames (and an observer's measurement frames) through the node with the interrupt (the module
    docstring's run)."""
    _TEMPERATURE_IDS.update(_temperature_ids())
    clock_hz = clock_mhz * 1e6
    fw_box: list[InterruptedFirmware] = []

    def core(elf: ElfImage) -> InterruptedFirmware:
        fw_box.append(motor_control_core(elf, rate_hz=isr_rate_hz, clock_hz=clock_hz))
        return fw_box[-1]

    try:
        node = FirmwareNode(artifact, image, core=core)
    except FirmwareError as exc:
        raise BenchError(str(exc)) from None
    fw = fw_box[0]
    period = fw.period
    rng = start_motor_control(fw, rate_hz=isr_rate_hz, clock_hz=clock_hz, seed=seed)
    frames = _frames(artifact, drive, initial, measurement)
    row_cycles = artifact.data_sample_period * clock_hz
    origin = fw.now + period
    step_jobs, other_jobs, outputs = [], [], []
    steps_seen = 0
    for index, group in enumerate(frames):
        base = origin + index * row_cycles
        for position, frame in enumerate(group):
            release = int(base + position * FRAME_SPACING_S * clock_hz + rng.integers(period))
            fw.release_at(release)
            replies = node.handle(frame)
            job = fw.jobs[-1]
            steps = sum(node.m4_cycles.values())
            (step_jobs if steps > steps_seen else other_jobs).append(job)
            steps_seen = steps
            outputs += [bytes(reply.data) for reply in replies if reply.arbitration_id in _TEMPERATURE_IDS]
    return FrameRun(fw, node, step_jobs, other_jobs, outputs, origin)


def measure(artifact: ModelArtifact, image: ElfImage, drive: np.ndarray, initial, *, isr_rate_hz: float = 10_000.0,
            clock_mhz: float = 90.0, seed: int = 0, measurement: np.ndarray | None = None) -> dict:
    """Run the drive through the node with the interrupt; the figures of the module docstring (cycles, µs)."""
    run = run_frames(artifact, image, drive, initial, isr_rate_hz=isr_rate_hz, clock_mhz=clock_mhz, seed=seed,
                     measurement=measurement)
    frames = _frames(artifact, drive, initial, measurement)
    bit_exact = run.outputs == _reference_outputs(artifact, image, frames)
    clock_hz = clock_mhz * 1e6
    span_s = (run.fw.now - run.origin) / clock_hz
    return _figures(run.fw, run.node, run.step_jobs, run.other_jobs, run.fw.period, clock_hz, span_s, bit_exact)


def _step_cycles(fw: InterruptedFirmware) -> tuple[list[int], list[int]]:
    """(own cycles, timeline cycles) of each model step from the node's pair of DWT_CYCCNT reads around fw_step."""
    reads = fw.dwt_reads
    own = [after[1] - before[1] for before, after in zip(reads[0::2], reads[1::2], strict=False)]
    wall = [after[0] - before[0] for before, after in zip(reads[0::2], reads[1::2], strict=False)]
    return own, wall


def _figures(fw: InterruptedFirmware, node: FirmwareNode, step_jobs, other_jobs, period: int, clock_hz: float,
             span_s: float, bit_exact: bool) -> dict:
    events = fw.isr_events
    latency = [event.latency for event in events]
    busy = [event.busy for event in events]
    preempting = [event for event in events if event.preempted is not None]
    idle = [event for event in events if event.preempted is None]
    own_step, wall_step = _step_cycles(fw)
    us = 1e6 / clock_hz
    step_total = sum(own_step)
    frame_total = sum(job.cycles for job in (*step_jobs, *other_jobs)) - step_total
    isr_load = float(np.mean(busy)) / period if busy else 0.0
    loads = {"current_loop_isr": round(isr_load, 5), "model_step": round(step_total / clock_hz / span_s, 7),
             "frame_handling": round(frame_total / clock_hz / span_s, 7)}
    loads["idle"] = round(1.0 - sum(loads.values()), 5)
    return {
        "clock_mhz": clock_hz / 1e6, "isr_period_cycles": period, "bit_exact": bit_exact,
        "frames": len(step_jobs) + len(other_jobs), "model_steps": len(step_jobs),
        "response_time_us": _percentiles([job.response for job in step_jobs], us),
        "response_time_cycles": _percentiles([job.response for job in step_jobs]),
        "frame_response_time_us": _percentiles([job.response for job in other_jobs], us),
        "preemptions_per_step": _percentiles([job.preemptions for job in step_jobs]),
        "measured_max_cycles": {"fw_step_with_dwt_reads": max(own_step, default=None),
                                "node_on_frame": max((job.cycles for job in (*step_jobs, *other_jobs)),
                                                     default=None),
                                HANDLER: max((event.handler_cycles for event in events), default=None)},
        "step_cycles_with_preemption": _percentiles(wall_step),
        "isr_latency_cycles": {**_percentiles(latency), "min": min(latency, default=None),
                               "jitter": (max(latency) - min(latency)) if latency else None},
        "isr_latency_idle_cycles": _percentiles([event.latency for event in idle]),
        "isr_latency_preempting_cycles": _percentiles([event.latency for event in preempting]),
        "isr_wait_caused_by_background_cycles": _percentiles([event.wait for event in preempting]),
        "isr_handler_cycles": _percentiles([event.handler_cycles for event in events]),
        "isr_busy_cycles": _percentiles(busy),
        "isr_lazy_fp_stacking": {"events": sum(event.lazy_fp for event in events), "of": len(events),
                                 "cycles_each": fw._timeline.costs.lazy_fp + fw._timeline.costs.fp_exit},
        "isr_tail_chained": sum(event.tail_chained for event in events),
        "isr_events": len(events), "isr_releases_skipped_idle": fw.skipped_releases,
        "masking_instructions": fw._masking,
        "cpu_load": loads,
        "stack_used_bytes": fw.stack_used(),
    }


def model_step_function(image: ElfImage) -> str:
    """The model step the node runs: the observer's (fw_obs_step) when the image has one, else fw_step."""
    return "fw_obs_step" if "fw_obs_step" in image.symbols else "fw_step"


def timed_functions(image: ElfImage) -> tuple[str, ...]:
    """The functions `bench firmware timing` bounds and measures: the model step, the frame handler, the ISR."""
    return (model_step_function(image), "node_on_frame", HANDLER)


def timing_sources(artifact: ModelArtifact) -> dict[str, str]:
    """The sources of `artifact`'s timing image (what its loop annotations are read from)."""
    from bench.firmware.codegen import generate
    from bench.firmware.toolchain import firmware_sources

    return firmware_sources(generate(artifact), isr=True)


def static_bounds(image: ElfImage, artifact: ModelArtifact, *, lost_rows: int = 0, mode: XcpMode = DRIVE_MODE,
                  functions: tuple[str, ...] | None = None) -> dict:
    """WCET bounds (IPET, `target_sim.firmware.wcet`) of the model step, node_on_frame (at most `lost_rows` lost
    rows per frame) and the handler (or of `functions`), in the XCP `mode`."""
    sources = timing_sources(artifact)
    facts = loop_facts(sources, lost_rows, mode.daq)
    values = value_facts(sources, mode.name)
    out: dict = {}
    for function in functions or timed_functions(image):
        try:
            out[function] = wcet(image, function, facts, values).cycles
        except WcetError as exc:
            raise BenchError(f"no static bound of {function}: {exc}") from None
    return out


def direct_step_max(artifact: ModelArtifact, image: ElfImage, drive: np.ndarray, initial,
                    measurement: np.ndarray | None = None) -> int:
    """The most cycles of the model step called alone (entry to return, as the bound counts) over the drive's steps
    (`bench firmware check`'s run: the node's DWT reads around the call add a few cycles of their own); an
    observer's steps take the raw channels of `measurement`, the host's channels per row (none: no reading)."""
    from bench.firmware.check import check_firmware
    from target_sim.observer import has_observer

    raw = None
    if has_observer(artifact):
        from target_sim.observer.node import measurement_width, raw_channels, raw_sources

        host = measurement if measurement is not None else np.full((len(drive), measurement_width(artifact)), np.nan)
        raw = raw_channels(raw_sources(artifact), drive, host)
    result = check_firmware(artifact, image, drive, initial, raw)   # FirmwareEstimator takes the parsed image
    return int(result["cycles"]["max"])


def adversarial_maxima(artifact: ModelArtifact, image: ElfImage, *, evaluations: int, isr_rate_hz: float,
                       seed: int = 0) -> dict:
    """The most cycles the input search (`bench.firmware.adversarial`) found for the model step (called alone) and
    for node_on_frame and the handler (a run of frames beside the interrupt at CLOCKS_MHZ[0]); `evaluations`
    candidates each (0: no search, None for each)."""
    from bench.firmware.adversarial import frame_scenario, maximize, step_scenario

    step = model_step_function(image)
    if evaluations <= 0:
        return {step: None, "node_on_frame": None, HANDLER: None}
    objective, dimension = step_scenario(artifact, image)
    found_step = maximize(objective, dimension, evaluations=evaluations, seed=seed)
    frames, dimension = frame_scenario(artifact, image, run_frames, isr_rate_hz=isr_rate_hz, clock_mhz=CLOCKS_MHZ[0],
                                       seed=seed)
    handler = [0]

    def frame_objective(point: np.ndarray) -> int:
        cycles, run = frames(point)
        handler[0] = max([handler[0], *(event.handler_cycles for event in run.fw.isr_events)])
        return cycles

    found_frame = maximize(frame_objective, dimension, evaluations=max(1, evaluations // 2), seed=seed)
    return {step: found_step.cycles, "node_on_frame": found_frame.cycles, HANDLER: handler[0] or None}


def daq_mode_bound(artifact: ModelArtifact, image: ElfImage, drive: np.ndarray, initial,
                   measurement: np.ndarray | None = None) -> dict:
    """node_on_frame's bound with an XCP master running the DAQ tables' whole budget (`DAQ_MODE`) beside the most
    cycles it took on the drive under that DAQ (`bench.firmware.daqload`)."""
    from bench.firmware.daqload import daq_run

    bound = static_bounds(image, artifact, mode=DAQ_MODE, functions=("node_on_frame",))["node_on_frame"]
    run = daq_run(artifact, image, _frames(artifact, drive, initial, measurement))
    measured = run["node_on_frame_max"]
    return {"mode": DAQ_MODE.name, "description": DAQ_MODE.description, "node_on_frame": {
        "bound": bound, "measured_max": measured, "bound_over_max": round(bound / measured, 3) if measured else None},
        "daq_packets": run["daq_packets"], "model_steps": run["model_steps"]}


def wcet_table(bounds: dict, drive_max: dict, adversarial: dict) -> dict:
    """Per function: the bound, the drive's and the search's measured maxima, and bound / the larger of them."""
    table = {}
    for name, bound in bounds.items():
        measured = max(value for value in (drive_max.get(name), adversarial.get(name)) if value is not None)
        table[name] = {"bound": bound, "drive_max": drive_max.get(name), "adversarial_max": adversarial.get(name),
                       "measured_max": measured, "bound_over_max": round(bound / measured, 3) if measured else None}
    return table


def timing_report(artifact: ModelArtifact, image: ElfImage, drive: np.ndarray, initial, *,
                  isr_rate_hz: float = 10_000.0, seed: int = 0, search: int = 0,
                  measurement: np.ndarray | None = None) -> dict:
    """`bench firmware timing`'s JSON: the bounds, the drive's and the input search's (`search` candidates)
    measured maxima beside them, then the run at each clock of `CLOCKS_MHZ`; `measurement`: an observer's host
    channels per row (its measurement frames), None for none."""
    bounds = static_bounds(image, artifact)
    step = model_step_function(image)
    runs = {f"{mhz}MHz": measure(artifact, image, drive, initial, isr_rate_hz=isr_rate_hz, clock_mhz=mhz,
                                 seed=seed, measurement=measurement) for mhz in CLOCKS_MHZ}
    main = runs[f"{CLOCKS_MHZ[0]}MHz"]
    drive_max = {step: direct_step_max(artifact, image, drive, initial, measurement),
                 **{name: max(run["measured_max_cycles"][name] or 0 for run in runs.values())
                    for name in bounds if name != step}}
    adversarial = adversarial_maxima(artifact, image, evaluations=search, isr_rate_hz=isr_rate_hz, seed=seed)
    table = wcet_table(bounds, drive_max, adversarial)
    measured = {name: row["measured_max"] for name, row in table.items()}
    with_daq = daq_mode_bound(artifact, image, drive, initial, measurement)
    daq_row = with_daq["node_on_frame"]
    return {
        "isr_rate_hz": isr_rate_hz, "clock_mhz": CLOCKS_MHZ[0], "model_step": step,
        "wcet": table, "wcet_cycles": bounds, "measured_max_cycles": measured,
        "wcet_with_xcp_daq": with_daq,
        "wcet_holds": all(measured[name] <= bounds[name] for name in bounds)
                      and daq_row["measured_max"] <= daq_row["bound"],
        "wcet_method": "IPET (Li & Malik 1995) over each function's CFG, solved by scipy.optimize.milp; counted "
                       "loops from the machine code, the others from the C's /* wcet-loop */ annotations; branches "
                       "on globals a mode fixes from the C's /* wcet-value */ facts",
        "wcet_assumptions": f"rows in order (0 lost rows per frame), frames as the host sends them, "
                            f"{DRIVE_MODE.description}; wcet_with_xcp_daq: {DAQ_MODE.description}",
        "search_evaluations": search,
        "response_time_us": main["response_time_us"], "isr_latency_cycles": main["isr_latency_cycles"],
        "cpu_load": {name: run["cpu_load"] for name, run in runs.items()},
        "bit_exact": all(run["bit_exact"] for run in runs.values()),
        "runs": runs,
    }
