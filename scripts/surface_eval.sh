#!/usr/bin/env bash
# What fusing the views does to the map's error, on generated sequences with
# ground truth, all through long3r_eval with the same options:
#   map        the voxel map (one point per voxel, the mean of what fell in it)
#   averaged   each true surface voxel's predictions averaged over the frames
#              that saw it (long3r_reconstruct --fusion-split): what an ideal
#              average of the views reaches; its error is the part every view
#              shares
#   rescaled   the same with each frame's own depth ratio divided out: shape
#              error alone
#   surface    the TSDF's surface (surface_enabled), and its mesh's vertices
# Frames are placed by the ground truth (--poses groundtruth) with the scale
# from the depth images, so that only the pointmaps' own error is measured;
# --model-poses places them by the model's pointmaps instead (no split then).
#   bash scripts/surface_eval.sh [--frames N] [--model FILE] [--img-size N] [--out DIR]
#        [--model-poses] [-- extra long3r_reconstruct options, e.g. --surface-min-weight 5]
# Defaults: 60 frames of the demo's two sequences (seed 7: hand-held and the
# robot's, rendered at 224 x 224 as the demo's), the shipped model at its own
# input size (--img-size N: at N x N), build/surface_eval.
set -euo pipefail
source "$(dirname "$0")/env.sh"
root=$LONG3R_ROOT
frames=60
model="$root/models/default.safetensors"
img_size=""
render_size=224
out="$root/build/surface_eval"
model_poses=0
extra=()
long3r_parse_args --frames=frames --model=model --img-size=img_size --out=out \
  --model-poses?model_poses --=extra -- "$@"
size=()
[ -n "$img_size" ] && size=(--img-size "$img_size")
bin=$LONG3R_CORE
long3r_build_core app_long3r_synth app_long3r_reconstruct app_long3r_eval
mkdir -p "$out"
field() { grep -m1 "$1" "$2" | awk '{print $4}'; }
printf "%-10s %-10s %9s %9s %9s %9s\n" sequence cloud "Acc cm" "Acc med" "Comp cm" "points"
for kind in handheld robot; do
  seq="$out/seq_${kind}_$frames"
  if [ ! -f "$seq/groundtruth.txt" ]; then
    args=()
    [ "$kind" = robot ] && args=(--trajectory robot)
    "$bin/long3r_synth" --out "$seq" --frames "$frames" --seed 7 --width "$render_size" \
      --height "$render_size" "${args[@]}" --quiet >/dev/null
  fi
  run="$out/run_${kind}_$frames"
  placement=(--poses groundtruth)
  [ "$model_poses" = 1 ] && placement=()
  split=(--fusion-split)
  [ "$model_poses" = 1 ] && split=()
  "$bin/long3r_reconstruct" "$seq" --model "$model" --out "$run" "${size[@]}" \
    --scale-source depth --surface-enabled true "${placement[@]}" "${split[@]}" "${extra[@]}" >"$run.log" 2>&1 ||
    { echo "long3r_reconstruct failed: see $run.log" >&2; exit 1; }
  clouds=(map surface mesh)
  [ "$model_poses" = 0 ] && clouds=(map averaged averaged_rescaled surface mesh)
  for cloud in "${clouds[@]}"; do
    "$bin/long3r_eval" --gt "$seq" --est-traj "$run/trajectory.txt" --est-map "$run/$cloud.ply" \
      --out "$run/eval_$cloud" >"$run/eval_$cloud.log" 2>&1
    m="$run/eval_$cloud.log"
    printf "%-10s %-10s %9s %9s %9s %9s\n" "$kind" "$cloud" "$(field 'Acc mean' "$m")" \
      "$(field 'Acc median' "$m")" "$(field 'Comp mean' "$m")" \
      "$(grep -m1 'points pred' "$m" | awk '{print $5}')"
  done
  grep -h "fusion split:\|surface:" "$run.log" | sed "s/^/  $kind: /"
  # The map stage's time a frame (frames.csv map_ms: voxel map, and surface
  # when on), median over the mapped frames, with the surface and without.
  "$bin/long3r_reconstruct" "$seq" --model "$model" --out "$run.nosurface" "${size[@]}" \
    --scale-source depth "${placement[@]}" "${extra[@]}" >"$run.nosurface.log" 2>&1
  median_map_ms() {
    /usr/bin/python3 -c "
import csv, statistics, sys
rows = [r for r in csv.DictReader(open(sys.argv[1])) if r['added_to_map'] == '1']
print('%.2f' % statistics.median(float(r['map_ms']) for r in rows))" "$1/frames.csv"
  }
  echo "  $kind: map stage median $(median_map_ms "$run") ms a frame with the surface," \
    "$(median_map_ms "$run.nosurface") ms without"
done
