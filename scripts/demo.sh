#!/usr/bin/env bash
# The main job on the embedded default: installs what is missing, builds,
# generates a synthetic indoor sequence with ground truth, replays it as a bag
# through the long3r_ros nodelet, and writes the map and the trajectory to
# OUT_DIR (default build/demo), then scores them against the ground truth.
# --robot: a wheeled robot's bag instead (tf_static base_link -> camera, wheel
# odometry odom -> base_link, registered depth), replayed as on a robot:
# map -> odom published, z-up map, frames placed by the odometry and scaled
# to metres by the depth (the shipped model's own poses are too coarse for an
# odometry scale; README, "Metric scale and pose source"); --pose-source and
# --scale-source choose otherwise (scripts/units_table.sh runs each pair);
# without --robot they default to the node's own (keyframes, no metric scale).
#   bash scripts/demo.sh [OUT_DIR] [--frames N] [--model FILE] [--robot]
#        [--pose-source model|keyframes|odometry] [--scale-source none|odometry|depth]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

out="$LONG3R_ROOT/build/demo"
frames=60
model=""
robot=0
pose_source=""
scale_source=""
long3r_parse_args --frames=frames --model=model --robot?robot --pose-source=pose_source \
  --scale-source=scale_source @out -- "$@"
# roslaunch starts the nodelet in ~/.ros: a model named relative to here by path.
if [ -n "$model" ]; then
  [ -f "$model" ] || { echo "demo: no model file $model" >&2; exit 2; }
  model=$(realpath "$model")
fi

"$LONG3R_ROOT/scripts/install_deps.sh"
# Only what the demo runs: the nodelet, the generator, the scorer (no tests,
# no trainer; the long3r_demo target).
"$LONG3R_ROOT/scripts/build.sh" --no-trainer long3r_demo
set +u; source "$LONG3R_WS/devel/setup.bash"; set -u
bin="$LONG3R_WS/devel/lib/long3r_ros"

mkdir -p "$out"
# roslaunch starts its nodes in ~/.ros: the bag and the outputs by absolute path.
out=$(cd "$out" && pwd)
echo "== generating a $frames-frame synthetic sequence"
rm -rf "$out/sequence"
gt_traj="$out/sequence/groundtruth.txt"
launch_args=()
if [ "$robot" = 1 ]; then
  "$bin/long3r_synth" --out "$out/sequence" --frames "$frames" --seed 7 --trajectory robot --quiet
  /usr/bin/python3 "$LONG3R_ROOT/scripts/tum_to_bag.py" "$out/sequence" "$out/sequence.bag" \
    --robot --depth-topic /camera/depth_registered/image_raw --time-offset 1000 >/dev/null
  # The node's trajectory is then base_link's, in metres.
  gt_traj="$out/sequence/base_groundtruth.txt"
  launch_args=(odom_frame:=odom base_frame:=base_link pose_source:="${pose_source:-odometry}"
              scale_source:="${scale_source:-depth}" depth:=/camera/depth_registered/image_raw)
else
  "$bin/long3r_synth" --out "$out/sequence" --frames "$frames" --seed 7 --quiet
  /usr/bin/python3 "$LONG3R_ROOT/scripts/tum_to_bag.py" "$out/sequence" "$out/sequence.bag" \
    --time-offset 1000 >/dev/null
  # Empty: the node's defaults (pose_source keyframes, no metric scale).
  launch_args=(pose_source:="$pose_source" scale_source:="$scale_source")
fi

if [ -z "$model" ]; then
  if [ -f "$LONG3R_ROOT/models/default.safetensors" ]; then
    model="$LONG3R_ROOT/models/default.safetensors"
  else
    model="$out/random_model.safetensors"
    cat <<'WARN'
######################################################################
#  WARNING: no trained model ships with the package yet.             #
#  The demo runs a small RANDOM-WEIGHT model: the pipeline runs end  #
#  to end, but the map and trajectory it writes are meaningless.     #
######################################################################
WARN
    "$LONG3R_ROOT/scripts/build.sh" --no-trainer app_long3r_make_random_model >/dev/null
    "$bin/long3r_make_random_model" --variant spann3r --size small --img-size 224 --seed 1 \
      --out "$model"
  fi
fi

echo "== replaying through the nodelet (model: $model)"
roslaunch long3r_ros demo.launch bag:="$out/sequence.bag" model_path:="$model" \
  out_dir:="$out" frames:="$frames" "${launch_args[@]}" 2>&1 | tee "$out/roslaunch.log" | grep -E "WARN|ERROR|FATAL|demo:|save_map" || true
[ -s "$out/map.ply" ] && [ -f "$out/trajectory.txt" ] || { echo "demo failed: see $out/roslaunch.log" >&2; exit 1; }

echo "== scoring against the ground truth"
# The bag's stamps start at 1000 s (tum_to_bag.py --time-offset above).
"$bin/long3r_eval" --gt "$out/sequence" --gt-traj "$gt_traj" --est-traj "$out/trajectory.txt" --est-map "$out/map.ply" \
  --offset -1000 --out "$out/eval" || echo "(evaluation needs at least 3 estimated poses)"
echo "== done: $out/map.ply, $out/trajectory.txt, $out/eval/"
