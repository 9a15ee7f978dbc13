"""The model firmware alone: the model compiled for a Cortex-M4F (`bench firmware build`), run in the emulated core
with the interface of the Python float32 reference (`target_sim.model.Float32Estimator`), for `bench firmware
check`. (The target's firmware engine runs the whole node: `target_sim.firmware.node_engine`.)

    model = FirmwareEstimator(artifact, "firmware.elf")   # FirmwareError: another core, another model, no fw_*
    model.reset(y0); y = model.step(torque, speed, coolant, ambient); model.last_cycles; model.x; model.y
    model.accumulate(sample); inputs = model.mean(); model.clear()        # the interval sum, in firmware RAM

A model with an electrical loss model takes the d/q currents after the four drive values, in `step(..., i_d, i_q)`
and in every sample and mean (`width` 6, the artifact's `drive_signals`), as `Float32Estimator` does.

One Unicorn call per firmware function: `step` writes the inputs, calls fw_step and reads the outputs (its counted
Cortex-M4 cycles are `last_cycles`); `x` asks fw_state only when read. Which row ends an interval is the
caller's integer logic; the sums and means are the firmware's (fw_accumulate, fw_mean, fw_clear). A fault of the
emulated core (`FirmwareFault`, one sentence) propagates to the caller.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from target_sim.artifact import ModelArtifact
from target_sim.firmware.elf import ElfImage, FirmwareError, memory_from_elf, read_elf
from target_sim.firmware.emulator import Firmware
from target_sim.firmware.node_protocol import firmware_refusal
from target_sim.observer import Float32Observer, has_observer

MODEL_ID_SYMBOL = "fw_model_id"
ENTRY_POINTS = ("fw_reset", "fw_restore", "fw_state", "fw_output", "fw_step", "fw_accumulate", "fw_mean",
                "fw_clear")
OBSERVER_ENTRY_POINTS = ("fw_obs_reset", "fw_obs_restore", "fw_obs_step", "fw_obs_report", "fw_obs_gate",
                         "fw_obs_checkpoint", "fw_obs_restore_checkpoint")
F32 = np.float32


class FirmwareEstimator:
    """The artifact's model as compiled firmware in the emulated Cortex-M4F (see the module docstring)."""

    def __init__(self, artifact: ModelArtifact, elf: str | os.PathLike | bytes | ElfImage, *,
                 count_cycles: bool = True):
        refusal = firmware_refusal(artifact)   # before the ELF is read: a loss model the firmware has not
        if refusal is not None:
            raise FirmwareError(refusal)
        image = elf if isinstance(elf, ElfImage) else read_elf(elf)
        self.artifact = artifact
        self.kind = artifact.kind
        self.fw = fw = Firmware(image, count_cycles=count_cycles)
        self.name = image.name
        self.memory = memory_from_elf(image)
        # an observer's model (fw_obs_*): a sample and a step's inputs carry its measurements' raw channels after
        # the drive values; it reports each node's 1-sigma and each measurement's innovation, and checkpoints
        self.observer = has_observer(artifact)
        reference = Float32Observer(artifact) if self.observer else None
        self.channels = sum(reference.layout.widths) if reference is not None else 0
        self.measurements = len(reference.measurements) if reference is not None else 0
        self.checkpoint_size = reference.checkpoint_size() if reference is not None else 0
        needed = (MODEL_ID_SYMBOL, *ENTRY_POINTS, *(OBSERVER_ENTRY_POINTS if self.observer else ()))
        missing = [name for name in needed if name not in fw.symbols]
        if missing:
            raise FirmwareError(f"{image.name} has no {', '.join(missing)}: it is not a model firmware of "
                                "'bench firmware build'")
        model_id = int(fw.read_i32(fw.address(MODEL_ID_SYMBOL), 1).view(np.uint32)[0])
        if model_id != artifact.model_id:
            raise FirmwareError(f"{image.name} is the firmware of model {model_id:08x}, not of the artifact's model "
                                f"{artifact.model_id:08x}; build it from this artifact with 'bench firmware build'")
        self.width = width = len(artifact.drive_signals)    # values per sample and step: 4, or 6 with the currents
        self.sample_width = sample_width = width + self.channels
        # the caller's buffers, allocated once in the scratch area (no firmware RAM)
        self._inputs, self._sample, self._mean = (fw.alloc_f32(sample_width) for _ in range(3))
        self._outputs, self._state = (fw.alloc_f32(4) for _ in range(2))
        self._report = fw.alloc_f32(4 + self.measurements)
        self._gate = fw.alloc(max(self.measurements, 1))
        self._checkpoint = fw.alloc_f32(max(self.checkpoint_size, 1))
        self._prefix = "fw_obs_" if self.observer else "fw_"
        self.last_cycles: int | None = None
        self.y = np.zeros(4, dtype=F32)

    # ------------------------------------------------------------------ the estimator (Float32Estimator's interface)
    def reset(self, temperatures: Sequence[float]) -> None:
        """x0 = C^-1 y0 (fw_reset, which also clears the interval sum)."""
        self.fw.write_f32(self._inputs, temperatures)
        self.fw.call(self._prefix + "reset", self._inputs)
        self.y = self._read("fw_output")

    def restore(self, state: Sequence[float]) -> None:
        """x bit for bit, y = C x (fw_restore, which also clears the interval sum)."""
        self.fw.write_f32(self._inputs, state)
        self.fw.call(self._prefix + "restore", self._inputs)
        self.y = self._read("fw_output")

    def step(self, *inputs: float, z: float | Sequence[float] | None = None) -> np.ndarray:
        """One model step (fw_step) on [torque, speed, coolant, ambient] (and [i_d, i_q] for an electrical loss
        model); an observer's model steps through its filter (fw_obs_step) with its measurements' raw channels z
        (NaN: no reading; one number for one channel, None: none at all). The counted Cortex-M4 cycles of the call
        are then in `last_cycles`."""
        if len(inputs) != self.width:
            raise ValueError(f"the {self.artifact.loss_model} loss model's step takes {self.width} inputs "
                             f"({', '.join(self.artifact.drive_signals)}), not {len(inputs)}")
        if self.observer:
            raw = np.full(self.channels, np.nan) if z is None else np.atleast_1d(np.asarray(z, dtype=np.float64))
            if len(raw) != self.channels:
                raise ValueError(f"the observer's measurements take {self.channels} raw channels, not {len(raw)}")
            inputs = (*inputs, *raw)
        fw = self.fw
        fw.write_f32(self._inputs, inputs)
        fw.call(self._prefix + "step", self._inputs, self._outputs)
        self.last_cycles = fw.last.cycles
        self.y = fw.read_f32(self._outputs, 4)
        return self.y.copy()

    def report(self) -> tuple[np.ndarray, np.ndarray]:
        """An observer's each node's 1-sigma and each measurement's innovation (NaN: not used) after the last step
        (fw_obs_report)."""
        self.fw.call("fw_obs_report", self._report)
        out = self.fw.read_f32(self._report, 4 + self.measurements)
        return out[:4].copy(), out[4:].copy()

    def gate(self) -> np.ndarray:
        """An observer's innovation gate after the last step (fw_obs_gate), per measurement: bit 0 its reading was
        rejected, bit 1 its sensor is flagged (`InnovationGate.rejected`, `.flagged`)."""
        self.fw.call("fw_obs_gate", self._gate)
        return np.frombuffer(self.fw.read_bytes(self._gate, self.measurements), dtype=np.uint8).copy()

    def checkpoint(self) -> np.ndarray:
        """An observer's checkpoint (fw_obs_checkpoint): `Float32Observer.checkpoint`'s elements."""
        self.fw.call("fw_obs_checkpoint", self._checkpoint)
        return self.fw.read_f32(self._checkpoint, self.checkpoint_size)

    def restore_checkpoint(self, state: Sequence[float], values: Sequence[float]) -> None:
        """x bit for bit and the filter from its checkpoint (fw_obs_restore_checkpoint)."""
        if len(values) != self.checkpoint_size:
            raise ValueError(f"an observer checkpoint of this filter has {self.checkpoint_size} elements, "
                             f"not {len(values)}")
        self.fw.write_f32(self._inputs, state)
        self.fw.write_f32(self._checkpoint, values)
        self.fw.call("fw_obs_restore_checkpoint", self._inputs, self._checkpoint)
        self.y = self._read("fw_output")

    @property
    def x(self) -> np.ndarray:
        """The state vector (fw_state), read when asked for: a checkpoint needs it every 20 steps."""
        return self._read("fw_state")

    def _read(self, function: str) -> np.ndarray:
        self.fw.call(function, self._state)
        return self.fw.read_f32(self._state, 4)

    # ------------------------------------------------------------------ the interval sum (InputAccumulator's)
    def accumulate(self, sample: Sequence[float]) -> None:
        """sum <- sum + sample in float32 (fw_accumulate)."""
        if len(sample) != self.sample_width:
            raise ValueError(f"a sample of the {self.artifact.loss_model} loss model has {self.sample_width} values, "
                             f"not {len(sample)}")
        self.fw.write_f32(self._sample, sample)
        self.fw.call("fw_accumulate", self._sample)

    def mean(self) -> np.ndarray | None:
        """The float32 mean of the accumulated samples, then cleared (fw_mean); None when there were none."""
        if not self.fw.call("fw_mean", self._mean, returns=int):
            return None
        return self.fw.read_f32(self._mean, self.sample_width)

    def clear(self) -> None:
        self.fw.call("fw_clear")
