#!/usr/bin/env bash
# Generates the rostest inputs: a short synthetic sequence as a bag, bags of
# bad input (make_bad_bag.py), of a pause and of a slow camera
# (make_timing_bag.py), a longer sequence for the live publisher
# (live_input_check.py), the same sequence as compressed images, robot-like
# bags (tum_to_bag.py --robot: TF tree, wheel odometry, registered depth) of one
# scene through an undistorted and a distorted lens, the same path at 320 x 240
# (robot_qvga: enough image features for the keyframe tracker, which finds
# too few at 160 x 120), a held-out robot path seen by a 2 Hz camera
# (robot_fast: every 16th frame at 640 x 480, whose turns the tracker loses
# six times), and a small random-weight model.
# Usage: make_replay_data.sh BIN_DIR OUT_DIR
set -euo pipefail
bin=$1
out=$2
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
mkdir -p "$out"
rm -rf "$out/seq"
"$bin/long3r_synth" --out "$out/seq" --frames 8 --width 160 --height 120 --seed 3 --quiet
rm -rf "$out/live"
"$bin/long3r_synth" --out "$out/live" --frames 24 --width 160 --height 120 --seed 5 --quiet
# Stamps start at 1000 s: time 0 means "no time" to TF.
/usr/bin/python3 "$root/scripts/tum_to_bag.py" "$out/seq" "$out/normal.bag" --time-offset 1000 >/dev/null
/usr/bin/python3 "$root/test/ros/make_bad_bag.py" "$out/normal.bag" "$out/bad.bag"
/usr/bin/python3 "$root/test/ros/make_timing_bag.py" "$out/normal.bag" "$out/pause.bag" \
  --pause-after 3 --pause-s 4 >/dev/null
/usr/bin/python3 "$root/test/ros/make_timing_bag.py" "$out/normal.bag" "$out/slow.bag" \
  --period 2 >/dev/null
/usr/bin/python3 "$root/scripts/tum_to_bag.py" "$out/seq" "$out/compressed.bag" --time-offset 1000 \
  --compressed jpeg >/dev/null
# One robot path through one room, rendered through a pinhole and through a
# plumb_bob lens (the distorted run is rectified by the node).
robot=(--trajectory robot --frames 40 --width 160 --height 120 --seed 7 --quiet)
rm -rf "$out/robot" "$out/robot_distorted" "$out/robot_qvga"
"$bin/long3r_synth" --out "$out/robot" "${robot[@]}"
"$bin/long3r_synth" --out "$out/robot_distorted" "${robot[@]}" --distortion -0.25 0.08 0.001 -0.001 0
"$bin/long3r_synth" --out "$out/robot_qvga" "${robot[@]}" --width 320 --height 240
for s in robot robot_distorted robot_qvga; do
  /usr/bin/python3 "$root/scripts/tum_to_bag.py" "$out/$s" "$out/$s.bag" --robot \
    --depth-topic /camera/depth/image_raw --time-offset 1000 >/dev/null
done
rm -rf "$out/robot_fast"
# Images of every 16th frame only (the ground truth and the odometry keep the
# path's every frame): the bag tum_to_bag.py --stride 16 made from all 400
# images, message for message, rendered in a sixteenth of the time.
"$bin/long3r_synth" --out "$out/robot_fast" --trajectory robot --frames 400 --width 640 \
  --height 480 --seed 2000000 --image-every 16 --quiet
/usr/bin/python3 "$root/scripts/tum_to_bag.py" "$out/robot_fast" "$out/robot_fast.bag" --robot \
  --depth-topic /camera/depth/image_raw --time-offset 1000 >/dev/null
"$bin/long3r_make_random_model" --variant spann3r --size tiny --img-size 224 --seed 1 \
  --out "$out/model.safetensors" >/dev/null
echo "replay data in $out"
