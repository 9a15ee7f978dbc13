"""Fault injection between the host and the bus (and, for process faults, on the target process).

* `spec`: the kinds, rates, counts and seed given on the command line (`--fault`, `--faults`, `--fault-seed`);
* `plan`: where the faults go, a deterministic function of (seed, row, pass);
* `bus`: `FaultyBus`, the python-can-like wrapper that applies them to the host's drive frames;
* `lockstep`: the lockstep replay that survives them (retransmission, re-initialization of a lost target);
* `reconcile`: injected versus detected, per kind, from the target's detection journal and the host's own
  observations; the `<log>.faults.json` sidecar.

Every injected fault and every gap is also marked in the log itself by a BenchEvent frame (DBC 0x1FF).
"""

from host.faults.bus import FaultyBus, Injection
from host.faults.lockstep import (
    DELAY_FACTOR,
    FREEZE_FACTOR,
    FaultRun,
    ProcessControl,
    Recovery,
    run_lockstep_with_faults,
)
from host.faults.plan import FaultPlan
from host.faults.realtime import check_realtime_faults, run_realtime_with_faults
from host.faults.reconcile import (
    DETECTION,
    Journal,
    fault_note,
    fault_problems,
    read_journal,
    read_sidecar,
    reconcile,
    sidecar_path,
    write_sidecar,
)
from host.faults.spec import (
    KINDS,
    MARKED_KINDS,
    REPLY_KINDS,
    FaultSpec,
    FaultSpecError,
    canonical_kind,
    parse_faults,
    spec_from_args,
)

__all__ = [
    "DELAY_FACTOR",
    "DETECTION",
    "FREEZE_FACTOR",
    "KINDS",
    "MARKED_KINDS",
    "REPLY_KINDS",
    "FaultPlan",
    "FaultRun",
    "FaultSpec",
    "FaultSpecError",
    "FaultyBus",
    "Injection",
    "Journal",
    "ProcessControl",
    "Recovery",
    "canonical_kind",
    "fault_note",
    "fault_problems",
    "parse_faults",
    "read_journal",
    "read_sidecar",
    "reconcile",
    "run_lockstep_with_faults",
    "run_realtime_with_faults",
    "check_realtime_faults",
    "spec_from_args",
    "sidecar_path",
    "write_sidecar",
]
