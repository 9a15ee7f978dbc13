"""What `bench observer` builds unless told otherwise, and the names its options choose among. Defined here, with
nothing but the standard library, so the command line is built (its --help, a bad argument's one sentence) without
importing the tuning (scipy, numba); `bench.observer.section` and `bench.observer.tune` import them from here."""

from __future__ import annotations

# the covariance form the target runs unless told otherwise (chosen from `bench numerics --observer`)
DEPLOYED_FORM = "ud"
# the consider kind `bench observer` builds unless told otherwise (--consider; "none": every state is updated).
# Chosen on the suite's validation profiles (2026-11-28; designer's Hammerstein models, the end-winding NTC with lag,
# gradient and offset estimated, magnet criterion, no bias, 150 filter runs; MSE K², open loop / --consider none /
# magnet): winding air-30kw 13.06 / 8.67 / 3.68, ipm-60kw-distributed 3.24 / 0.30 / 1.11, outrunner-200kw
# 12.55 / 8.08 / 10.95; magnet 3.31 / 4.87 / 2.70, 5.05 / 2.74 / 2.28, 7.74 / 7.09 / 7.64. Only "magnet" leaves
# the magnet no worse than the open loop on every motor (none: worse on air-30kw) with the winding still better.
DEFAULT_CONSIDER = "magnet"
# the bias `bench observer` adds unless told otherwise (--bias; "none": no bias state) when a measurement reads its node
# (`default_bias`; else none). Chosen on the suite's validation profiles (2026-12-06; designer's Hammerstein models,
# the end-winding NTC with lag, gradient and offset estimated, magnet criterion with its stator guard, consider
# magnet, 150 filter runs; MSE K² winding / magnet, open loop → no bias → winding-output): air-30kw 10.18 / 1.67 →
# 5.47 / 1.41 → 0.27 / 1.67, ipm-60kw-distributed 23.39 / 1.44 → 23.38 / 1.45 → 0.14 / 1.44, outrunner-200kw
# 4.08 / 4.99 → 4.06 / 4.99 → 0.08 / 4.99: winding + magnet better on 3 of 3, the magnet the open loop's by
# construction (on air-30kw the filter without a bias had brought it to 1.41).
DEFAULT_BIAS = "winding-output"
# the key-on release `bench observer` writes unless told otherwise (--consider-release SIGMA, K; None: the consider
# states held always): a held magnet whose 1-σ exceeds it is updated by every measurement
DEFAULT_CONSIDER_RELEASE_C = None
# the innovation gate `bench observer` writes unless told otherwise (--gate, --gate-flag-after): a reading more than
# 3 sigma of its innovation off (ν²/S > 9, the 99.73 % quantile of chi-square with 1 degree of freedom) predicts only;
# 10 rejections in a row (5 s at 0.5 s steps) flag the sensor
DEFAULT_GATE = (3.0, 10)

# `bench observer --criterion`: what the tuning scores (bench.observer.tune)
TUNING_CRITERIA = ("magnet", "nodes", "likelihood")
