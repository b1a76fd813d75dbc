#!/usr/bin/env bash
# The ros tests, again and again, on a loaded machine: N runs of `ctest -L
# ros` in the built workspace with K busy loops beside them (the rostests
# must wait for what they count, never for quiet or a fixed time). Stops at
# the first failing run; prints each run's result and time.
#   bash scripts/ros_label_loaded.sh [--runs N] [--busy K]   (defaults 5, 2)
# Build first: bash scripts/build.sh all tests
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
runs=5
busy=2
long3r_parse_args --runs=runs --busy=busy -- "$@"
loops=()
cleanup() { [ ${#loops[@]} -eq 0 ] || kill "${loops[@]}" 2>/dev/null || true; }
trap cleanup EXIT
for _ in $(seq "$busy"); do
  (while :; do :; done) &
  loops+=($!)
done
set +u  # catkin's setup reads unset variables
# shellcheck disable=SC1091
source "$LONG3R_WS/devel/setup.bash"
set -u
cd "$LONG3R_WS/build"
for run in $(seq "$runs"); do
  start=$(date +%s)
  if ctest -L ros --output-on-failure > "$LONG3R_ROOT/build/logs/ros_label_run_$run.log" 2>&1; then
    result=passed
  else
    result=FAILED
  fi
  summary=$(grep -E "tests passed|tests failed" "$LONG3R_ROOT/build/logs/ros_label_run_$run.log" | tail -1)
  echo "run $run of $runs with $busy busy loops: $result in $(( $(date +%s) - start )) s ($summary)"
  [ "$result" = passed ] || exit 1
done
echo "$runs runs in a row passed"
