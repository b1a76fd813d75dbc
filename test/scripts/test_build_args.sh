#!/usr/bin/env bash
# scripts/build.sh's options reach CMake (catkin_make hands everything after
# --make-args to make, so they must come before it): --no-trainer and
# --no-tests leave out what they say, --no-unity turns the libraries' unity
# build off (on by default), LONG3R_TORCH_DIR chooses the libtorch, a new
# workspace is generated for Ninja where it is installed, and the targets go
# to make or ninja. Each case configures a workspace of its own
# under WORK_DIR and runs make's cheap `help` target; nothing is compiled.
#   test_build_args.sh WORK_DIR
set -uo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
work=$1
rm -rf "$work"
mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
cached() {  # the value of a CMake cache entry in workspace $1
  sed -n "s/^$2:[A-Z]*=//p" "$1/build/CMakeCache.txt"
}
has_target() {  # the `help` output in log $1 lists target $2 (make's or ninja's)
  grep -q -e "^\.\.\. $2\$" -e "^$2: phony\$" "$1"
}
unity_source() {  # the first unity batch CMake generated for long3r_io in workspace $1
  echo "$1/build/long3r_ros/CMakeFiles/long3r_io.dir/Unity/unity_0_cxx.cxx"
}

# A libtorch of the user's own, as LONG3R_TORCH_DIR names it: a folder whose
# TorchConfig.cmake hands over to Debian's (Debian's).
debian_torch=""
for d in /usr/lib/*/cmake/Torch /usr/share/cmake/Torch /usr/lib/cmake/Torch; do
  [ -f "$d/TorchConfig.cmake" ] && debian_torch=$d && break
done
[ -n "$debian_torch" ] || { echo "no TorchConfig.cmake under /usr: nothing to check"; exit 1; }
mkdir -p "$work/torch"
echo "include(\"$debian_torch/TorchConfig.cmake\")" >"$work/torch/TorchConfig.cmake"

ws=$work/no_trainer
LONG3R_WS=$ws LONG3R_TORCH_DIR=$work/torch bash "$root/scripts/build.sh" --no-trainer --no-unity help \
  >"$work/no_trainer.log" 2>&1 || fail "build.sh --no-trainer help failed: $work/no_trainer.log"
[ "$(cached "$ws" LONG3R_BUILD_TRAINER)" = OFF ] || fail "--no-trainer: LONG3R_BUILD_TRAINER is '$(cached "$ws" LONG3R_BUILD_TRAINER)'"
[ "$(cached "$ws" LONG3R_BUILD_TESTS)" = OFF ] || fail "--no-trainer: LONG3R_BUILD_TESTS is '$(cached "$ws" LONG3R_BUILD_TESTS)'"
[ "$(cached "$ws" CATKIN_ENABLE_TESTING)" = OFF ] || fail "--no-trainer: CATKIN_ENABLE_TESTING is '$(cached "$ws" CATKIN_ENABLE_TESTING)'"
[ "$(cached "$ws" Torch_DIR)" = "$work/torch" ] || fail "LONG3R_TORCH_DIR: Torch_DIR is '$(cached "$ws" Torch_DIR)'"
[ "$(cached "$ws" LONG3R_UNITY_BUILD)" = OFF ] || fail "--no-unity: LONG3R_UNITY_BUILD is '$(cached "$ws" LONG3R_UNITY_BUILD)'"
[ ! -e "$(unity_source "$ws")" ] || fail "--no-unity: a unity source was generated"
if command -v ninja >/dev/null; then
  [ "$(cached "$ws" CMAKE_GENERATOR)" = Ninja ] || fail "ninja is installed, the generator is '$(cached "$ws" CMAKE_GENERATOR)'"
fi
grep -q "Running command: \"\(make\|ninja\) -j[0-9]* help\"" "$work/no_trainer.log" ||
  fail "make was not given the target alone: $(grep 'Running command: "\(make\|ninja\)' "$work/no_trainer.log")"
has_target "$work/no_trainer.log" long3r_demo || fail "--no-trainer: no long3r_demo target"
! has_target "$work/no_trainer.log" app_long3r_train || fail "--no-trainer: the trainer is built"

ws=$work/no_tests
LONG3R_WS=$ws bash "$root/scripts/build.sh" --no-tests help >"$work/no_tests.log" 2>&1 ||
  fail "build.sh --no-tests help failed: $work/no_tests.log"
[ "$(cached "$ws" LONG3R_BUILD_TRAINER)" = ON ] || fail "--no-tests: LONG3R_BUILD_TRAINER is '$(cached "$ws" LONG3R_BUILD_TRAINER)'"
[ "$(cached "$ws" LONG3R_BUILD_TESTS)" = OFF ] || fail "--no-tests: LONG3R_BUILD_TESTS is '$(cached "$ws" LONG3R_BUILD_TESTS)'"
[ "$(cached "$ws" LONG3R_UNITY_BUILD)" = ON ] || fail "default: LONG3R_UNITY_BUILD is '$(cached "$ws" LONG3R_UNITY_BUILD)'"
[ -f "$(unity_source "$ws")" ] || fail "default: no unity source for long3r_io"
has_target "$work/no_tests.log" app_long3r_train || fail "--no-tests: no trainer target"
! has_target "$work/no_tests.log" long3r_model_tests || fail "--no-tests: the tests are built"

if [ "$failures" -eq 0 ]; then
  echo "build.sh: --no-trainer, --no-tests, --no-unity, LONG3R_TORCH_DIR and the targets reach CMake and make"
  rm -rf "$work"
fi
exit $((failures > 0))
