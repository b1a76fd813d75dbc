#!/usr/bin/env bash
# The recipe of the sequence model, models/experiments/seq_k5
# (docs/model_card.md, "The sequence model against long3r_ship"): four
# runs of scripts/train_pairs_curve.sh, each from the last one's weights, at
# 64 x 64 on the generated scenes' frame cache: pairs (10^6), 5-frame
# sequences (stopped at step 8501 of its schedule, as the kept run was), 10-
# and 32-frame sequences with the encoder frozen, 32-frame sequences with a
# short-term window of 5. Then the blind control on the held-out seeds and,
# with --install, the last run's model copied to models/default.safetensors.
# The kept runs' steps took 32 hours on two CPU cores. A run that stops is
# continued by the same command (each part resumes from its checkpoint in
# RUN_DIR, default build/train_sequence_model), never from the snapshots
# kept in models/experiments/. Written from the kept runs' own commands; not
# yet run end to end.
#   bash scripts/train_sequence_model.sh [RUN_DIR] [--ranks N] [--install]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

run="$LONG3R_ROOT/build/train_sequence_model"
ranks=$(nproc)
install=0
long3r_parse_args --ranks=ranks --install?install @run -- "$@"
mkdir -p "$run"
run=$(cd "$run" && pwd)

init=""
part() {  # name config [--max-steps N]
  local name=$1 config=$2; shift 2
  local out="$run/$name" target last
  if [ "${1:-}" = --max-steps ]; then
    target=$2
  else
    target=$(/usr/bin/python3 -c 'import json, sys
print(sum(s["steps"] for s in json.load(open(sys.argv[1]))["stages"]))' "$LONG3R_ROOT/config/$config")
  fi
  if [ ! -f "$out/done" ]; then
    echo "== $name ($config)"
    local from=()
    [ -n "$init" ] && from=(--init "$init")
    # An empty snapshot folder: a reproduction continues only its own runs.
    mkdir -p "$out/no_snapshot"
    bash "$LONG3R_ROOT/scripts/train_pairs_curve.sh" "$out" --config "$LONG3R_ROOT/config/$config" \
      --budget-s 0 --ranks "$ranks" --snapshot "$out/no_snapshot" "${from[@]}" "$@"
    # A run stopped by a signal ends as well as a finished one (its
    # checkpoint kept): the part is done only at its last step.
    last=$(tail -n 1 "$out/train_log.csv" | cut -d, -f1)
    if [ "$last" != "$target" ]; then
      echo "== $name stopped at step $last of $target: the same command continues it" >&2
      exit 1
    fi
    touch "$out/done"
  else
    echo "== $name: done before"
  fi
  init="$out/model.safetensors"
}
part pairs_wide train_pairs_wide.json
part seq_wide train_seq_wide.json --max-steps 8501
part seq_long train_seq_long.json
part seq_k5 train_seq_k5.json

long3r_build_core app_long3r_model_eval
"$LONG3R_CORE/long3r_model_eval" --model "$init" --blind-control --seed-begin 2000000 \
  --sequences 16 --blind-starts 8 --threads "$(nproc)"
if [ "$install" = 1 ]; then
  cp "$init" "$LONG3R_ROOT/models/default.safetensors.tmp"
  mv "$LONG3R_ROOT/models/default.safetensors.tmp" "$LONG3R_ROOT/models/default.safetensors"
  echo "== installed $init as models/default.safetensors"
fi
