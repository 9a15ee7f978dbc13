"""The estimator beside the motor control: the current loop's interrupt preempting the emulated core leaves the
model's outputs and cycle counts as without it, is timed by the Cortex-M4 exception model, and the static WCET
bounds hold over what the core measured (fw_step, node_on_frame, the handler) for every packaged kind."""

from __future__ import annotations

import numpy as np
import pytest

from target_sim.firmware import Firmware, read_elf
from target_sim.firmware.interrupts import ExceptionCosts, InterruptedFirmware
from target_sim.firmware.wcet import WcetError, loop_facts, wcet

KINDS = ("hammerstein", "lti-lptn", "pv-lptn")
IRQ = 18


@pytest.fixture(scope="module")
def timing_image(firmware_builds):
    """kind -> (packaged artifact, ElfImage with the current loop), built once per run (`firmware_builds`)."""
    from bench.firmware.codegen import generate
    from bench.model.default import default_artifact_path
    from target_sim.artifact import load_artifact

    built = {}

    def get(kind):
        if kind not in built:
            artifact = load_artifact(default_artifact_path(kind))
            built[kind] = (artifact, read_elf(firmware_builds.build(generate(artifact), isr=True).elf))
        return built[kind]

    return get


def _drive(rows: int = 60) -> np.ndarray:
    rng = np.random.default_rng(3)
    return np.column_stack([rng.uniform(-250, 250, rows), rng.uniform(0, 6000, rows), np.full(rows, 65.0),
                            np.full(rows, 25.0)])


def _steps(fw: Firmware, interrupted: bool, count: int = 12) -> tuple[np.ndarray, list[int]]:
    inputs, outputs, state = fw.alloc_f32(4), fw.alloc_f32(4), fw.alloc_f32([60.0] * 4)
    fw.call("fw_reset", state)
    values, cycles = [], []
    for k in range(count):
        if interrupted:
            fw.release_at(fw.now + 517 * k)
        fw.write_f32(inputs, [20.0 * k - 100.0, 400.0 * k, 60.0, 25.0])
        fw.call("fw_step", inputs, outputs)
        values.append(fw.read_f32(outputs, 4))
        cycles.append(fw.last.cycles)
    return np.array(values), cycles


@pytest.mark.slow   # 12 s loaded: kept out of the 5-minute default run
def test_the_shipped_images_have_no_interrupt_and_the_timing_image_links_it(timing_image):
    from bench.firmware.images import packaged_elf_path

    artifact, image = timing_image("hammerstein")
    assert "foc_isr" in image.symbols and "foc_isr" not in read_elf(packaged_elf_path("hammerstein")).symbols
    with pytest.raises(Exception, match="no handler for exception 34"):
        InterruptedFirmware.load(packaged_elf_path("hammerstein"), irq=IRQ, period_cycles=9000)


@pytest.mark.parametrize("period", [700, 2000, 9000])
def test_preemption_leaves_the_model_bit_for_bit_and_its_cycles_unchanged(timing_image, period):
    _, image = timing_image("hammerstein")
    plain = Firmware(image)
    fw = InterruptedFirmware(image, irq=IRQ, period_cycles=period)
    fw.call("foc_init", 10000.0)
    fw.start_interrupts(at=fw.now + 5)
    expected, plain_cycles = _steps(plain, False)
    got, cycles = _steps(fw, True)
    assert np.array_equal(expected.view(np.uint32), got.view(np.uint32))
    assert cycles == plain_cycles
    jobs = [job for job in fw.jobs if job.function == "fw_step"]
    assert sum(job.preemptions for job in jobs) > 0
    events = fw.isr_events
    assert int(fw.read_i32(fw.address("foc_ticks"), 1)[0]) == len(events)
    for job in jobs:     # the response is the job's own cycles plus what every interrupt inside it took
        inside = [e for e in events if job.start <= e.taken < job.end and e.preempted == "fw_step"]
        assert job.response == (job.start - job.release) + job.cycles + sum(e.busy for e in inside)
        assert len(inside) == job.preemptions


