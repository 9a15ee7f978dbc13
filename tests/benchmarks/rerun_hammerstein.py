"""Issue 37: the Hammerstein stage of a stored suite identification, rerun with --hammerstein-poles fixed|fit.

The swarm (and polish) result is read from a kept identify.json (its lptn_parameters) instead of searched again:
identify_lptn is replaced by a function returning it, and the run is made with --polish 0. Everything after the
network (the Hammerstein fit with cv, the artifacts, the validation figures) is `bench identify` itself.
usage: PYTHONPATH=. python tests/benchmarks/rerun_hammerstein.py KEPT_IDENTIFY_JSON -- identify ... --polish 0
(docs/method.md, "Fitting the poles too": the floor and training-split runs of issue 37 were made so)."""
import json
import sys

import bench.model.identify as mi
from bench.model.lptn_fit import LptnFit, parameter_bounds
from bench.thermal.parameters import LptnParameters

kept = json.loads(open(sys.argv[1], encoding="utf-8").read())
kept = kept.get("json", kept)
params = LptnParameters(**kept["lptn_parameters"])


def stored(runs, dt, *, start, width, **_):
    return LptnFit(params, kept["pso_cost"], kept["pso_history"], 0, 0, 220, 100, parameter_bounds(start, width),
                   kept["parameters_on_bounds"], tuple(kept["nodes"]), None, kept["pso_stalled_at"])


mi.identify_lptn = stored
from bench.cli import main  # noqa: E402

sys.exit(main(sys.argv[3:]))
