#!/usr/bin/env bash
# The paper's two memory ablations retrained with the shipped model's recipe
# and budget (scripts/train_ship.sh, docs/model_card.md):
#   no_long_term    config/model_ship_no_long_term.json (L = 0)
#   spann3r_memory  config/model_ship_spann3r_memory.json (Spann3R's memory
#                   rules instead of the 3D spatio-temporal memory)
#   bash scripts/train_ablations.sh [RUN_DIR] [--ship-run DIR] [--only NAME]
#                                   [--device cpu|cuda] [--threads N]
# no_long_term starts stage 2 from the shipped run's stage 1 (--ship-run,
# default build/train_ship): with K = 10 short-term frames a 5-frame sequence
# never reaches long-term memory, so L plays no part in stage 1 and training it
# again would repeat the shipped run's stage 1 exactly. spann3r_memory trains
# both stages (its similarity rule can drop frames from short-term memory).
# Stopped runs continue with the same command. Score them with
#   bash scripts/model_card_eval.sh --retrained RUN_DIR
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

run="$LONG3R_ROOT/build/train_ablations"
ship_run="$LONG3R_ROOT/build/train_ship"
only=
pass=()
device="" threads=""
long3r_parse_args --ship-run=ship_run --only=only --device=device --threads=threads @run -- "$@"
[ -n "$device" ] && pass+=(--device "$device")
[ -n "$threads" ] && pass+=(--threads "$threads")
case "$only" in ""|no_long_term|spann3r_memory) ;; *) echo "unknown ablation $only" >&2; exit 2 ;; esac

if [ -z "$only" ] || [ "$only" = no_long_term ]; then
  [ -f "$ship_run/stage1/done" ] || bash "$LONG3R_ROOT/scripts/train_ship.sh" "$ship_run" "${pass[@]}"
  bash "$LONG3R_ROOT/scripts/train_ship.sh" "$run/no_long_term" "${pass[@]}" \
    --model-config "$LONG3R_ROOT/config/model_ship_no_long_term.json" \
    --stage1-from "$ship_run/stage1"
fi
if [ -z "$only" ] || [ "$only" = spann3r_memory ]; then
  bash "$LONG3R_ROOT/scripts/train_ship.sh" "$run/spann3r_memory" "${pass[@]}" \
    --model-config "$LONG3R_ROOT/config/model_ship_spann3r_memory.json"
fi