@pytest.mark.slow   # 4 s: kept out of the 5-min default run
def test_the_exception_model_costs(timing_image):
    _, image = timing_image("lti-lptn")
    costs = ExceptionCosts()
    fw = InterruptedFirmware(image, irq=IRQ, period_cycles=9000)
    fw.start_interrupts(at=0)                  # no FP instruction yet in thread mode: no FP context
    fw.idle_until(3 * 9000 + 1)
    first = fw.isr_events[0]
    assert (first.latency, first.wait, first.lazy_fp) == (costs.entry, 0, False)
    assert first.busy == costs.entry + first.handler_cycles + costs.exit
    fw.call("foc_init", 10000.0)               # floating point in thread mode: FPCA set from here on
    fw.idle_until(fw.now + 2 * 9000)
    later = fw.isr_events[-1]
    assert later.lazy_fp and later.busy == (costs.entry + later.handler_cycles + costs.lazy_fp + costs.exit
                                            + costs.fp_exit)
    assert all(event.latency - costs.entry <= 14 for event in fw.isr_events)   # VDIV, the longest instruction


def _documented_costs() -> dict[str, tuple[int, int]]:
    """The table of docs/tutorials/firmware.md: cost -> (ARM's figure, what the emulator charges)."""
    import re

    from helpers import ROOT

    text = (ROOT / "docs" / "tutorials" / "firmware.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)`: [^|]+\| (\d+) cycles[^|]*\| (\d+) \|$", text, flags=re.MULTILINE)
    return {name: (int(arm), int(charged)) for name, arm, charged in rows}


def test_the_charged_exception_costs_are_arms_documented_figures():
    """Cortex-M4 TRM (as ARM's knowledge article 103489845 quotes it): entry 12, exit 10, each plus 17 with the
    FP context; tail-chaining 6; AN298: 17 words of lazily stacked FP context, 18 reserved."""
    from dataclasses import asdict

    from target_sim.firmware.interrupts import FP_FRAME_WORDS, FRAME_WORDS

    documented = _documented_costs()
    assert set(documented) == set(asdict(ExceptionCosts()))
    assert {name: arm for name, (arm, _) in documented.items()} == \
        {"entry": 12, "exit": 10, "tail_chain": 6, "lazy_fp": 17, "fp_exit": 17}
    assert asdict(ExceptionCosts()) == {name: charged for name, (_, charged) in documented.items()}
    assert all(arm == charged for arm, charged in documented.values())
    assert (FRAME_WORDS, FP_FRAME_WORDS) == (8, 17 + 1)     # R0-R3, R12, LR, PC, xPSR; S0-S15, FPSCR, reserved


@pytest.mark.slow   # 14 s loaded: kept out of the 5-minute default run
def test_tail_chaining_costs_six_cycles_between_handlers(timing_image):
    """A release pending when the handler returns: the next handler starts 6 cycles after, no unstacking."""
    _, image = timing_image("lti-lptn")
    probe = InterruptedFirmware(image, irq=IRQ, period_cycles=9000)
    probe.start_interrupts(at=0)
    probe.idle_until(1)
    handler = probe.isr_events[0].handler_cycles
    period = handler + 11      # release 2 (h + 11) before the first return (12 + h), release 3 after the second
    fw = InterruptedFirmware(image, irq=IRQ, period_cycles=period)
    fw.start_interrupts(at=0)
    fw.idle_until(1)
    first, second = fw.isr_events[:2]
    assert not first.tail_chained and second.tail_chained
    assert second.start - first.end == ExceptionCosts().tail_chain == 6
    assert first.end == first.start + first.handler_cycles            # no exit charged between the two


