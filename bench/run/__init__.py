"""A bench run's part: the run as data (`request`, with the one-line parsers of its values in `values`), and the
pipeline every way to run the bench goes through, request -> `prepare` (every refusal before any work; the model,
data and rows, read through `inputs`) -> `execute` (the target process of `target` started, or one on the bus
attached to; replay, log) -> `judge` (analysis, criteria, verdict: one `RunSummary`), with `leftovers`, the
cleanup of what a killed run left behind. `bench run`, `bench host`, a campaign and the pytest plugin adapt it."""
