"""`bench campaign`: sweeps of `bench run` over the axes of a TOML spec, on a local or remote Dask cluster.

* `spec`: the TOML spec, validated and expanded into runs (one per combination of the axes, each with a stable id);
* `execute`: the runs on Dask workers, each a `python -m bench run` subprocess, retried once when it crashes, times
  out or loses its worker;
* `store`: the SQLite table (one row per run, written in one transaction when the run ends, never over a done row);
* `once`: results exactly once on any cluster (a directory per execution, the driver's commit, the no-worker
  notice), shared with `bench robustness`;
* `report`: the campaign's report.md and figures, from the table alone.

Nothing here is imported by the other commands; dask and distributed are imported only when a campaign runs.
"""
