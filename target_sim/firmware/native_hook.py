"""The emulator's block hook compiled (numba cfunc): the cycle count without entering Python for a known block.

`Firmware` counts cycles from a hook on every basic block the core enters (`Firmware._on_block`): one look-up of the
block's cost and a few additions. As a Python callback it costs about 0.5 µs a block, and a frame's
`node_on_frame` enters some 70 blocks: two thirds of the firmware engine's time per lockstep row. This hook does
the same accounting in native code on a table of the blocks seen so far, indexed by the block's address in flash;
a block it has not seen (or one outside flash, or a call past its instruction limit) goes to the Python hook
(`slow`), which computes the block's cost once (`CycleModel.block`), enters it in the table and counts it with
the same rule. So every count, DWT read and fault is what the Python hook gives (tests/target_sim/test_emulator.py
compares the two).

`dwt_read` answers the firmware's reads of DWT_CYCCNT (an MMIO page) from the same state, also without Python.

The state the hook shares with Python is one int64 array (`BlockCounter.state`): the per-call counters first
(STATE_FIELDS), then per flash half-word (a Thumb block starts on one) the block's size, cycles, extra cycles when
its final branch is taken, fall-through address and instruction count (size 0: not seen).
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

CYCLES, INSTRUCTIONS, EXTRA, FALL, MAX_INSTRUCTIONS, SLOW_HOOK, FLASH_BASE, ENTRIES, CYCCNT_BEFORE = range(9)
HEADER = 9
ENTRY = 5                 # size, cycles, extra, fall, instructions
SIZE, COST, TAKEN, NEXT, COUNT = range(ENTRY)

# the hook's C type: void (*)(uc_engine *uc, uint64_t address, uint32_t size, void *user_data)
HOOK_SIGNATURE = types.void(types.voidptr, types.uint64, types.uint32, types.voidptr)
HOOK_CTYPE = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_uint64, ctypes.c_uint32, ctypes.c_void_p)


@intrinsic
def _call_slow(typingctx, function, engine, address, size, user):
    """Call the hook at address `function` (an int64) with the hook's own arguments."""
    signature = types.void(types.int64, types.voidptr, types.uint64, types.uint32, types.voidptr)

    def codegen(context, builder, sig, args):
        pointer = ir.IntType(8).as_pointer()
        hook = ir.FunctionType(ir.VoidType(), [pointer, ir.IntType(64), ir.IntType(32), pointer])
        builder.call(builder.inttoptr(args[0], hook.as_pointer()), list(args[1:]))
        return context.get_dummy_value()

    return signature, codegen


@numba.cfunc(HOOK_SIGNATURE, cache=True, nopython=True)
def block_hook(engine, address, size, user):
    """`Firmware._on_block` for a block in the table; anything else through the Python hook."""
    header = numba.carray(user, HEADER, dtype=np.int64)
    index = (np.int64(address) - header[FLASH_BASE]) >> 1
    if index < 0 or index >= header[ENTRIES]:
        _call_slow(header[SLOW_HOOK], engine, address, size, user)
        return
    table = numba.carray(user, HEADER + ENTRY * header[ENTRIES], dtype=np.int64)
    at = HEADER + ENTRY * index
    if table[at + SIZE] != np.int64(size) or header[INSTRUCTIONS] + table[at + COUNT] > header[MAX_INSTRUCTIONS]:
        _call_slow(header[SLOW_HOOK], engine, address, size, user)   # unseen, or over the limit: Python decides
        return
    cycles = table[at + COST]
    if np.int64(address) != header[FALL]:      # the previous block's final branch was taken
        cycles += header[EXTRA]
    header[CYCLES] += cycles
    header[EXTRA] = table[at + TAKEN]
    header[FALL] = table[at + NEXT]
    header[INSTRUCTIONS] += table[at + COUNT]


# an MMIO read callback's C type: uint64_t (*)(uc_engine *uc, uint64_t offset, unsigned size, void *user_data)
DWT_READ_SIGNATURE = types.uint64(types.voidptr, types.uint64, types.uint32, types.voidptr)


@numba.cfunc(DWT_READ_SIGNATURE, cache=True, nopython=True)
def dwt_read(engine, offset, size, user):
    """`Firmware._on_dwt_read` without entering Python (a model step reads DWT_CYCCNT twice): what it read as the
    call started (CYCCNT_BEFORE, kept by `Firmware`) plus this call's cycles so far; the other registers read 0."""
    if offset != 4:
        return np.uint64(0)
    header = numba.carray(user, HEADER, dtype=np.int64)
    return np.uint64((header[CYCCNT_BEFORE] + header[CYCLES]) & 0xFFFF_FFFF)


class BlockCounter:
    """The state array and the Python fallback of one core's native block hook."""

    def __init__(self, flash: tuple[int, int], max_instructions: int,
                 slow: Callable[[object, int, int, object], None]):
        entries = flash[1] // 2
        self.state = np.zeros(HEADER + ENTRY * entries, dtype=np.int64)
        self.counters = memoryview(self.state)[:HEADER]      # the header as Python ints, without numpy's per-item cost
        self.table = self.state[HEADER:].reshape(entries, ENTRY)
        self.flash_base = flash[0]
        self.slow = HOOK_CTYPE(slow)           # kept referenced while the hook lives
        self.state[SLOW_HOOK] = ctypes.cast(self.slow, ctypes.c_void_p).value
        self.state[FLASH_BASE], self.state[ENTRIES] = flash[0], entries
        self.state[MAX_INSTRUCTIONS] = max_instructions
        self.function = block_hook.address     # the cfunc's address (what uc_hook_add takes)

    @property
    def user_data(self) -> int:
        return self.state.ctypes.data

    def learn(self, address: int, size: int, block: tuple[int, int, int, int]) -> None:
        """Enter a block's cost (`CycleModel.block`) in the table, if it lies in flash."""
        index = (address - self.flash_base) >> 1
        if 0 <= index < len(self.table):
            cycles, extra, fall, count = block
            self.table[index] = (size, cycles, extra, fall, count)
