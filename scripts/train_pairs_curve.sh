#!/usr/bin/env bash
# The registration-onset experiment (docs/model_card.md, "Registration
# against pairs seen"): config/train_pairs_fast.json, trained across sittings
# that resume exactly. Builds the trainer without ROS, continues RUN_DIR's own
# checkpoint or, in a fresh clone, the snapshot kept in
# models/experiments/pairs_fast/, trains for at most --budget-s seconds, then
# prints the blind control against pairs seen. --keep stores the newest
# checkpoint and log back into models/experiments/pairs_fast/ for the next
# sitting (a full checkpoint: weights, AdamW state, data and RNG states).
#   bash scripts/train_pairs_curve.sh [RUN_DIR] [--budget-s S] [--threads N] [--keep]
# Run it in the background and build nothing beside it: the figures are
# pairs per second of the whole machine.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

run="$LONG3R_ROOT/build/runs/pairs_fast"
budget=3000
threads=$(nproc)
keep=0
while [ $# -gt 0 ]; do
  case "$1" in
    --budget-s) budget=$2; shift 2 ;;
    --threads) threads=$2; shift 2 ;;
    --keep) keep=1; shift ;;
    -h|--help) sed -n '2,13p' "$0"; exit 0 ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) run=$1; shift ;;
  esac
done
snapshot="$LONG3R_ROOT/models/experiments/pairs_fast"

build="$LONG3R_ROOT/build/core"
cmake -S "$LONG3R_ROOT" -B "$build" -DLONG3R_WITH_ROS=OFF -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build "$build" -j "$LONG3R_JOBS" --target app_long3r_train

mkdir -p "$run/checkpoint"
if [ ! -f "$run/checkpoint/latest" ] && [ -f "$snapshot/checkpoint/latest" ]; then
  echo "== continuing the kept snapshot ($(cat "$snapshot/checkpoint/latest"))"
  cp "$snapshot/checkpoint/"* "$run/checkpoint/"
fi
resume=()
[ -f "$run/checkpoint/latest" ] && resume=(--resume)
# The model config path in the training config is relative to the repository.
cd "$LONG3R_ROOT"
"$build/long3r_train" --config config/train_pairs_fast.json --out "$run" --seed 0 \
  --threads "$threads" --prefetch 1 --render-threads 1 --time-budget-s "$budget" "${resume[@]}"

if [ "$keep" = 1 ]; then
  latest=$(cat "$run/checkpoint/latest")
  mkdir -p "$snapshot/checkpoint"
  cp "$run/checkpoint/$latest" "$snapshot/checkpoint/$latest.tmp"
  mv "$snapshot/checkpoint/$latest.tmp" "$snapshot/checkpoint/$latest"
  echo "$latest" > "$snapshot/checkpoint/latest"
  find "$snapshot/checkpoint" -name 'step_*.pt' ! -name "$latest" -delete
  cp "$run/train_log.csv" "$snapshot/train_log.csv"
  echo "== kept $latest in $snapshot"
fi
/usr/bin/python3 "$LONG3R_ROOT/scripts/blind_curve.py" "$run/train_log.csv" --every 4
