#!/usr/bin/env bash
# Replays a bag through long3r_ros with rviz (config/long3r.rviz) on a virtual
# X display and saves a PNG of the rviz window once the replay is over. Used for
# the README picture; needs no screen and no GPU (Mesa renders in software).
#   bash scripts/rviz_snapshot.sh [--bag BAG] [--model FILE] [--out PNG]
#                                 [--frames N] [--size WxH]
# Without --bag it generates a synthetic sequence (seed 7) and replays that.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

bag=""
model=""
out="$LONG3R_ROOT/build/rviz_snapshot.png"
frames=60
size=1280x800
long3r_parse_args --bag=bag --model=model --out=out --frames=frames --size=size -- "$@"

"$LONG3R_ROOT/scripts/install_deps.sh"
"$LONG3R_ROOT/scripts/build.sh" >/dev/null
set +u; source "$LONG3R_WS/devel/setup.bash"; set -u
bin="$LONG3R_WS/devel/lib/long3r_ros"
work=$(mktemp -d)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT

expected=0  # pointmaps to wait for; 0 = until the node goes quiet
if [ -z "$bag" ]; then
  expected=$frames
  "$bin/long3r_synth" --out "$work/sequence" --frames "$frames" --seed 7 --quiet
  /usr/bin/python3 "$LONG3R_ROOT/scripts/tum_to_bag.py" "$work/sequence" "$work/sequence.bag" \
    --time-offset 1000 >/dev/null
  bag="$work/sequence.bag"
fi
if [ -z "$model" ]; then model="$LONG3R_ROOT/models/default.safetensors"; fi

# A free display number.
display=99
while [ -e "/tmp/.X11-unix/X$display" ] || [ -e "/tmp/.X$display-lock" ]; do
  display=$((display + 1))
done
Xvfb ":$display" -screen 0 "${size}x24" -nolisten tcp >"$work/xvfb.log" 2>&1 &
pids+=($!)
export DISPLAY=":$display" LIBGL_ALWAYS_SOFTWARE=1
for _ in $(seq 50); do [ -e "/tmp/.X11-unix/X$display" ] && break; sleep 0.1; done

# The queue keeps every frame, so the picture shows the whole sequence; the
# delay lets rviz (slow to start with software rendering) subscribe first.
roslaunch "$LONG3R_ROOT/launch/replay.launch" bag:="$bag" model_path:="$model" rviz:=true \
  queue_size:=1000 start_delay_s:=30 >"$work/roslaunch.log" 2>&1 &
pids+=($!)

# Wait (wall time) for every pointmap of a generated bag, or until none arrived
# for 30 s after the first one (rviz rendering in software shares the cores
# with the model), give rviz a moment to draw, then grab the screen.
if ! /usr/bin/python3 - "$out" "$DISPLAY" "$expected" <<'EOF'
import os, sys, time
import rospy
from PIL import ImageGrab
from long3r_ros.msg import Pointmap

out, display, expected = sys.argv[1], sys.argv[2], int(sys.argv[3])
rospy.init_node('rviz_snapshot', anonymous=True, disable_signals=True)
state = {'n': 0, 'last': time.time()}
def cb(_):
    state['n'] += 1
    state['last'] = time.time()
rospy.Subscriber('/long3r/pointmap', Pointmap, cb, queue_size=100)
start = time.time()
while time.time() - start < 1800:
    time.sleep(0.5)
    if expected > 0 and state['n'] >= expected:
        break
    if state['n'] > 0 and time.time() - state['last'] > 30.0:
        break
else:
    sys.exit('rviz_snapshot: no pointmaps within 30 minutes')
time.sleep(3.0)
for _ in range(30):
    img = ImageGrab.grab(xdisplay=display)
    if not all(lo == hi for lo, hi in img.getextrema()):
        break
    time.sleep(2.0)
else:
    sys.exit('rviz_snapshot: the screen stayed blank (rviz did not start?)')
tmp = out + '.tmp.png'
img.save(tmp)
os.replace(tmp, out)
print('rviz_snapshot: %d frames, wrote %s' % (state['n'], out))
EOF
then
  cp "$work/roslaunch.log" "${out%.png}.log"
  echo "rviz_snapshot failed; roslaunch log (all of it in ${out%.png}.log):" >&2
  tail -n 30 "$work/roslaunch.log" >&2
  exit 1
fi
