#!/usr/bin/env bash
# The recipe of the previous default model, long3r_ship (kept in
# models/experiments/long3r_ship; docs/model_card.md, "The previous model:
# long3r_ship"; the shipped one's is scripts/train_sequence_model.sh): builds the core
# without ROS, trains stage 1 at 160 x 160 and stage 2 at 224 x 224 from it,
# scores the result on held-out generated sequences and, with --install,
# copies it to models/default.safetensors.
#   bash scripts/train_ship.sh [RUN_DIR] [--device cpu|cuda] [--threads N] [--install]
#                              [--model-config FILE] [--stage1-from DIR]
# --model-config trains another model config (JSON, e.g. the ablations in
# config/model_ship_*.json) with the same recipe; --stage1-from starts stage 2
# from a finished stage 1 (DIR/model.safetensors) instead of training one
# (scripts/train_ablations.sh: where stage 1 cannot differ).
# A run that stops can be continued with the same command (each stage resumes
# from its last checkpoint).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

run="$LONG3R_ROOT/build/train_ship"
device=cpu
threads=$(nproc)
install=0
model_config=()
model_config_file=""
stage1_from=
long3r_parse_args --device=device --threads=threads --install?install --model-config=model_config_file \
  --stage1-from=stage1_from @run -- "$@"
[ -n "$model_config_file" ] && model_config=(--model-config "$model_config_file")

build=$LONG3R_CORE
long3r_build_core app_long3r_train app_long3r_model_eval

stage() {  # name config [extra args]
  local name=$1 config=$2; shift 2
  local out="$run/$name"
  if [ -f "$out/done" ]; then echo "== $name: done before"; return; fi
  local resume=()
  [ -f "$out/checkpoint/latest" ] && resume=(--resume)
  echo "== $name ($config)"
  "$build/long3r_train" --config "$LONG3R_ROOT/config/$config" --out "$out" --device "$device" \
    --threads "$threads" --seed 1 "${model_config[@]}" "${resume[@]}" "$@"
  touch "$out/done"
}
if [ -n "$stage1_from" ]; then
  [ -f "$stage1_from/done" ] || { echo "no finished stage 1 in $stage1_from" >&2; exit 1; }
  stage1_model="$stage1_from/model.safetensors"
else
  stage stage1 train_ship_stage1.json
  stage1_model="$run/stage1/model.safetensors"
fi
stage stage2 train_ship_stage2.json --init-dust3r "$stage1_model"

echo "== held-out evaluation"
"$build/long3r_model_eval" --model "$run/stage2/model.safetensors" --frames 50 --sequences 3 \
  --threads "$threads" --json "$run/eval_50.json"
if [ "$install" = 1 ]; then
  mkdir -p "$LONG3R_ROOT/models"
  cp "$run/stage2/model.safetensors" "$LONG3R_ROOT/models/default.safetensors.tmp"
  mv "$LONG3R_ROOT/models/default.safetensors.tmp" "$LONG3R_ROOT/models/default.safetensors"
  echo "installed models/default.safetensors"
fi
