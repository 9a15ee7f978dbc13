"""The lab's side of the observer: tune its process and measurement noise on training files, write it into a model
artifact (the optional `observer` section, schema version 3; `target_sim.observer` runs it), and judge it on data.

- `reference`: the float64 reference filter on an artifact and a file (`bench.thermal.kalman`), its P0 and Q;
- `tune`: the tuning of q and R on training files (`tune_observer`) and its warnings;
- `section`: the artifact's `observer` section of a tuned fit (`observer_section`, `with_observer`);
- `choices`: what `bench observer` builds unless told otherwise, and its tuning criteria (standard library only: the
  command line is built from them);
- `measured`: the lab side of an artifact's measurements; `measures/`: one module per measurement kind
  (`LAB_MEASUREMENT_KINDS`) and the calibrations;
- `evaluate`: open loop vs observer, the recovery from a wrong magnet, the covariance forms compared; `plots`: the
  observer's figure per file.
"""
