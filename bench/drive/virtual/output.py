"""Writing a virtual plant's profiles: one CSV per profile, as a user would bring them, and profiles.json, the index
that says what each file is."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.drive.motor import RPM_PER_RAD_S
from bench.drive.virtual.profiles import ROLES, Profile
from bench.drive.virtual.simulation import VirtualPlant, VirtualRun
from bench.fileio import write_bytes_atomically

# Bump when anything that changes the generated numbers changes.
GENERATOR_VERSION = "1.1.0"  # 1.1.0: the distributed plant in portable arithmetic (same bytes on every CPU)
INDEX_NAME = "profiles.json"


def generate_profiles(plant: VirtualPlant, out_dir: Path, seed: int | None = None, names=None,
                      progress: Callable[[Profile, VirtualRun, float], None] | None = None) -> dict:
    """Simulate the profiles (all, or those named), write each CSV atomically and then DIR/profiles.json.

    Returns the index (what profiles.json holds). It lists the profiles written now and, when only some were
    asked for, those an earlier run of the same motor file, generator and seed left in DIR unchanged.
    """
    import time

    out_dir = Path(out_dir)
    seed = plant.seed if seed is None else int(seed)
    if seed < 0:
        raise ValueError("the seed must be a non-negative integer")
    profiles = plant.profiles if names is None else tuple(plant.profile(n) for n in names)
    entries = []
    for profile in profiles:
        started = time.perf_counter()
        run = plant.simulate(profile, seed)
        payload = plant.csv_bytes(run.measured)
        write_bytes_atomically(out_dir / profile.filename, payload)
        entries.append(_index_entry(plant, profile, run, hashlib.sha256(payload).hexdigest()))
        if progress is not None:
            progress(profile, run, time.perf_counter() - started)
    if names is not None:
        entries = _kept_entries(plant, out_dir, seed, entries)
    index = {
        "generator": "bench.drive.virtual", "generator_version": GENERATOR_VERSION, "seed": seed,
        "motor": {"name": plant.motor.name, "file": plant.motor.path.name if plant.motor.path else None,
                  "sha256": plant.motor.sha256},
        "sample_period_s": plant.sample_period_s, "time_column": None,
        "initial_state": "all nodes at the profile's start_C, else at its first coolant set point",
        "columns": [{"name": c.name, "signal": c.signal, "unit": c.unit, "resolution": c.resolution,
                     "noise": c.noise, **({"at": c.at} if c.at else {})} for c in plant.columns],
        "profiles": entries,
        "roles": {role: [e["file"] for e in entries if e["role"] == role] for role in ROLES},
    }
    text = json.dumps(index, indent=2, ensure_ascii=False) + "\n"
    write_bytes_atomically(out_dir / INDEX_NAME, text.encode("utf-8"))
    return index


def _kept_entries(plant: VirtualPlant, out_dir: Path, seed: int, written: list[dict]) -> list[dict]:
    """written plus the entries of an existing index of the same motor, generator and seed whose files are still
    as written, in the motor file's profile order."""
    try:
        old = json.loads((out_dir / INDEX_NAME).read_text(encoding="utf-8"))
        same = (old.get("generator_version") == GENERATOR_VERSION and old.get("seed") == seed
                and old.get("motor", {}).get("sha256") == plant.motor.sha256)
        previous = {e["name"]: e for e in old.get("profiles", [])} if same else {}
    except (OSError, ValueError, AttributeError, KeyError, TypeError):
        previous = {}
    by_name = {e["name"]: e for e in written}
    out = []
    for profile in plant.profiles:
        entry = by_name.get(profile.name) or previous.get(profile.name)
        if entry is None:
            continue
        if profile.name not in by_name:
            try:
                if hashlib.sha256((out_dir / profile.filename).read_bytes()).hexdigest() != entry.get("sha256"):
                    continue
            except OSError:
                continue
        out.append(entry)
    return out


def _index_entry(plant: VirtualPlant, profile: Profile, run: VirtualRun, sha: str) -> dict:
    phases, starts = [], profile.starts_s
    for k, phase in enumerate(profile.phases):
        phases.append({**phase.spec, "start_s": float(starts[k]), "end_s": float(starts[k + 1])})
    torque, speed = run.truth["torque"], run.truth["speed"]
    power = torque * speed / RPM_PER_RAD_S
    return {"name": profile.name, "file": profile.filename, "sha256": sha, "role": profile.role,
            "rows": len(run.time_s), "duration_s": profile.duration_s,
            "coolant_setpoint_C": profile.coolant_C, "coolant_setpoints_C": profile.setpoints_C,
            **({"start_C": profile.start_C} if profile.start_C is not None else {}),
            "phases": phases,
            "true_max_rise_above_coolant_K": run.rise_K(),
            "true_range_C": {n: [round(float(run.truth[n].min()), 2), round(float(run.truth[n].max()), 2)]
                             for n in ("coolant", "winding", "magnet")},
            "peak": {"torque_Nm": round(float(np.abs(torque).max()), 1),
                     "speed_rpm": round(float(speed.max()), 0), "power_kW": round(float(power.max()) / 1e3, 1),
                     "current_A": round(float(np.hypot(run.truth["i_d"], run.truth["i_q"]).max()), 1)}}
