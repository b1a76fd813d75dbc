# Sourced by the scripts that build the libtorch-only part on a machine with
# a Python torch and nothing else (scripts/gpu_check.sh, scripts/train_gpu.sh):
# finds that torch, its libtorch and the header-only dependencies, and
# configures the build (-DLONG3R_WITH_ROS=OFF, OpenCV and PCL left out).
# The caller sets root (the repository), start (its start, date +%s) and
# jobs (build jobs), and calls report_open first.
# Sets for the caller: device, torch_dir, json_dir, eigen_dir, cmake_args.
# shellcheck shell=bash disable=SC2154,SC2034

# The option parser every script uses.
# shellcheck source=scripts/parse_args.sh
source "$(dirname "${BASH_SOURCE[0]}")/parse_args.sh"

# report_open PATH: starts the record that say MESSAGE (prints it and
# records it) adds to and finish CODE (records the wall time, copies the
# record to PATH, exits) ends.
report_open() {
  report_path=$1
  report=$(mktemp)
  trap 'rm -f "$report"' EXIT
}
say() { echo "$@" | tee -a "$report"; }
finish() {
  say ""
  say "wall time $(( $(date +%s) - start )) s"
  mkdir -p "$(dirname "$report_path")"
  cp "$report" "$report_path"
  echo "report: $report_path"
  exit "$1"
}

# torch_setup DRY TORCH_DIR DEPS_DIR: the Python torch ($PYTHON, default
# python3) and, unless DRY is 1, its CUDA GPU; its libtorch (or TORCH_DIR)
# and the header-only dependencies. Sets device (cuda, or cpu when DRY),
# torch_dir, json_dir and eigen_dir; says what it found; finish on failure.
torch_setup() {
  local py=${PYTHON:-python3}
  if ! torch_probe "$py"; then
    say "no usable Python torch ($py): $torch_info"
    finish 3
  fi
  say "$(torch_describe)"
  device=cuda
  if [ "$1" = 1 ]; then device=cpu; else torch_require_cuda; fi
  torch_find_dir "$2" "$1"
  header_deps_find "$3"
  say "nlohmann-json from $json_dir, Eigen from $eigen_dir"
}

