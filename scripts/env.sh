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
