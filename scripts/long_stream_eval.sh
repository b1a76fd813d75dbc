#!/usr/bin/env bash
# A model on long streams against the constant-depth plane, at the model's
# own resolution (docs/model_card.md, "Long streams"): the card's held-out
# seeds (2000000 on), 50-frame sequences (3, clouds on every second pixel)
# and one 200-frame sequence (every fourth pixel), at each --stride (path
# frames between used frames), poses from the model's own pointmaps
# (PnP-RANSAC classic, float32). Prints one markdown row per length and
# stride: the model's and the plane's Acc / Comp and ATE, the ratios
# model / plane and the frames posed; writes each run's JSON and log to
# --out.
#   bash scripts/long_stream_eval.sh --model FILE [--strides "2 8"]
#        [--threads N] [--out DIR]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

model=""
strides="2 8"
threads=1
out="$LONG3R_ROOT/build/long_stream_eval"
long3r_parse_args --model=model --strides=strides --threads=threads --out=out -- "$@"
[ -n "$model" ] && model=$(realpath "$model")
[ -n "$model" ] || { echo "long_stream_eval.sh: --model FILE is needed" >&2; exit 2; }
long3r_build_core app_long3r_model_eval
mkdir -p "$out"
# The model's own resolution (the size it records it was trained at, else its
# config's img_size, as long3r_model_eval takes it), for the plane too.
img_size=$(/usr/bin/python3 - "$model" <<'PY'
import json, struct, sys
with open(sys.argv[1], "rb") as f:
    header = json.loads(f.read(struct.unpack("<Q", f.read(8))[0]))
config = json.loads(header["__metadata__"]["config"])
print(max(config.get("input_width", 0), config.get("input_height", 0))
      or max(config["dust3r"]["img_size"]))
PY
)

echo "| frames | stride | model Acc / Comp | plane Acc / Comp | model ATE | plane ATE | ATE ratio | Acc ratio | frames posed |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for stride in $strides; do
  for spec in "50 3 2" "200 1 4"; do
    read -r frames seqs step <<<"$spec"
    common=(--frames "$frames" --sequences "$seqs" --stride "$stride" --pixel-step "$step"
            --threads "$threads")
    "$LONG3R_CORE/long3r_model_eval" --model "$model" "${common[@]}" \
      --json "$out/model_${frames}_s${stride}.json" >"$out/model_${frames}_s${stride}.log" 2>&1
    "$LONG3R_CORE/long3r_model_eval" --baseline constant-depth --img-size "$img_size" \
      "${common[@]}" --json "$out/plane_${frames}_s${stride}.json" \
      >"$out/plane_${frames}_s${stride}.log" 2>&1
    /usr/bin/python3 - "$out/model_${frames}_s${stride}.json" "$out/plane_${frames}_s${stride}.json" \
      "$frames" "$stride" <<'PY'
import json, sys
m, p = (json.load(open(f))["mean"] for f in sys.argv[1:3])
frames, stride = sys.argv[3:5]
print("| %s | %s | %.3f / %.3f | %.3f / %.3f | %.3f | %.3f | %.2f | %.2f | %.1f of %s |" % (
    frames, stride, m["acc_mean_m"], m["comp_mean_m"], p["acc_mean_m"], p["comp_mean_m"],
    m["ate_rmse_m"], p["ate_rmse_m"], m["ate_rmse_m"] / p["ate_rmse_m"],
    m["acc_mean_m"] / p["acc_mean_m"],
    m["posed"], frames))
PY
  done
done
