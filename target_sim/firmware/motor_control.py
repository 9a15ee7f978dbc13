"""The motor control beside the estimator on the emulated core: the field-oriented current loop's interrupt of a
timing image (bench/firmware/foc_isr.c, `build_firmware(isr=True)`) and the peripherals that feed it.

    fw = motor_control_core(image, rate_hz=10_000)     # InterruptedFirmware, the handler checked
    start_motor_control(fw, rate_hz=10_000)           # foc_init, the ADC's samples, the first release

`AdcFeed` is what the ADC's DMA leaves before each interrupt: a current vector of 150 A rotating at a 200 Hz
electrical frequency plus noise from a seeded generator, and now and then a torque step so the PI controllers
saturate and the anti-windup acts. `bench firmware timing` and the firmware engine with `--isr-rate` both run
the interrupt this way.
"""

from __future__ import annotations

import numpy as np

from dbc.contract import M4_CLOCK_HZ
from target_sim.firmware.elf import ElfImage, FirmwareError
from target_sim.firmware.interrupts import InterruptedFirmware

FOC_IRQ = 18                      # foc_isr.c: the ADC end-of-conversion interrupt of an STM32F4
HANDLER = "foc_isr"
ELECTRICAL_HZ = 200.0
MAX_ISR_RATE_HZ = 50_000          # 1800 cycles at 90 MHz: the loop's ~300 with its exception costs is a sixth
AMPS_PER_COUNT = 0.1220703125     # foc_isr.c's scaling of the 12-bit samples


def isr_rate_problem(rate_hz: float) -> str | None:
    """Why `rate_hz` is no current-loop rate (one sentence), or None; 0 means no interrupt."""
    if not 0 <= rate_hz <= MAX_ISR_RATE_HZ:
        return (f"--isr-rate {rate_hz:.10g} is not a current-loop rate: give 0 (no interrupt) or up to "
                f"{MAX_ISR_RATE_HZ} Hz (inverters run 5000-20000)")
    return None


class AdcFeed:
    """The DMA's samples before each interrupt (see the module docstring)."""

    def __init__(self, fw: InterruptedFirmware, clock_hz: float, seed: int):
        self.fw, self.clock_hz = fw, clock_hz
        self.address = fw.address("foc_adc")
        self.reference = fw.address("foc_reference")
        self.rng = np.random.default_rng(seed)
        self.count = 0

    def __call__(self, release: int) -> None:
        angle = (release / self.clock_hz * ELECTRICAL_HZ) % 1.0
        theta = 2.0 * np.pi * angle
        noise = self.rng.normal(0.0, 40.0, 2)
        i_a = 150.0 * np.cos(theta) / AMPS_PER_COUNT + 2048.0 + noise[0]
        i_b = 150.0 * np.cos(theta - 2.0 * np.pi / 3.0) / AMPS_PER_COUNT + 2048.0 + noise[1]
        raw = np.clip(np.round([i_a, i_b]), 0, 4095).astype("<u2")
        self.fw.write_bytes(self.address, raw.tobytes() + int(angle * 65536).to_bytes(2, "little") + bytes(2))
        self.count += 1
        if self.count % 97 == 0:        # a torque step now and then: the PI saturates, the anti-windup acts
            i_q = float(self.rng.choice([0.0, 120.0, 400.0, -300.0]))
            self.fw.write_f32(self.reference, [-40.0 if i_q else 0.0, i_q])


def period_cycles(rate_hz: float, clock_hz: float = M4_CLOCK_HZ) -> int:
    return int(round(clock_hz / rate_hz))


def motor_control_core(image: ElfImage, *, rate_hz: float, clock_hz: float = M4_CLOCK_HZ) -> InterruptedFirmware:
    """The emulated core with the current loop's interrupt every clock/rate cycles (not yet enabled);
    FirmwareError (one sentence) for an image without it."""
    fw = InterruptedFirmware(image, irq=FOC_IRQ, period_cycles=period_cycles(rate_hz, clock_hz))
    if fw.handler_name != HANDLER:
        raise FirmwareError(f"{image.name}'s IRQ {FOC_IRQ} is {fw.handler_name}, not the current loop {HANDLER}")
    return fw


def start_motor_control(fw: InterruptedFirmware, *, rate_hz: float, clock_hz: float = M4_CLOCK_HZ,
                        seed: int = 0) -> np.random.Generator:
    """foc_init for the rate, the ADC's samples before each interrupt, the first release at a seeded phase; the
    seeded generator, for the caller's own phases."""
    fw.call("foc_init", float(rate_hz))
    fw.before_handler = AdcFeed(fw, clock_hz, seed)
    rng = np.random.default_rng(seed)
    fw.start_interrupts(at=fw.now + int(rng.integers(fw.period)))
    return rng


def interrupt_figures(fw: InterruptedFirmware) -> dict:
    """The interrupt as the core saw it: its period, how many it took (and the idle releases not emulated), their
    latency (release -> the handler's first instruction) p50/max and its CPU load, the mean of what each took from
    the core (exception costs included) over the period."""
    events = fw.isr_events
    latency = sorted(event.latency for event in events)
    busy = sum(event.busy for event in events)
    return {"period_cycles": fw.period, "interrupts": len(events), "skipped_idle": fw.skipped_releases,
            "latency_cycles": {"p50": latency[(len(latency) - 1) // 2] if latency else None,
                               "max": latency[-1] if latency else None},
            "cpu_load_percent": round(100.0 * busy / len(events) / fw.period, 3) if events else None}
