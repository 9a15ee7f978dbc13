#!/usr/bin/env bash
# The acceptance job of a drive team's CI: GitHub Actions (github-actions.yml) and GitLab CI (gitlab-ci.yml) run
# this script after installing the bench from the checkout (python -m pip install ".[test]");
# tests/bench/acceptance runs it too, and the recipes' commands in order, so their steps stay true. It writes into $BENCH_CI_OUT (default out/ci), which the recipes upload:
#   bench.blf, report/ (report.md and figures), bench-junit.xml, summary.json    the bench run and its criteria
#   pytest-<target>.xml, runs-<target>/                                         the pytest suite per target
#   external-target.log                                                         the external target's output
# Settings (environment):
#   BENCH_CI_INTERFACE  udp_multicast (default) or socketcan (with BENCH_CI_CHANNEL=vcan0 where the runner can
#                       `modprobe vcan`)
#   BENCH_CI_CHANNEL    the bus's channel (default: the bench's machine-local multicast group)
#   BENCH_CI_TARGETS    the targets the pytest suite runs against (default "python firmware external"; "" none)
#   BENCH_CI_ROWS       rows of the bench run (default 1500)
#   BENCH_PYTEST_ARGS   more pytest arguments (a source checkout without the package installed:
#                       "-p no:bench -p bench.pytest_plugin")
set -euo pipefail

HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${BENCH_CI_OUT:-out/ci}
INTERFACE=${BENCH_CI_INTERFACE:-udp_multicast}
CHANNEL=${BENCH_CI_CHANNEL:-}
TARGETS=${BENCH_CI_TARGETS-python firmware external}
ROWS=${BENCH_CI_ROWS:-1500}
PYTEST_ARGS=${BENCH_PYTEST_ARGS:-}
EXTERNAL_PORT=${BENCH_CI_EXTERNAL_PORT:-43131}   # the external target's udp port (udp_multicast)

mkdir -p "$OUT"
bus=(-i "$INTERFACE")
if [ -n "$CHANNEL" ]; then bus+=(-c "$CHANNEL"); fi

# 1. the bench run of the packaged model, judged by the acceptance criteria: exit status 1 names a failed one
python -m bench run --rows "$ROWS" --criteria "$HERE/criteria.toml" --log "$OUT/bench.blf" \
    --report "$OUT/report" --junit-xml "$OUT/bench-junit.xml" --json --quiet "${bus[@]}" > "$OUT/summary.json"

# 2. the pytest suite against each target: one the bench starts (python, firmware engine), and one already on the
#    bus (external: here a second process posing as the real target, `python -m target_sim`)
for target in $TARGETS; do
    options=(--bench-engine "$target")
    if [ "$target" = external ]; then
        group=${CHANNEL:-ff11:7079:7468:6f6e:6465:6d6f:6d63:6173}
        if [ "$INTERFACE" = udp_multicast ]; then
            ext_bus=(-i udp_multicast -c "$group" --bus-kwargs "port=$EXTERNAL_PORT")
        else
            ext_bus=(-i "$INTERFACE" -c "$group")
        fi
        model=$(python -c "from bench.model.default import default_artifact_path; print(default_artifact_path())")
        python -m target_sim --model "$model" "${ext_bus[@]}" 2> "$OUT/external-target.log" &
        target_pid=$!
        trap 'kill "$target_pid" 2>/dev/null || true' EXIT
        for _ in $(seq 120); do   # until it serves (a loaded runner takes seconds to start Python)
            if grep -q serving "$OUT/external-target.log"; then break; fi
            if ! kill -0 "$target_pid" 2>/dev/null; then cat "$OUT/external-target.log" >&2; exit 1; fi
            sleep 1
        done
        options=(--bench-interface "${ext_bus[1]}" --bench-channel "${ext_bus[3]}")
        if [ "$INTERFACE" = udp_multicast ]; then options+=(--bench-bus-kwargs "port=$EXTERNAL_PORT"); fi
    elif [ "$INTERFACE" != udp_multicast ]; then
        options+=(--bench-interface "$INTERFACE" ${CHANNEL:+--bench-channel "$CHANNEL"})
    fi
    # shellcheck disable=SC2086  # PYTEST_ARGS is a list of words
    # xunit1: the figures as properties of each test; system-out: its log and JUnit XML as [[ATTACHMENT|path]] lines
    python -m pytest "$HERE" $PYTEST_ARGS -p no:cacheprovider -n 0 -o junit_family=xunit1 \
        -o junit_logging=system-out --junitxml "$OUT/pytest-$target.xml" --bench-out "$OUT/runs-$target" \
        "${options[@]}"
    if [ "$target" = external ]; then kill "$target_pid"; wait "$target_pid" 2>/dev/null || true; trap - EXIT; fi
done
echo "acceptance: the bench run and the suite against: ${TARGETS:-no target} passed; artifacts in $OUT"
