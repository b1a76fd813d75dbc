# Sourced by the project's scripts: common paths and the Debian pitfalls.
# shellcheck shell=bash
LONG3R_ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
LONG3R_WS=${LONG3R_WS:-$LONG3R_ROOT/build/.ws}
LONG3R_JOBS=${LONG3R_JOBS:-2}
# catkin's configure breaks with a python3 other than Debian's (e.g. pyenv's
# shims first on PATH): put /usr/bin first and pass it explicitly too.
export PATH=/usr/bin:/bin:$PATH
LONG3R_CMAKE_PY_ARGS=(-DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3)
# torch starts with one intra-op thread on Debian; OpenBLAS reads its own count.
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-$(nproc)}
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
# The ROS-free core build that the evaluation scripts run (Release, no ROS):
# long3r_build_core TARGET... configures it and builds those targets.
LONG3R_CORE=$LONG3R_ROOT/build/core
long3r_build_core() {
  cmake -S "$LONG3R_ROOT" -B "$LONG3R_CORE" -DLONG3R_WITH_ROS=OFF -DCMAKE_BUILD_TYPE=Release \
    >/dev/null
  cmake --build "$LONG3R_CORE" -j "$LONG3R_JOBS" --target "$@" >/dev/null
}

# The option parser every script uses.
# shellcheck source=scripts/parse_args.sh
source "$LONG3R_ROOT/scripts/parse_args.sh"
