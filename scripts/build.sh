#!/usr/bin/env bash
# Builds long3r_ros in a catkin workspace under build/ws (the repository is
# linked into its src/). Extra arguments go to catkin_make (e.g. a target).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

mkdir -p "$LONG3R_WS/src"
ln -sfn "$LONG3R_ROOT" "$LONG3R_WS/src/long3r_ros"
cd "$LONG3R_WS"
catkin_make --make-args -j"$LONG3R_JOBS" "$@" -- \
  "${LONG3R_CMAKE_PY_ARGS[@]}" -DCMAKE_BUILD_TYPE=Release -DCATKIN_ENABLE_TESTING=ON
