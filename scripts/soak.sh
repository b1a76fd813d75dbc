#!/usr/bin/env bash
# Soak benchmark (not a CI test): long3r.launch with the shipped model, fed
# N frames of a generated 224x224 sequence at a fixed rate with wall-clock
# stamps (scripts/soak.py); prints the node's RSS and the result latency
# every 500 frames. docs/performance.md has the figures.
#   bash scripts/soak.sh [--frames N] [--rate HZ] [--every K] [--queue-size Q]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

frames=10000
rate=8
every=500
queue=1
long3r_parse_args --frames=frames --rate=rate --every=every --queue-size=queue -- "$@"

"$LONG3R_ROOT/scripts/build.sh" >/dev/null
set +u; source "$LONG3R_WS/devel/setup.bash"; set -u
bin="$LONG3R_WS/devel/lib/long3r_ros"
work=$(mktemp -d /tmp/long3r_soak.XXXXXX)
launch_pid=""
trap '[ -n "$launch_pid" ] && kill "$launch_pid" 2>/dev/null; wait 2>/dev/null; rm -rf "$work"' EXIT

"$bin/long3r_synth" --out "$work/seq" --frames 48 --seed 11 --quiet
port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("localhost", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI=http://localhost:$port
roslaunch -p "$port" long3r_ros long3r.launch queue_size:="$queue" >"$work/roslaunch.log" 2>&1 &
launch_pid=$!
echo "== soak: $frames frames at $rate Hz, queue_size $queue (roslaunch log: $work/roslaunch.log)"
/usr/bin/python3 "$LONG3R_ROOT/scripts/soak.py" --sequence "$work/seq" --frames "$frames" \
  --rate "$rate" --every "$every"
