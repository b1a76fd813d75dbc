#!/usr/bin/env bash
# The camera path of long3r_reconstruct with each pose source on the
# held-out generated sequences at a camera's resolution (640 x 480): ATE
# (long3r_eval, Sim(3)-aligned) and its ratio to a camera that never moves
# (the RMS distance of the true positions from their mean), and the keyframe
# tracker's time per frame (frames.csv's tracking_ms: median and 90th
# percentile, the median of its ORB detection, and the CPU). The controls:
# the same tracker given a constant-depth plane instead of the model's depth
# (--tracker-constant-depth), which the model's depth must beat, and given
# the sequence's true depth (--tracker-true-depth), what a perfect depth
# would leave of the error (the tracker's own). depth_camera: an RGB-D
# camera's run (--scale-source depth, the tracker lifting its features by the
# depth images), its path in metres: its ATE without the scale alignment
# (SE(3)) beside the Sim(3) one; depth_scale: the same camera with the depth
# giving only the scale (--tracker-depth-images false: the tracker lifts by
# the model's depth, as for a monocular camera).
#   bash scripts/keyframes_eval.sh [--stride N] [--frames N] [--model FILE] [--out DIR]
#        [--sources "model keyframes plane true_depth depth_camera depth_scale"]
# Defaults: stride 2, 60 frames, the shipped model, build/keyframes_eval, every source.
# Extra arguments after -- go to long3r_reconstruct (e.g. -- --tracker-solver essential).
set -euo pipefail
source "$(dirname "$0")/env.sh"
root=$LONG3R_ROOT
stride=2
frames=60
model="$root/models/default.safetensors"
out="$root/build/keyframes_eval"
sources="model keyframes plane true_depth depth_camera depth_scale"
extra=()
long3r_parse_args --stride=stride --frames=frames --model=model --out=out --sources=sources \
  --=extra -- "$@"
bin=$LONG3R_CORE
long3r_build_core app_long3r_synth app_long3r_reconstruct app_long3r_eval
mkdir -p "$out"
ratio() { /usr/bin/python3 -c "import sys; print('%.3f' % (float(sys.argv[1]) / 100 / float(sys.argv[2])))" "$1" "$2"; }
for seed in 2000000 2000001 2000002; do
  seq="$out/seq_${seed}_$((frames * stride))"
  if [ ! -f "$seq/groundtruth.txt" ]; then
    "$bin/long3r_synth" --out "$seq" --seed "$seed" --frames $((frames * stride)) --width 640 \
      --height 480 --quiet >/dev/null
  fi
  # A camera that never moves: the true positions' RMS distance from their mean.
  still=$(/usr/bin/python3 - "$seq/groundtruth.txt" "$stride" "$frames" <<'EOF'
import math, sys
rows = [l.split() for l in open(sys.argv[1]) if l.strip() and not l.startswith('#')]
stride, frames = int(sys.argv[2]), int(sys.argv[3])
p = [[float(v) for v in r[1:4]] for r in rows[::stride][:frames]]
m = [sum(c) / len(p) for c in zip(*p)]
print('%.4f' % math.sqrt(sum(sum((a - b) ** 2 for a, b in zip(q, m)) for q in p) / len(p)))
EOF
)
  line="seed $seed (still camera $(ratio "$still" 0.0001) cm):"
  for source in $sources; do
    run="$out/${seed}_${source}_s${stride}"
    args=(--pose-source "$source")
    [ "$source" = plane ] && args=(--pose-source keyframes --tracker-constant-depth)
    [ "$source" = true_depth ] && args=(--pose-source keyframes --tracker-true-depth)
    [ "$source" = depth_camera ] && args=(--pose-source keyframes --scale-source depth)
    [ "$source" = depth_scale ] &&
      args=(--pose-source keyframes --scale-source depth --tracker-depth-images false)
    "$bin/long3r_reconstruct" --model "$model" --out "$run" --stride "$stride" \
      --max-frames "$frames" "${args[@]}" "${extra[@]}" "$seq" > "$run.log" 2>&1
    ate=$("$bin/long3r_eval" --gt "$seq" --est-traj "$run/trajectory.txt" --out "$run/eval" | awk '/ATE RMSE/{print $4}')
    line="$line  $source ATE $ate cm ($(ratio "$ate" "$still")x)"
    if [ "$source" = depth_camera ] || [ "$source" = depth_scale ]; then
      se3=$("$bin/long3r_eval" --gt "$seq" --est-traj "$run/trajectory.txt" --no-scale --out "$run/eval_se3" | awk '/ATE RMSE/{print $4}')
      line="$line, in metres (SE(3)) $se3 cm ($(ratio "$se3" "$still")x)"
    fi
    if [ "$source" = keyframes ]; then
      ms=$(/usr/bin/python3 - "$run/frames.csv" <<'EOF'
import csv, statistics, sys
rows = [r for r in csv.DictReader(open(sys.argv[1])) if r['tracking_ms']]
t = sorted(float(r['tracking_ms']) for r in rows)
f = statistics.median(float(r['tracking_features_ms']) for r in rows)
print('%.1f ms median (ORB detection %.1f ms), %.1f ms p90' % (statistics.median(t), f, t[min(len(t) - 1, int(0.9 * len(t)))]))
EOF
)
      line="$line, tracking $ms"
    fi
  done
  echo "$line"
done
# The CPU the times were measured on (long3r_reconstruct's summary).
grep -m1 -h '^ *cpu ' "$out"/2000000_*_s"${stride}".log | head -1 |
  sed 's/^ */tracking times measured on: /'
