#!/usr/bin/env bash
# The held-out numbers of docs/model_card.md: the shipped model, its
# inference-time ablations, the untrained model and the constant-depth plane,
# on generated scenes never used in training (seeds 2000000..), 50- and
# 200-frame sequences, all at the model's own input size. Writes one JSON per
# row and column into OUT_DIR.
#   bash scripts/model_card_eval.sh [OUT_DIR] [--model FILE] [--threads N]
#        [--untrained CONFIG] [--retrained DIR] [--only-retrained]
# --untrained: the architecture of the untrained row, a named config or a JSON
# file (default config/model_pairs_wide_k5.json, the shipped model's; long3r_ship
# for the previous one, models/experiments/long3r_ship).
# --retrained: also score the retrained ablations of scripts/train_ablations.sh
# found in DIR (default build/train_ablations); --only-retrained: only those.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

out="$LONG3R_ROOT/build/model_card"
model="$LONG3R_ROOT/models/default.safetensors"
threads=$(nproc)
retrained="$LONG3R_ROOT/build/train_ablations"
untrained="$LONG3R_ROOT/config/model_pairs_wide_k5.json"
only_retrained=0
long3r_parse_args --model=model --threads=threads --retrained=retrained \
  --untrained=untrained --only-retrained?only_retrained @out -- "$@"
build=$LONG3R_CORE
long3r_build_core app_long3r_model_eval
mkdir -p "$out"

row() {  # name args...
  local name=$1; shift
  # 200-frame clouds are scored on every fourth pixel, as in the card's tables.
  for spec in "50 3 2" "200 1 4"; do
    local frames seqs step
    read -r frames seqs step <<<"$spec"
    echo "== $name, $frames frames"
    "$build/long3r_model_eval" "$@" --frames "$frames" --sequences "$seqs" --stride 2 \
      --pixel-step "$step" \
      --threads "$threads" --json "$out/${name}_${frames}.json" \
      --picture "$out/${name}_${frames}.png"
  done
}
if [ "$only_retrained" = 0 ]; then
  row long3r --model "$model"
  # The rows without a model of their own run at the size the model ran at.
  size=$(/usr/bin/python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["img_size"])' \
    "$out/long3r_50.json")
  row no_long_term --model "$model" --long-term-capacity 0
  row spann3r_memory --model "$model" --long-term-policy spann3r
  row untrained --untrained "$untrained" --img-size "$size"
  row constant_depth --baseline constant-depth --img-size "$size"
fi
for name in no_long_term spann3r_memory; do
  # Each retrained model carries its own memory config in its metadata.
  trained="$retrained/$name/stage2/model.safetensors"
  if [ -f "$retrained/$name/stage2/done" ]; then
    row "${name}_retrained" --model "$trained"
  else
    echo "== ${name}_retrained: no finished run in $retrained/$name, skipped"
  fi
done
