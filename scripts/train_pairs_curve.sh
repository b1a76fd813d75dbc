#!/usr/bin/env bash
# The registration-onset experiment (docs/model_card.md, "Registration
# against pairs seen"): config/train_pairs_fast.json (or --config), trained
# across sittings that resume exactly. Builds the trainer and the
# frame-cache writer without ROS; renders the configuration's training
# scenes once into a frame cache (build/cache/, about 14 GB at 64 px, named
# by the scenes it holds, so that configurations drawing the same frames
# share it; kept while it fits); continues RUN_DIR's own checkpoint or, in a
# fresh clone, the snapshot kept in --snapshot (default
# models/experiments/pairs_fast/); trains for at most --budget-s seconds as
# --ranks data-parallel processes of one thread each (Gloo over loopback;
# the global batch and its draws are the same at any rank count); then
# prints the blind control against pairs seen. --keep stores the newest
# checkpoint and the logs back into the snapshot folder for the next sitting
# (a full checkpoint: weights, AdamW state, data and RNG states). --init
# starts a fresh run from a model's weights (by name; the sequence stage
# starts from the pair model); a run that resumes ignores it. SIGTERM or
# SIGINT to the script ends the run after the step in progress, with its
# checkpoint, and keeps it as at the budget's end.
#   bash scripts/train_pairs_curve.sh [RUN_DIR] [--budget-s S] [--ranks N] [--keep]
#        [--config FILE] [--snapshot DIR] [--init MODEL.safetensors] [--max-steps N]
# --max-steps ends the run at that global step, its schedule unchanged (how
# scripts/train_sequence_model.sh repeats a stage that was stopped by hand).
# Run it in the background (nice -n 19) and build nothing beside it: the
# figures are pairs per second of the whole machine.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

# Linux's autogroup scheduling weighs sessions against each other before
# nice counts: a run started as its own session (setsid nohup nice -n 19 ...)
# would still take half the cores from a build in a terminal. As a session
# leader it gives its session's group its own niceness too.
if [ "$(ps -o sid= -p $$ | tr -d ' ')" = "$$" ] && [ -w /proc/self/autogroup ]; then
  echo "$(nice)" > /proc/self/autogroup 2>/dev/null || true
fi

config="config/train_pairs_fast.json"
run=""
budget=3000
ranks=$(nproc)
keep=0
snapshot="$LONG3R_ROOT/models/experiments/pairs_fast"
init=""
max_steps=()
while [ $# -gt 0 ]; do
  case "$1" in
    --budget-s) budget=$2; shift 2 ;;
    --ranks) ranks=$2; shift 2 ;;
    --config) config=$2; shift 2 ;;
    --snapshot) snapshot=$2; shift 2 ;;
    --init) init=$(realpath "$2"); shift 2 ;;
    --max-steps) max_steps=(--max-steps "$2"); shift 2 ;;
    --keep) keep=1; shift ;;
    -h|--help) sed -n '2,25p' "$0"; exit 0 ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) run=$1; shift ;;
  esac
done
name=$(basename "$config" .json)
[ -n "$run" ] || run="$LONG3R_ROOT/build/runs/${name#train_}"
[ "$ranks" -ge 1 ] || { echo "--ranks must be >= 1" >&2; exit 2; }

build=$LONG3R_CORE
long3r_build_core app_long3r_train app_long3r_frame_cache

# The model config path in the training config is relative to the repository.
cd "$LONG3R_ROOT"
mkdir -p "$LONG3R_ROOT/build/cache"
cache=$("$build/long3r_frame_cache" --config "$config" --out "$LONG3R_ROOT/build/cache" --print-name)
if ! "$build/long3r_frame_cache" --config "$config" --out "$cache" --check 2>/dev/null; then
  echo "== rendering the training scenes into $cache"
  "$build/long3r_frame_cache" --config "$config" --out "$cache" --threads "$(nproc)"
fi

mkdir -p "$run/checkpoint"
if [ ! -f "$run/checkpoint/latest" ] && [ -f "$snapshot/checkpoint/latest" ]; then
  echo "== continuing the kept snapshot ($(cat "$snapshot/checkpoint/latest"))"
  cp "$snapshot/checkpoint/"* "$run/checkpoint/"
  # The logs up to the checkpoint (newer checkpoints keep only their length).
  for f in train_log.csv blind_control.csv; do
    if [ -f "$snapshot/$f" ]; then cp "$snapshot/$f" "$run/$f"; fi
  done
fi
resume=()
if [ -f "$run/checkpoint/latest" ]; then
  resume=(--resume)
elif [ -n "$init" ]; then
  resume=(--init-dust3r "$init")
fi
args=(--config "$config" --out "$run" --seed 0 --threads 1 --prefetch 0 --render-threads 1
      --frame-cache "$cache" --time-budget-s "$budget" "${resume[@]}" "${max_steps[@]}")
# The ranks run in the background so that a SIGTERM or SIGINT to this
# script reaches them: each ends after the step in progress, all at the same
# step, with its checkpoint, and --keep below still keeps it.
pids=()
forward_stop() { kill -TERM "${pids[@]}" 2>/dev/null || true; }
trap forward_stop TERM INT
if [ "$ranks" = 1 ]; then
  "$build/long3r_train" "${args[@]}" &
  pids+=($!)
else
  # One process per rank on this machine; rank 0 serves the rendezvous.
  port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  for ((r = 0; r < ranks; r++)); do
    RANK=$r WORLD_SIZE=$ranks LOCAL_RANK=$r MASTER_ADDR=127.0.0.1 MASTER_PORT=$port \
      "$build/long3r_train" "${args[@]}" &
    pids+=($!)
  done
fi
status=0
for p in "${pids[@]}"; do
  # A trapped signal interrupts wait (status > 128) while the rank runs on.
  while :; do
    if wait "$p"; then break; fi
    rc=$?
    kill -0 "$p" 2>/dev/null && continue
    status=$rc
    break
  done
done
trap - TERM INT
[ "$status" = 0 ] || { echo "a rank failed (exit $status)" >&2; exit "$status"; }

if [ "$keep" = 1 ]; then
  latest=$(cat "$run/checkpoint/latest")
  mkdir -p "$snapshot/checkpoint"
  cp "$run/checkpoint/$latest" "$snapshot/checkpoint/$latest.tmp"
  mv "$snapshot/checkpoint/$latest.tmp" "$snapshot/checkpoint/$latest"
  echo "$latest" > "$snapshot/checkpoint/latest"
  find "$snapshot/checkpoint" -name 'step_*.pt' ! -name "$latest" -delete
  for f in train_log.csv blind_control.csv; do
    if [ -f "$run/$f" ]; then cp "$run/$f" "$snapshot/$f"; fi
  done
  echo "== kept $latest in $snapshot"
fi
# Samples seen counted by the first stage's batch and frames.
read -r batch frames < <(/usr/bin/python3 -c 'import json, sys
s = json.load(open(sys.argv[1]))["stages"][0]; print(s["batch_size"], s["frames"])' "$config")
/usr/bin/python3 "$LONG3R_ROOT/scripts/blind_curve.py" "$run/train_log.csv" --every 4 \
  --batch "$batch" --frames "$frames"
