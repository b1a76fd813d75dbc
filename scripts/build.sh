#!/usr/bin/env bash
# Builds long3r_ros in a catkin workspace under build/.ws (the repository is
# linked into its src/). The folder is hidden because roslaunch looks for
# launch files by walking the package folder, following links and skipping
# only dot-folders: a visible workspace would lead it round the link back into
# the repository, again and again.
#   bash scripts/build.sh [--no-tests] [--no-trainer] [--no-unity] [TARGET...]
# --no-tests leaves out the tests, --no-trainer the trainer and its tools
# (long3r_train, long3r_frame_cache, long3r_model_eval; the tests need it, so
# it implies --no-tests): what a robot needs. --no-unity compiles each
# library source alone (LONG3R_UNITY_BUILD=OFF: slower from scratch, quicker
# after editing one file). TARGETs (catkin_make's, e.g.
# long3r_node) build only those; other arguments go to make (or ninja).
# LONG3R_TORCH_DIR (a folder with TorchConfig.cmake, e.g. a CUDA libtorch;
# see scripts/install_deps.sh) builds against that libtorch instead of
# Debian's.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
tests=ON
trainer=ON
unity=ON
make_args=()
while [ $# -gt 0 ]; do
  case "$1" in
    --no-tests) tests=OFF; shift ;;
    --no-trainer) trainer=OFF; tests=OFF; shift ;;
    --no-unity) unity=OFF; shift ;;
    *) make_args+=("$1"); shift ;;
  esac
done
torch_args=()
[ -n "${LONG3R_TORCH_DIR:-}" ] && torch_args=(-DTorch_DIR="$LONG3R_TORCH_DIR")
# Ninja where it is installed: it compiles a library's sources once their
# headers exist, where make first waits for the libraries they link (the
# compile in scripts/demo.sh from a fresh clone, AMD EPYC, two cores: 181 s
# against 234 s). A workspace keeps the
# generator it was first configured with (CMake will not change it).
generator_args=()
cache=$LONG3R_WS/build/CMakeCache.txt
if command -v ninja >/dev/null &&
  { [ ! -f "$cache" ] || grep -q '^CMAKE_GENERATOR:INTERNAL=Ninja$' "$cache"; }; then
  generator_args=(--use-ninja)
fi

mkdir -p "$LONG3R_WS/src"
# catkin snapshots the environment of the test wrapper (env_cached.sh) at
# configure time and leaves out paths that do not exist yet: without this, a
# fresh workspace's tests could not import the generated Python messages.
mkdir -p "$LONG3R_WS/devel/lib/python3/dist-packages"
ln -sfn "$LONG3R_ROOT" "$LONG3R_WS/src/long3r_ros"
cd "$LONG3R_WS"
# Every option given each time: the workspace's cache keeps what the last
# build asked for otherwise. CMake's options come first: catkin_make hands
# everything after --make-args to make, a "--" included.
catkin_make "${generator_args[@]}" "${LONG3R_CMAKE_PY_ARGS[@]}" "${torch_args[@]}" -DCMAKE_BUILD_TYPE=Release \
  -DCATKIN_ENABLE_TESTING="$tests" -DLONG3R_BUILD_TESTS="$tests" -DLONG3R_BUILD_TRAINER="$trainer" \
  -DLONG3R_UNITY_BUILD="$unity" --make-args -j"$LONG3R_JOBS" "${make_args[@]}"
