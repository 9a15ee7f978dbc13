"""Issue 37: is it the four-node structure or what the training profiles cover that keeps a suite motor off the
accuracy goal? A diagnostic, nothing is chosen on it.

For each suite motor, the model `bench identify` deployed (kept by `bench_suite.py` in its --work directory,
<work>/<motor>/<prior>/model.json) is run on every profile; its float64 errors on the winding and the magnet are
then fitted by a parallel bank of first-order lags (extra states: unit-gain lags with the time constants `--taus`
of the four node losses and the coolant, 20 states per node) by ridge least squares:
- fitted on the nine non-test profiles, scored on the three test profiles (held out: what more states would buy);
- fitted on all twelve, scored on the test profiles (in-sample: whether such states can represent the plant).
When the in-sample bank meets the goal but the held-out one does not, more states would not close the gap on
these data: the test profiles ask for what the training profiles do not show.

usage: PYTHONPATH=. python tests/benchmarks/bench_lag_bank.py --work DIR [--prior designer] [--json PATH]
(record: docs/results/lag_bank-<prior>.json)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from record import Record, add_record_arguments  # noqa: E402

from bench.drive.dataset import load_dataset  # noqa: E402
from bench.drive.mapping import load_mapping  # noqa: E402
from bench.model.baselines import lowpass  # noqa: E402
from bench.model.fileeval import evaluate_file  # noqa: E402
from target_sim.artifact import load_artifact  # noqa: E402

SUITE = ROOT / "examples" / "suite"
NODES = ("winding", "pm")
TAUS_S = (60.0, 300.0, 1200.0, 4000.0)
RIDGE = 1e-3          # × rows, on features scaled to unit spread: a light hold, the bank's 20 weights per node


def lagged(u: np.ndarray, dt: float, taus: tuple[float, ...]) -> np.ndarray:
    """(steps, len(taus)·width): each input column through each unit-gain first-order lag, from zero."""
    return np.column_stack([lowpass(column, tau, dt) for tau in taus for column in u.T])


def profile_errors(artifact, mapping, path: Path, taus) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(lag features, {node: reference - estimate}) of one profile, float64 as the bank would add to it."""
    result = evaluate_file(artifact, load_dataset(path, mapping, sample_period_s=artifact.data_sample_period))
    run = result.evaluation.run
    u = np.column_stack([run.inputs.table_losses, run.inputs.coolant])
    return lagged(u, run.dt, taus), {n: result.references[n] - result.estimate(n, "float64") for n in NODES}


def ridge_fit(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    spread = x.std(axis=0) + 1e-12
    xs = x / spread
    return np.linalg.solve(xs.T @ xs + RIDGE * len(y) * np.eye(x.shape[1]), xs.T @ y) / spread


def stacked(runs, node: str) -> tuple[np.ndarray, np.ndarray]:
    """The runs' lag features and one node's errors, one below the other."""
    return np.vstack([r[1] for r in runs]), np.concatenate([r[2][node] for r in runs])


def figures(errors: np.ndarray) -> dict[str, float]:
    return {"mse_K2": round(float(np.mean(errors ** 2)), 4), "max_K": round(float(np.max(np.abs(errors))), 3)}


def one_motor(work: Path, motor: str, prior: str, taus) -> dict:
    data = work / motor / "data"
    roles = json.loads((data / "profiles.json").read_text(encoding="utf-8"))["roles"]
    artifact = load_artifact(work / motor / prior / "model.json")
    mapping = load_mapping(SUITE / motor / "mapping.json")
    runs = {name: (role, *profile_errors(artifact, mapping, data / name, taus))
            for role in ("train", "validate", "test") for name in roles[role]}
    test = [r for r in runs.values() if r[0] == "test"]
    out = {"motor": motor, "kind": artifact.kind, "model_sha256": artifact.content["sha256"],
           "profiles": {role: roles[role] for role in roles}}
    for node in NODES:
        held = ridge_fit(*stacked([r for r in runs.values() if r[0] != "test"], node))
        every = ridge_fit(*stacked(runs.values(), node))
        before = np.concatenate([r[2][node] for r in test])
        out[node] = {"model": figures(before),
                     "bank_held_out": figures(np.concatenate([r[2][node] - r[1] @ held for r in test])),
                     "bank_in_sample": figures(np.concatenate([r[2][node] - r[1] @ every for r in test]))}
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True, help="bench_suite.py's --work directory (kept runs)")
    parser.add_argument("--prior", default="designer", help="the kept identification: designer, table1 or auto")
    parser.add_argument("--taus", default=",".join(f"{t:g}" for t in TAUS_S), help="the lags' time constants, s")
    add_record_arguments(parser)
    args = parser.parse_args()
    taus = tuple(float(t) for t in args.taus.split(","))
    motors = sorted(p.name for p in args.work.iterdir() if (p / args.prior / "model.json").is_file()) \
        if args.work.is_dir() else []
    if not motors:
        parser.error(f"{args.work} holds no kept {args.prior} identification (<motor>/{args.prior}/model.json): "
                     "give bench_suite.py's --work directory")
    record = Record("lag_bank", args, parameters={"prior": args.prior, "taus_s": list(taus), "ridge": RIDGE,
                                                  "inputs": ["P_y", "P_w", "P_t", "P_m", "coolant"]},
                    variant=args.prior)
    record.figures["motors"] = []
    for motor in motors:
        row = one_motor(args.work, motor, args.prior, taus)
        record.figures["motors"].append(row)
        print(motor, {n: row[n] for n in NODES}, flush=True)
    record.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
