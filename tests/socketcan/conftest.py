"""SocketCAN tests: they need a kernel with AF_CAN and an up `vcan0`, else they skip and say how to get one.

`BENCH_REQUIRE_SOCKETCAN=1` turns that skip into a failure: tests/vm/run-socketcan-tests sets it inside its VM,
where vcan0 must exist, so a VM run can never end green with nothing tested.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dbc.transport import socketcan_usable

ROOT = Path(__file__).resolve().parents[2]
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
    from bench.drive.dataset import write_dataset

    rows, rng = 600, np.random.default_rng(11)
    t = np.arange(rows) * 0.2
    surface = np.round(40 + 10 * (1 - np.exp(-t / 900.0)), 1)
    columns = {"time_s": t,
               "torque_Nm": np.round(np.clip(np.cumsum(rng.normal(0, 15, rows)), -600, 600), 1),
               "speed_rpm": np.round(np.clip(np.abs(np.cumsum(rng.normal(0, 80, rows))), 0, 9000), 0),
               "coolant_C": np.round(40 + 2 * np.sin(t / 60.0), 1),
               "ambient_C": np.round(25 + 0.5 * np.sin(t / 90.0), 1),
               "winding_C": np.round(40 + 30 * (1 - np.exp(-t / 300.0)), 1),
               "rotor_surface_C": surface, "pm_C": np.round(surface + 5.0, 1)}
    path = tmp_path_factory.mktemp("data") / "small.csv"
    write_dataset(path, columns, {"coolant_setpoint_C": 40.0, "note": "synthetic socketcan test data"})
    return path


def run_cli(*argv: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """`python -m ...` from the project root, without a python-can interface configured in the environment."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAN_")}
    env.update(MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    return subprocess.run([sys.executable, *argv], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)