def test_an_interrupt_taken_inside_an_it_block_runs_the_handler_unconditionally(timing_image):
    """Unicorn may start a block inside a Thumb If-Then block, so a release can be taken with ITSTATE set: the
    exception frame keeps it and the handler starts without it (it once ran the handler's first instruction, its
    push, as the IT block's next conditional one: skipped, the return then popped a stack address as the PC)."""
    from unicorn import arm_const as arm

    from target_sim.firmware.interrupts import XPSR_IT

    _, image = timing_image("hammerstein")
    fw = InterruptedFirmware(image, irq=IRQ, period_cycles=9000)
    fw.call("foc_init", 10000.0)
    fw.start_interrupts(at=fw.now)
    xpsr = fw.uc.reg_read(arm.UC_ARM_REG_XPSR)
    fw.uc.reg_write(arm.UC_ARM_REG_XPSR, xpsr | 0x0000_2000 | 0x0400_0000)   # an IT block in progress (NE, ...)
    it_state = fw.uc.reg_read(arm.UC_ARM_REG_XPSR) & XPSR_IT
    assert it_state, "unicorn did not take the ITSTATE write"
    fw.idle_until(fw.now + 3 * 9000)
    assert int(fw.read_i32(fw.address("foc_ticks"), 1)[0]) == len(fw.isr_events) == 3
    assert fw.uc.reg_read(arm.UC_ARM_REG_XPSR) & XPSR_IT == it_state       # restored for the interrupted code


@pytest.mark.slow   # kept out of the 5-min default run
def test_a_period_shorter_than_the_handler_is_a_fault_not_a_hang(timing_image):
    from target_sim.firmware import FirmwareFault

    _, image = timing_image("pv-lptn")
    fw = InterruptedFirmware(image, irq=IRQ, period_cycles=100)
    fw.start_interrupts(at=0)
    with pytest.raises(FirmwareFault, match="runs longer than its period"):
        fw.idle_until(10_000)


# the packaged kind in the default run, the others kept out of the 5-min default run
@pytest.mark.parametrize("kind", [k if k == "hammerstein" else pytest.param(k, marks=pytest.mark.slow) for k in KINDS])
def test_the_wcet_bound_holds_over_the_measured_maximum(timing_image, kind):
    from bench.firmware.timing import direct_step_max, measure, static_bounds

    artifact, image = timing_image(kind)
    bounds = static_bounds(image, artifact)
    run = measure(artifact, image, _drive(), [60.0] * 4, isr_rate_hz=20_000)
    assert run["bit_exact"] and run["model_steps"] > 0
    for name in ("node_on_frame", "foc_isr"):
        assert 0 < run["measured_max_cycles"][name] <= bounds[name], name
    assert direct_step_max(artifact, image, _drive(), [60.0] * 4) <= bounds["fw_step"]
    _, cycles = _steps(Firmware(image), False, 30)
    assert max(cycles) <= bounds["fw_step"]
    assert run["isr_latency_cycles"]["max"] >= run["isr_latency_idle_cycles"]["max"] == ExceptionCosts().entry
    assert 0 < run["cpu_load"]["current_loop_isr"] < 0.1 and run["cpu_load"]["idle"] > 0.9


@pytest.mark.slow   # 5 s; the packaged kinds' bounds are checked in the default run: kept out of the 5-min default run
@pytest.mark.parametrize(("kind", "realization"), [
    ("hammerstein", "balanced"),
    pytest.param("lti-lptn", "physical", marks=pytest.mark.slow),
    pytest.param("pv-lptn", "physical", marks=pytest.mark.slow)])
def test_the_wcet_bound_holds_for_an_electrical_loss_model(electrical_of, electrical_drive, initial, firmware_builds,
                                                             kind, realization):
    """An electrical loss model's firmware (losses from the d/q currents: straight-line code, no loop of its own,
    so `loop_bounds` needs no entry for it) is bounded like the maps: fw_step, node_on_frame and the handler,
    each bound over the measured maximum, the outputs bit for bit beside the interrupt."""
    from bench.firmware.codegen import generate
    from bench.firmware.timing import direct_step_max, measure, static_bounds

    artifact, _ = electrical_of(kind, realization, 0.5)
    image = read_elf(firmware_builds.build(generate(artifact), isr=True).elf)
    bounds = static_bounds(image, artifact)
    drive = electrical_drive[:80]
    run = measure(artifact, image, drive, initial, isr_rate_hz=20_000)
    assert run["bit_exact"] and run["model_steps"] > 10
    for name in ("node_on_frame", "foc_isr"):
        assert 0 < run["measured_max_cycles"][name] <= bounds[name], name
    assert 0 < direct_step_max(artifact, image, drive, initial) <= bounds["fw_step"]


