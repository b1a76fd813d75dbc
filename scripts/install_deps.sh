#!/usr/bin/env bash
# Installs every Debian package long3r_ros needs. Idempotent: when everything is
# already present it only checks and returns within a second or two.
# Works as root, or through sudo otherwise.
#
# Another libtorch (e.g. one built with CUDA): set LONG3R_TORCH_DIR to the
# folder holding its TorchConfig.cmake,
#   LONG3R_TORCH_DIR=$(python3 -c 'import torch; print(torch.utils.cmake_prefix_path)')/Torch \
#     bash scripts/install_deps.sh
# Debian's CPU libtorch (libtorch-dev) and its Python torch (python3-torch)
# are then left out; scripts/build.sh builds against LONG3R_TORCH_DIR, and
# the Python scripts use the python3 of that torch.
set -euo pipefail

PACKAGES=(
  # toolchain
  build-essential cmake ninja-build pkg-config git clang-format ccache
  # ROS 1 from Debian (installed under /usr; no setup.bash needed)
  ros-base-dev catkin libroscpp-dev libnodelet-dev python3-nodelet
  libpcl-ros-dev libcv-bridge-dev libimage-transport-dev libtf2-ros-dev
  libtf2-geometry-msgs-dev libtf2-eigen-dev libdiagnostic-updater-dev libimage-geometry-dev
  libmessage-filters-dev libdepth-image-proc-dev libpcl-conversions-dev
  libsensor-msgs-dev libgeometry-msgs-dev libnav-msgs-dev libstd-srvs-dev
  ros-message-generation ros-message-runtime
  python3-rosbag python3-rospy python3-rosservice python3-rostest python3-rosnode
  python3-rostopic python3-roslaunch
  # message and TF bindings the Python test and demo nodes import
  python3-tf2-ros python3-nav-msgs python3-sensor-msgs python3-visualization-msgs python3-std-srvs python3-diagnostic-msgs
  python3-genmsg python3-gencpp python3-genpy python3-catkin-pkg python3-empy python3-nose
  image-transport-tools rviz libnodeletlib-tools rosbash rosout ros-core
  # core libraries
  libtorch-dev libopenblas0-openmp libopenblas0-pthread libopencv-dev libpcl-dev libeigen3-dev
  nlohmann-json3-dev libnanoflann-dev googletest libgtest-dev libgmock-dev
  # 3-D occupancy; the TSDF surface and mesh (optional: without it the rest builds)
  liboctomap-dev libopen3d-dev
  # the Gloo headers of libtorch's c10d (data-parallel training)
  libgloo-dev
  # python side (checkpoint converter)
  python3-torch python3-numpy python3-yaml
  # scripts/rviz_snapshot.sh: rviz on a virtual display, PNG capture
  xvfb python3-pil
)

if [ -n "${LONG3R_TORCH_DIR:-}" ]; then
  if [ ! -f "$LONG3R_TORCH_DIR/TorchConfig.cmake" ]; then
    echo "install_deps.sh: LONG3R_TORCH_DIR=$LONG3R_TORCH_DIR holds no TorchConfig.cmake" >&2
    exit 1
  fi
  kept=()
  for p in "${PACKAGES[@]}"; do
    case "$p" in libtorch-dev | python3-torch | libgloo-dev) ;; *) kept+=("$p") ;; esac
  done
  PACKAGES=("${kept[@]}")
  echo "install_deps.sh: libtorch from $LONG3R_TORCH_DIR (Debian's libtorch-dev, python3-torch and the Gloo headers built for them left out)"
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "install_deps.sh: not root and no sudo; install these packages yourself:" >&2
    echo "  ${PACKAGES[*]}" >&2
    exit 1
  fi
fi

missing=()
for p in "${PACKAGES[@]}"; do
  # dpkg-query's status is "install ok installed" only for a fully installed package.
  if [ "$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null)" != "install ok installed" ]; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps.sh: all ${#PACKAGES[@]} packages already installed"
else
  echo "install_deps.sh: installing ${#missing[@]} missing package(s): ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# Debian's default reference BLAS makes torch's CPU matmuls ~40x slower, and
# its default OpenBLAS (the pthread build) keeps a thread pool of its own that
# busy-waits against torch's OpenMP pool, so the engine could only give it one
# thread (one core for every float32 GEMM). The OpenMP build shares torch's
# pool: make it the active alternative, and ThreadConfig gives it torch's
# thread count (docs/performance.md, "Threads"). The pthread build stays
# installed for scripts/bench_vs_official.sh, which times both.
for alt in libblas.so.3-x86_64-linux-gnu liblapack.so.3-x86_64-linux-gnu libopenblas.so.0-x86_64-linux-gnu; do
  cand=$(update-alternatives --list "$alt" 2>/dev/null | grep -m1 openblas-openmp || true)
  if [ -n "$cand" ] && [ "$(readlink -f /etc/alternatives/$alt 2>/dev/null)" != "$(readlink -f "$cand")" ]; then
    $SUDO update-alternatives --set "$alt" "$cand" >/dev/null
  fi
done
