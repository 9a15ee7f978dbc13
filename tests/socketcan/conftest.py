"""SocketCAN tests: they need a kernel with AF_CAN and an up `vcan0`, else they skip and say how to get one.

`BENCH_REQUIRE_SOCKETCAN=1` turns that skip into a failure: tests/vm/run-socketcan-tests sets it inside its VM,
where vcan0 must exist, so a VM run can never end green with nothing tested.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from dbc.transport import socketcan_usable

from helpers import synthetic_columns, write_synthetic_dataset

CHANNEL = "vcan0"
HOW_TO_GET_VCAN0 = ("no SocketCAN vcan0 here; create it with `sudo modprobe vcan && sudo ip link add dev vcan0 type "
                    "vcan && sudo ip link set up vcan0`, or run tests/vm/run-socketcan-tests (boots a VM whose "
                    "kernel has SocketCAN)")


@pytest.fixture(scope="session", autouse=True)
def vcan0() -> str:
    """The SocketCAN channel; skips (or fails, with BENCH_REQUIRE_SOCKETCAN=1) where it cannot be opened."""
    if not socketcan_usable(CHANNEL):
        if os.environ.get("BENCH_REQUIRE_SOCKETCAN") == "1":
            pytest.fail(f"BENCH_REQUIRE_SOCKETCAN=1 but {HOW_TO_GET_VCAN0}", pytrace=False)
        pytest.skip(HOW_TO_GET_VCAN0)
    return CHANNEL


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory) -> Path:
    """600 rows at 5 Hz of drive-like data (steps and ramps of torque and speed, slow coolant drift)."""
    return write_synthetic_dataset(tmp_path_factory.mktemp("data") / "small.csv", synthetic_columns(600, seed=11),
                                   "synthetic socketcan test data")
