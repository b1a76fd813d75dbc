#!/usr/bin/env bash
# Where the keyframe tracker's lost frames go (tracker_motion_prior) on a
# wheeled robot with odometry: long3r_reconstruct with pose_source keyframes
# and scale_source depth (an RGB-D robot: the stream is metric from its
# first frame) on held-out generated robot sequences (640 x 480, 400 frames
# at 30 Hz, taken every --stride-th: at 16, a 2 Hz camera, the turns lose
# frames), each prior in turn: constant_velocity (the default), odometry from
# the wheels (tum_to_bag.py's: 3 % scale error, 1 degree of yaw drift a
# metre, the same odometry the robot bags carry on /tf) and odometry from
# the ground truth. Prints the path's ATE (Sim(3)-aligned and in metres,
# SE(3)) and how many frames the images did not place.
#   bash scripts/odometry_prior_eval.sh [--stride N] [--frames N] [--model FILE] [--out DIR]
# Defaults: stride 16, 25 frames, the shipped model, build/odometry_prior_eval.
# Extra arguments after -- go to long3r_reconstruct.
set -euo pipefail
source "$(dirname "$0")/env.sh"
root=$LONG3R_ROOT
stride=16
frames=25
model="$root/models/default.safetensors"
out="$root/build/odometry_prior_eval"
extra=()
long3r_parse_args --stride=stride --frames=frames --model=model --out=out --=extra -- "$@"
bin=$LONG3R_CORE
long3r_build_core app_long3r_synth app_long3r_reconstruct app_long3r_eval
mkdir -p "$out"
length=$((stride * frames))
for seed in 2000000 2000001 2000002; do
  seq="$out/robot_${seed}_$length"
  if [ ! -f "$seq/groundtruth.txt" ]; then
    "$bin/long3r_synth" --out "$seq" --seed "$seed" --frames "$length" --width 640 --height 480 \
      --trajectory robot --quiet >/dev/null
  fi
  # The wheel odometry of the same path, as the robot bags' /tf carries it
  # (the bag of a 160 x 120 rendering: only its odometry is wanted).
  odometry="$out/robot_${seed}_${length}_wheel_odometry.txt"
  if [ ! -f "$odometry" ]; then
    small="$out/robot_${seed}_${length}_small"
    "$bin/long3r_synth" --out "$small" --seed "$seed" --frames "$length" --width 160 \
      --height 120 --trajectory robot --quiet >/dev/null
    cmp -s "$small/groundtruth.txt" "$seq/groundtruth.txt" ||
      { echo "odometry_prior_eval.sh: the 160 x 120 path differs from the sequence's" >&2; exit 1; }
    /usr/bin/python3 "$root/scripts/tum_to_bag.py" "$small" "$small.bag" --robot \
      --odom-tum "$odometry" >/dev/null 2>&1
    rm -rf "$small" "$small.bag"
  fi
  line="seed $seed:"
  for prior in constant_velocity odometry:wheels odometry:groundtruth; do
    name=${prior//:/_}
    run="$out/${seed}_s${stride}_$name"
    args=(--tracker-motion-prior "${prior%%:*}")
    [ "$prior" = odometry:wheels ] && args+=(--odometry "$odometry")
    "$bin/long3r_reconstruct" --model "$model" --out "$run" --stride "$stride" \
      --max-frames "$frames" --pose-source keyframes --scale-source depth "${args[@]}" \
      "${extra[@]}" "$seq" >"$run.log" 2>&1
    sim3=$("$bin/long3r_eval" --gt "$seq" --est-traj "$run/trajectory.txt" --out "$run/eval" |
      awk '/ATE RMSE/{print $4}')
    se3=$("$bin/long3r_eval" --gt "$seq" --est-traj "$run/trajectory.txt" --no-scale \
      --out "$run/eval_se3" | awk '/ATE RMSE/{print $4}')
    lost=$(/usr/bin/python3 - "$run/frames.csv" <<'EOF'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print('%d of %d' % (sum(r['tracking'] not in ('tracked', 'keyframe') for r in rows), len(rows)))
EOF
)
    line="$line  $name ATE $sim3 cm (SE(3) $se3 cm, $lost not placed by the images)"
  done
  echo "$line"
done
