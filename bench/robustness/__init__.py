"""`bench robustness`: how much input noise, bias, drift, quantization, dropped samples, parameter error, a wrong
start and Δt jitter cost a model's estimate, measured with the target's own float32 code.

* `kinds/`: the perturbation kinds, one module per kind, in a registry (`PERTURBATIONS`);
* `channels`: the inputs a kind can perturb (the drive channels; an observer's measurement channels);
* `models`: a model artifact with a parameter group off (rebuilt, sealed, verified);
* `filters`: first-order low-pass and moving mean in float32, and the delay each adds;
* `lanes`: many trajectories through one `Float32Estimator` at once (seeds side by side), and through the float32
  observer lane by lane (open loop and observer side by side for an observer artifact);
* `spec`, `cases`: the TOML spec and the cases it makes; `evaluate`: one case on a worker;
* `study`: the cases on Dask (the campaign's client and task loop) or in a serial loop; `store`: the SQLite table;
* `table`, `report`: the sensitivity table, worst case, filtering trade-off, robustness.json, report.md, figures.
"""
