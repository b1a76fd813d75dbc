#!/usr/bin/env bash
# The metric scale of frames placed by odometry (pose_source odometry,
# scale_source odometry: BaselineScale triangulates the images' matches over
# the odometry's baseline) against the scale from true depth
# (--scale-source depth), with long3r_reconstruct and a model (default: the
# shipped one) on held-out generated robot sequences (a wheeled base, 60
# frames at 640 x 480, the ground truth standing in for the odometry): the
# scale applied, from how many samples, and the first frame mapped.
#   bash scripts/baseline_scale_eval.sh [--model FILE] [--out DIR]
set -euo pipefail
source "$(dirname "$0")/env.sh"
root=$LONG3R_ROOT
model="$root/models/default.safetensors"
out="$root/build/baseline_scale_eval"
long3r_parse_args --model=model --out=out -- "$@"
bin=$LONG3R_CORE
long3r_build_core app_long3r_synth app_long3r_reconstruct
mkdir -p "$out"
for seed in 2000000 2000001 2000002; do
  seq="$out/robot_$seed"
  if [ ! -f "$seq/groundtruth.txt" ]; then
    "$bin/long3r_synth" --out "$seq" --seed "$seed" --frames 60 --width 640 --height 480 \
      --trajectory robot --quiet >/dev/null
  fi
  line="seed $seed:"
  for source in odometry depth; do
    run="$out/${seed}_$source"
    "$bin/long3r_reconstruct" --model "$model" --out "$run" --poses groundtruth \
      --scale-source "$source" "$seq" > "$run.log" 2>&1
    applied=$(grep -o "metric scale [0-9.]* +- [0-9.]* m per model unit from [0-9]* samples" \
      "$run.log" | sed 's/metric scale //; s/ m per model unit from/ m\/unit,/' || true)
    first=$(/usr/bin/python3 - "$run/frames.csv" <<'EOF'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
mapped = [r['frame'] for r in rows if r['added_to_map'] == '1']
print(f"mapped from frame {mapped[0]}, {len(mapped)} of {len(rows)}" if mapped else f"never mapped (0 of {len(rows)})")
EOF
)
    line="$line  $source: ${applied:-no scale}, $first;"
  done
  echo "$line"
done
