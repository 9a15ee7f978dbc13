"""Short scheduling slices for the processes of a lockstep run (Linux's EEVDF scheduler, kernel 6.12 and later).

Why: in lockstep the host and the target each wake thousands of times a second for a few tens of µs of work. On a
machine whose cores are busy with CPU-bound neighbours (a CI runner, a campaign's other workers) the kernel lets a
waking task preempt the running one only when the waking task's virtual deadline is earlier; with the default slice
(a few ms) it often is not, and each of the row's two wake-ups waits for a neighbour's slice to end. Asking for the
shortest slice the kernel grants (its `sched_runtime` of sched_setattr(2) for a fair-class task) gives each wake-up
an earlier deadline: the same CPU share, shorter waits. It needs no privilege and changes neither the policy nor the
priority; where the kernel or the platform cannot (another OS, an older kernel, a seccomp filter), nothing changes.
"""

from __future__ import annotations

import ctypes
import platform
import struct
import sys

SLICE_US = 100   # the shortest slice the kernel grants a fair-class task (0.1 ms)
_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}   # the syscall's number per architecture
_SCHED_OTHER = 0
_ATTR = "IIQiIQQQII"   # struct sched_attr (size, policy, flags, nice, priority, runtime, deadline, period, clamps)


def request_short_slices(slice_us: int = SLICE_US) -> bool:
    """Ask for `slice_us` slices for the calling thread (and the threads it starts later); True when the kernel
    took the request. Call it from the thread that receives frames, before the loop."""
    number = _SCHED_SETATTR.get(platform.machine())
    if not sys.platform.startswith("linux") or number is None:
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        attr = struct.pack(_ATTR, struct.calcsize(_ATTR), _SCHED_OTHER, 0, 0, 0, slice_us * 1000, 0, 0, 0, 0)
        return libc.syscall(number, 0, ctypes.create_string_buffer(attr, len(attr)), 0) == 0
    except (OSError, AttributeError):
        return False


def slice_us() -> int | None:
    """The calling thread's slice in µs as the kernel reports it (sched_getattr(2)), None where it cannot say."""
    number = _SCHED_SETATTR.get(platform.machine())
    if not sys.platform.startswith("linux") or number is None:
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        size = struct.calcsize(_ATTR)
        buffer = ctypes.create_string_buffer(size)
        if libc.syscall(number + 1, 0, buffer, size, 0) != 0:   # sched_getattr follows sched_setattr
            return None
        return struct.unpack(_ATTR, buffer.raw)[5] // 1000
    except (OSError, AttributeError):
        return None