def test_a_loop_without_a_stated_bound_is_named(timing_image):
    """The frame handler's data-dependent loops take their bounds from the C's /* wcet-loop */ annotations, found
    by the image's line table; without them the first is named with its C line. The model step's loop is counted
    from the machine code and needs none."""
    from bench.firmware.timing import timing_sources

    artifact, image = timing_image("hammerstein")
    sources = timing_sources(artifact)
    with pytest.raises(WcetError, match=r"(node_on_frame|xcp_\w+) has a loop at 0x[0-9a-f]+ \(loop \d of the "
                                        r"function, C (node|xcp)\.c:\d+\)"):
        wcet(image, "node_on_frame", {})
    assert wcet(image, "fw_step", {}).cycles > 0
    with pytest.raises(ValueError):
        loop_facts(sources, -1)
    facts = loop_facts(sources)
    lost = next(line for line, bound in facts.items() if "lost_rows" in bound.reason)
    assert facts[lost].iterations == 0 and loop_facts(sources, 3)[lost].iterations == 3
    assert "lost < row" in sources["node.c"].splitlines()[lost[1] - 1]
    assert wcet(image, "node_on_frame", loop_facts(sources, 3)).cycles > wcet(image, "node_on_frame", facts).cycles
    # the XCP slave's DAQ (bench/firmware/xcp.c): none without a master, the tables' whole budget with one
    assert wcet(image, "node_on_frame", loop_facts(sources, 0, (16, 16))).cycles > \
        wcet(image, "node_on_frame", facts).cycles
    with pytest.raises(ValueError):
        loop_facts(sources, 0, (-1, 0))


def test_without_a_master_the_xcp_paths_are_infeasible_and_with_one_the_bound_covers_a_daq_run(timing_image):
    """The no_master mode's facts (bench/firmware/xcp.c's wcet-value(no_master) globals) decide branches of the
    XCP slave only and tighten node_on_frame's bound. They are what the emulated core has after a drive (the
    globals still at their stated values), and they do not hold with a master: a drive under the DAQ tables' whole
    budget takes more cycles than the no-master bound, and no more than the bound with a master (DAQ_MODE)."""
    from bench.firmware.timing import DAQ_MODE, DRIVE_MODE, _frames, daq_mode_bound, timing_sources
    from target_sim.firmware.node_engine import FirmwareNode
    from target_sim.firmware.wcet import value_facts

    artifact, image = timing_image("hammerstein")
    sources = timing_sources(artifact)
    values = value_facts(sources, DRIVE_MODE.name)
    assert values == {"xcp_connected": 0, "daq_lists": 0, "daq_odts": 0, "daq_queued": 0}
    assert value_facts(sources, DAQ_MODE.name) == {}
    facts = loop_facts(sources)
    bound = wcet(image, "node_on_frame", facts, values)
    assert bound.decided and {branch.function for branch in bound.decided} <= {"xcp_event", "xcp_flush"}
    assert bound.cycles < wcet(image, "node_on_frame", facts).cycles
    node = FirmwareNode(artifact, image)
    for group in _frames(artifact, _drive(), [60.0] * 4):
        for frame in group:
            node.handle(frame)
    assert node.model_steps > 0
    for name, value in values.items():
        symbol = image.symbols[name]
        assert int.from_bytes(node.fw.read_bytes(symbol.address, symbol.size), "little") == value, name
    with_daq = daq_mode_bound(artifact, image, _drive(), [60.0] * 4)
    row = with_daq["node_on_frame"]
    assert with_daq["daq_packets"] == 16 * with_daq["model_steps"] > 0
    assert bound.cycles < row["measured_max"] <= row["bound"]


