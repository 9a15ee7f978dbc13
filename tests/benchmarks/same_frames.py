"""Do two bench logs hold the same frames? (prints a verdict; not a test): for a change that must not change what
goes on the bus, e.g. a `bench run` of the same data and model before and after it.

    python tests/benchmarks/same_frames.py BEFORE.blf AFTER.blf

Read with python-can's reader of the suffix (`host.canlog.read_log`). Ids and data are compared in order, except
what is a wall-clock measurement by nature: the heartbeat (Status, RxErrors, every 100 ms of wall time: how many
and where differ between any two runs) is left out, and Timing1's StepTimeMeasured (the model step's measured µs
on the Python engine) is masked with its CRC. When the order differs, the frames of each sender are compared on
their own too: a host that sends the next row before the target's timing frames of the previous one (it waits
only for the temperatures) interleaves the two differently in another run, the frames being the same. Exit
status 0 when the logs are the same in order, 1 when not, 2 for a log that cannot be read.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from dbc.database import frame_id, host_frame_ids, layout_named  # noqa: E402
from host.canlog import LogError, read_log  # noqa: E402

HEARTBEAT = frozenset({frame_id("Status"), frame_id("RxErrors")})


def _timing1_mask() -> tuple[int, int]:
    """Timing1's id and the mask that keeps all of its bits but the measured time and the CRC (byte 0)."""
    measured = layout_named("Timing1").signal("StepTimeMeasured")
    return frame_id("Timing1"), ~((measured.mask << measured.start) | 0xFF) & (2**64 - 1)


def frames(path: str) -> tuple[list[tuple[int, bytes]], int, bool]:
    """(id, data) of every frame but the heartbeat, Timing1's measured time masked; the count of all frames; whether
    the times never go back."""
    timing1, mask = _timing1_mask()
    out: list[tuple[int, bytes]] = []
    count, ordered, last = 0, True, float("-inf")
    for msg in read_log(path):
        count += 1
        ordered = ordered and msg.timestamp >= last
        last = msg.timestamp
        if msg.arbitration_id in HEARTBEAT:
            continue
        data = bytes(msg.data)
        if msg.arbitration_id == timing1:
            data = (int.from_bytes(data, "little") & mask).to_bytes(len(data), "little")
        out.append((msg.arbitration_id, data))
    return out, count, ordered


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.split("\n\n")[1].strip(), file=sys.stderr)
        return 2
    try:
        (a, count_a, ordered_a), (b, count_b, ordered_b) = frames(argv[0]), frames(argv[1])
    except LogError as exc:
        print(f"same_frames: {exc}", file=sys.stderr)
        return 2
    same = a == b
    print(f"{count_a} / {count_b} frames, {len(a)} / {len(b)} without the heartbeat; the same ids and data in the same "
          f"order: {'yes' if same else 'no'}; times never go back: {ordered_a} / {ordered_b}")
    if not same:
        host = host_frame_ids()
        for who, keep in (("host", lambda f: f[0] in host), ("target", lambda f: f[0] not in host)):
            mine_a, mine_b = [f for f in a if keep(f)], [f for f in b if keep(f)]
            print(f"  the {who}'s frames alone ({len(mine_a)} / {len(mine_b)}): the same in order: "
                  f"{'yes' if mine_a == mine_b else 'no'}")
        differ = [i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y]
        print(f"  positions that differ: {len(differ) + abs(len(a) - len(b))} (first: {differ[:5]})")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
