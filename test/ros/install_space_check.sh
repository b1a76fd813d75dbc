#!/usr/bin/env bash
# The install space on its own (what `catkin_make install` makes): in an
# environment with nothing but its setup.bash, the package is found there,
# every launch file resolves, the scripts the launch files run are installed,
# and the demo runs from it (demo.launch: the nodelet replays a bag, then the
# recorder saves the map and the trajectory).
#   install_space_check.sh BUILD_DIR DATA_DIR WORK_DIR
# BUILD_DIR: the workspace's build folder (its install rules, installed where
# catkin_make install puts them: its CMAKE_INSTALL_PREFIX, catkin's setup
# files hold that path); DATA_DIR: the ros_replay_data fixture (normal.bag,
# model.safetensors); WORK_DIR: the demo's outputs and the logs.
set -euo pipefail
build=$1
data=$2
work=$3
rm -rf "$work"
mkdir -p "$work"
install=$(sed -n 's/^CMAKE_INSTALL_PREFIX:PATH=//p' "$build/CMakeCache.txt")
[ -n "$install" ] || { echo "FAIL: no CMAKE_INSTALL_PREFIX in $build"; exit 1; }
cmake --install "$build" >"$work/install.log"

# Nothing of the source tree or the devel space: the install space's setup only.
in_install() {
  env -i HOME="$HOME" PATH=/usr/bin:/bin LANG=C.UTF-8 OMP_NUM_THREADS=2 \
    bash -c "source '$install/setup.bash' && $1"
}
fail() { echo "FAIL: $*"; exit 1; }

found=$(in_install "rospack find long3r_ros")
[ "$found" = "$install/share/long3r_ros" ] || fail "rospack finds long3r_ros at $found"
for l in long3r replay realsense usb_camera demo; do
  in_install "roslaunch --nodes long3r_ros $l.launch bag:=x.bag out_dir:=/tmp" >/dev/null ||
    fail "roslaunch cannot resolve $l.launch from the install space"
done
for s in demo_record.py play_when_subscribed.py tum_to_bag.py convert_checkpoint.py long3r_node long3r_synth; do
  [ -x "$install/lib/long3r_ros/$s" ] || fail "$s is not installed"
done
[ -f "$install/share/long3r_ros/models/default.safetensors" ] || fail "the shipped model is not installed"
[ ! -e "$install/share/long3r_ros/models/experiments" ] || fail "the experiments' checkpoints are installed"

# The demo, on its own master.
port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("localhost", 0)); print(s.getsockname()[1])')
in_install "export ROS_MASTER_URI=http://localhost:$port; timeout 600 roslaunch -p $port long3r_ros \
  demo.launch bag:=$data/normal.bag model_path:=$data/model.safetensors out_dir:=$work/demo frames:=8" \
  >"$work/demo.log" 2>&1 || { tail -30 "$work/demo.log"; fail "the demo failed from the install space"; }
[ -s "$work/demo/map.ply" ] && [ -s "$work/demo/trajectory.txt" ] && [ -f "$work/demo/summary.json" ] ||
  fail "the demo wrote no map or trajectory: $work/demo.log"
grep -q '"results": 8' "$work/demo/summary.json" || fail "not every frame answered: $(cat "$work/demo/summary.json")"
echo "install space: found, launch files resolve, the demo ran (8 frames)"