# the packaged kind in the default run, the others kept out of the 5-min default run
@pytest.mark.parametrize("kind", [k if k == "hammerstein" else pytest.param(k, marks=pytest.mark.slow) for k in KINDS])
def test_the_ipet_bound_covers_the_searched_maximum_and_is_tight(timing_image, kind):
    """Each timed function's IPET bound is at least the most cycles measured, on a drive and by the input search,
    and within 10 % of it (the frame handler's without an XCP master, rows in order); node_on_frame's bound with a
    master running DAQ covers a drive under that DAQ."""
    from bench.firmware.timing import timing_report

    artifact, image = timing_image(kind)
    report = timing_report(artifact, image, _drive(), [60.0] * 4, isr_rate_hz=20_000, search=6)
    table = report["wcet"]
    assert set(table) == {"fw_step", "node_on_frame", "foc_isr"} and report["wcet_holds"]
    for name, row in table.items():
        assert row["drive_max"] > 0 and row["adversarial_max"] > 0, name
        assert row["measured_max"] == max(row["drive_max"], row["adversarial_max"]) <= row["bound"], name
    assert table["fw_step"]["bound_over_max"] <= 1.10
    assert table["node_on_frame"]["bound_over_max"] <= 1.10
    daq = report["wcet_with_xcp_daq"]["node_on_frame"]
    assert table["node_on_frame"]["bound"] < daq["measured_max"] <= daq["bound"]


@pytest.mark.slow   # 7-10 s: the default run keeps its 5-minute budget; .ci/run runs it
def test_the_observer_step_is_bounded_within_ten_percent(observer_artifact, firmware_builds):
    """An observer's model step (fw_obs_step: the model step, the UD prediction and update, the gate) is the timed
    model step; its bound covers the searched maximum (readings on and off) within 10 %, node_on_frame's within
    25 % (the benchmark record's drive and longer search show it within 10 %)."""
    from bench.firmware.codegen import generate
    from bench.firmware.timing import adversarial_maxima, static_bounds, timed_functions
    from target_sim.artifact import load_artifact

    artifact = load_artifact(observer_artifact)
    image = read_elf(firmware_builds.build(generate(artifact), isr=True).elf)
    assert timed_functions(image)[0] == "fw_obs_step"
    bounds = static_bounds(image, artifact)
    found = adversarial_maxima(artifact, image, evaluations=24, isr_rate_hz=20_000)
    for name, bound in bounds.items():
        assert 0 < found[name] <= bound, name
    assert bounds["fw_obs_step"] / found["fw_obs_step"] <= 1.10
    assert bounds["node_on_frame"] / found["node_on_frame"] <= 1.25   # 12 frame candidates: a short search


@pytest.mark.slow
def test_bench_firmware_timing_reports_the_figures_and_refuses_a_rate_the_core_cannot_carry(tmp_path, small_dataset):
    import json

    from helpers import run_cli

    proc = run_cli("-m", "bench", "firmware", "timing", "--data", str(small_dataset), "--rows", "40",
                   "--isr-rate", "20000", "--out", str(tmp_path), "--json", timeout=600)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["wcet_holds"] and report["bit_exact"]
    assert all(report["measured_max_cycles"][name] <= bound for name, bound in report["wcet_cycles"].items())
    assert set(report["response_time_us"]) == {"p50", "p99", "max"} and report["response_time_us"]["max"] > 0
    assert {"p50", "max"} <= set(report["isr_latency_cycles"]) and set(report["cpu_load"]) == {"90MHz", "168MHz"}
    fresh = tmp_path / "fresh"
    proc = run_cli("-m", "bench", "firmware", "timing", "--data", str(small_dataset), "--isr-rate", "1000000",
                   "--out", str(fresh))
    assert proc.returncode == 2 and "--isr-rate 1000000 is not a current-loop rate" in proc.stderr
    assert "Traceback" not in proc.stderr and not fresh.exists()    # refused before the build, not after it
