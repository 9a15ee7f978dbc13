"""ensure_default_datasets in one directory from two places at once (parallel test workers, two commands): each
file is generated once, the other caller waits for it and reuses it."""

from __future__ import annotations

import threading
import time

from bench.drive import generate as gen
from bench.drive.dataset import write_dataset

from helpers import synthetic_columns


def test_two_callers_at_once_generate_each_dataset_once(tmp_path, monkeypatch):
    made: list[str] = []

    def slow_generate_and_write(path, setpoint_C, seed):   # a stand-in for the ~2 s of one real dataset
        made.append(path.name)
        time.sleep(0.2)
        write_dataset(path, synthetic_columns(20), {"seed": seed, "generator_version": gen.GENERATOR_VERSION,
                                                    "coolant_setpoint_C": setpoint_C})

    monkeypatch.setattr(gen, "generate_and_write", slow_generate_and_write)
    results, errors = [], []

    def call():
        try:
            results.append(gen.ensure_default_datasets(tmp_path / "data", gen.DEFAULT_SEED))
        except BaseException as exc:   # reported below
            errors.append(exc)

    threads = [threading.Thread(target=call) for _ in range(2)]   # each opens its own descriptor: flock excludes
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert not errors and len(results) == 2 and results[0] == results[1]
    assert sorted(made) == ["cycle_coolant20.csv", "cycle_coolant40.csv", "cycle_coolant60.csv"]
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == sorted(
        [*made, *(name.replace(".csv", ".json") for name in made)])   # no lock file, no temporary left