# torch_probe PYTHON: sets torch_info ("key value" lines); non-zero when that
# interpreter has no usable torch.
torch_probe() {
  torch_info=$("$1" - <<'PY' 2>&1
import os, torch
print("torch", torch.__version__)
print("cuda_build", torch.version.cuda or "none")
print("cuda_available", torch.cuda.is_available())
print("gpu", torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none")
print("cxx11_abi", torch.compiled_with_cxx11_abi())
print("cmake_prefix", torch.utils.cmake_prefix_path)
print("include", os.path.join(os.path.dirname(torch.__file__), "include"))
PY
)
}
torch_field() { echo "$torch_info" | sed -n "s/^$1 //p"; }

# torch_describe: the one-line summary of the probed torch.
torch_describe() {
  echo "python torch $(torch_field torch), CUDA build $(torch_field cuda_build)," \
       "cuda available $(torch_field cuda_available), GPU $(torch_field gpu)," \
       "C++11 ABI $(torch_field cxx11_abi)"
}

# torch_require_cuda: finish 3, saying why, unless the probed torch has a usable GPU.
torch_require_cuda() {
  [ "$(torch_field cuda_available)" = True ] && return 0
  local why="torch.cuda.is_available() is False"
  [ "$(torch_field cuda_build)" = none ] && why="this torch is built without CUDA (torch.version.cuda is None)"
  command -v nvidia-smi >/dev/null 2>&1 || why="$why; no nvidia-smi (no NVIDIA driver)"
  say "NO CUDA GPU: $why. Nothing measured. (--cpu-dry-run exercises the steps on the CPU.)"
  finish 3
}

# torch_find_dir GIVEN DRY: sets torch_dir to GIVEN, or the probed torch's
# share/cmake/Torch; a dry run without one falls back to the system libtorch
# (torch_dir empty); otherwise finish 1.
torch_find_dir() {
  torch_dir=$1
  [ -n "$torch_dir" ] && return 0
  torch_dir="$(torch_field cmake_prefix)/Torch"
  [ -f "$torch_dir/TorchConfig.cmake" ] && return 0
  if [ "$2" = 1 ]; then
    say "this Python torch ships no CMake files ($torch_dir); dry run: the system libtorch instead"
    torch_dir=""
    return 0
  fi
  say "no TorchConfig.cmake in $torch_dir: give --torch-dir (a libtorch's share/cmake/Torch)"
  finish 1
}

# header_deps_find DEPS_DIR: sets json_dir (holds nlohmann/json.hpp) and
# eigen_dir (holds Eigen/Core), looking in DEPS_DIR (what header_deps_pack
# wrote), $LONG3R_NLOHMANN_JSON_DIR / $LONG3R_EIGEN_DIR, the system and the
# torch install; finish 1 naming what is missing.
header_deps_find() {
  json_dir=${LONG3R_NLOHMANN_JSON_DIR:-} eigen_dir=${LONG3R_EIGEN_DIR:-}
  local d
  for d in "$1" /usr/include /usr/local/include "$(torch_field include)"; do
    [ -z "$json_dir" ] && [ -f "$d/nlohmann/json.hpp" ] && json_dir=$d
  done
  for d in "$1/eigen3" /usr/include/eigen3 /usr/local/include/eigen3; do
    [ -z "$eigen_dir" ] && [ -f "$d/Eigen/Core" ] && eigen_dir=$d
  done
  if [ -z "$json_dir" ] || [ -z "$eigen_dir" ]; then
    say "header-only dependencies missing (nlohmann/json.hpp: ${json_dir:-not found}," \
        "Eigen/Core: ${eigen_dir:-not found}). On a machine that has them (Debian:" \
        "nlohmann-json3-dev, libeigen3-dev) run: bash scripts/train_gpu.sh --pack-deps, then" \
        "bring build/gpu-deps along (or set LONG3R_NLOHMANN_JSON_DIR / LONG3R_EIGEN_DIR)"
    finish 1
  fi
}

# header_deps_pack DEPS_DIR: copies this machine's nlohmann-json and Eigen
# headers into DEPS_DIR (about 5 MB), for a machine without them.
header_deps_pack() {
  local src_json="" src_eigen="" d
  for d in /usr/include /usr/local/include; do
    [ -z "$src_json" ] && [ -f "$d/nlohmann/json.hpp" ] && src_json=$d/nlohmann
    [ -z "$src_eigen" ] && [ -f "$d/eigen3/Eigen/Core" ] && src_eigen=$d/eigen3/Eigen
  done
  if [ -z "$src_json" ] || [ -z "$src_eigen" ]; then
    echo "--pack-deps: this machine lacks nlohmann/json.hpp or Eigen/Core" >&2
    return 1
  fi
  rm -rf "$1.partial" && mkdir -p "$1.partial/eigen3"
  cp -r "$src_json" "$1.partial/nlohmann"
  cp -r "$src_eigen" "$1.partial/eigen3/Eigen"
  rm -rf "$1" && mv "$1.partial" "$1"
  echo "packed $(du -sh "$1" | cut -f1) of headers into $1"
}

# torch_only_cmake_args BUILD_DIR TESTS: sets cmake_args for the libtorch-only
# configure (uses torch_dir, json_dir, eigen_dir). Eigen comes from eigen_dir
# even where CMake would find a system one, so that the build uses exactly
# what a machine without it is given.
torch_only_cmake_args() {
  cmake_args=(-S "$root" -B "$1" -DLONG3R_WITH_ROS=OFF -DLONG3R_BUILD_TESTS="$2"
              -DCMAKE_BUILD_TYPE=Release -DCMAKE_DISABLE_FIND_PACKAGE_OpenCV=ON
              -DCMAKE_DISABLE_FIND_PACKAGE_PCL=ON -DCMAKE_DISABLE_FIND_PACKAGE_Eigen3=ON
              -DLONG3R_EIGEN_DIR="$eigen_dir" -DLONG3R_NLOHMANN_JSON_DIR="$json_dir")
  if [ -n "$torch_dir" ]; then cmake_args+=(-DTorch_DIR="$torch_dir"); fi
}

# torch_only_build BUILD_DIR TESTS TARGET...: configures and builds; on
# failure says so with the logs' tails and finish 1.
torch_only_build() {
  local build=$1 tests=$2
  shift 2
  torch_only_cmake_args "$build" "$tests"
  mkdir -p "$build"
  if ! cmake "${cmake_args[@]}" >"$build/configure.log" 2>&1 ||
     ! cmake --build "$build" -j "$jobs" --target "$@" >"$build/build.log" 2>&1; then
    say "BUILD FAILED (logs: $build/configure.log, $build/build.log):"
    tail -20 "$build/build.log" "$build/configure.log" 2>/dev/null | tee -a "$report"
    finish 1
  fi
}
