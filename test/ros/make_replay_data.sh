#!/usr/bin/env bash
# Generates the rostest inputs: a short synthetic sequence as a bag, bags of
# bad input (make_bad_bag.py), of a pause and of a slow camera
# (make_timing_bag.py), a longer sequence for the live publisher
# (live_input_check.py), and a small random-weight model.
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
"$bin/long3r_make_random_model" --variant spann3r --size tiny --img-size 224 --seed 1 \
  --out "$out/model.safetensors" >/dev/null
echo "replay data in $out"
