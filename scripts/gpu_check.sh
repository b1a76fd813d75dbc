#!/usr/bin/env bash
# One command for a machine with an NVIDIA GPU and a Python torch built with
# CUDA (no ROS, no OpenCV C++, no apt needed):
#   bash scripts/gpu_check.sh [--out REPORT] [--frames N] [--torch-dir DIR]
#                             [--build-dir DIR] [--jobs N] [--cpu-dry-run]
# 1. builds the torch-only part (-DLONG3R_WITH_ROS=OFF, OpenCV/PCL left out)
#    against that torch's libtorch (python3 -c 'import torch;
#    print(torch.utils.cmake_prefix_path)'; --torch-dir overrides);
# 2. runs every golden case of test/data/golden on CUDA in float32 with TF32
#    off (long3r_golden: PASS at the 1e-4 relative tolerance, deviation
#    printed), and in bfloat16 and float16 (deviation printed, not judged);
# 3. runs the CUDA unit tests (ctest -R Cuda, where googletest is installed);
# 4. times the paper-size LONG3R (long3r_bench --config long3r_paper, random
#    weights, 224 x 224, N frames) in float32, bfloat16 and float16;
# and writes everything to one report (default build-gpu-check/report.txt).
# Meant to finish within 8 minutes on a machine with a recent GPU and 8+ cores.
#
# Without a usable CUDA GPU it says why and exits 3. --cpu-dry-run runs the
# same steps on the CPU with tiny sizes instead (long3r_tiny at 64 x 64,
# bfloat16 emulated where the CPU lacks it; float16 is refused on the CPU and
# reported so), to check the script and the build where no GPU is at hand;
# with a Python torch that ships no CMake files (Debian's python3-torch) it
# falls back to the system libtorch.
# PYTHON selects the interpreter (default python3); the header-only
# dependencies (nlohmann-json, Eigen) are looked for as scripts/torch_only.sh
# says, build/gpu-deps (scripts/train_gpu.sh --pack-deps) first.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
# shellcheck source=scripts/torch_only.sh
source "$root/scripts/torch_only.sh"
start=$(date +%s)

out="" frames=20 torch_dir="" build="$root/build-gpu-check" jobs=$(nproc) dry=0
long3r_parse_args --out=out --frames=frames --torch-dir=torch_dir --build-dir=build \
  --jobs=jobs --cpu-dry-run?dry -- "$@"
mkdir -p "$build"
out=${out:-$build/report.txt}
report_open "$out"

say "== long3r gpu_check $(git -C "$root" rev-parse --short HEAD 2>/dev/null || echo '?') $(date -u +%Y-%m-%dT%H:%M:%SZ)"
[ "$dry" = 1 ] && say "MODE: --cpu-dry-run (CPU, tiny sizes: checks the script and the build, measures nothing about a GPU)"

# ---- torch and the GPU -------------------------------------------------------
torch_setup "$dry" "$torch_dir" "$root/build/gpu-deps"

# ---- build ----------------------------------------------------------------
tests=OFF
if [ "$(torch_field cxx11_abi)" = True ] && { [ -f /usr/include/gtest/gtest.h ] || [ -f /usr/local/include/gtest/gtest.h ]; }; then
  tests=ON
fi
say "== build ($build, tests $tests, libtorch ${torch_dir:-system})"
targets=(app_long3r_golden app_long3r_bench)
[ "$tests" = ON ] && targets+=(long3r_model_tests)
torch_only_build "$build" "$tests" "${targets[@]}"
say "built in $(( $(date +%s) - start )) s"
bin="$build"  # plain CMake puts the executables at the top of the build folder

# ---- golden cases -----------------------------------------------------------
say ""
say "== golden cases on $device (TF32 off), max relative deviation of the outputs vs the official float32 run"
status=0
for case_dir in "$root"/test/data/golden/*/; do
  [ -f "$case_dir/io.safetensors" ] || continue
  name=$(basename "$case_dir")
  for prec in float32 bfloat16 float16; do
    extra=(--device "$device")
    if [ "$prec" != float32 ]; then
      extra+=(--precision "$prec" --tol 1)  # printed, not judged
      [ "$device" = cpu ] && extra+=(--allow-emulated-precision)
    fi
    line=$(OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} "$bin/long3r_golden" "${extra[@]}" "$case_dir" 2>&1 | tail -1) || true
    case "$line" in
      *PASS*) r=$(echo "$line" | sed -n 's/.*max relative difference \([^,]*\),.*/\1/p') ;;
      *) r="FAILED: $line"; [ "$prec" = float32 ] && status=1 ;;
    esac
    say "$(printf '  %-26s %-9s %s' "$name" "$prec" "$r")"
  done
done

# ---- unit tests ---------------------------------------------------------------
if [ "$tests" = ON ]; then
  say ""
  say "== unit tests on the device (ctest -R Cuda)"
  (cd "$build" && ctest -R 'Cuda\.' --output-on-failure) >"$build/ctest.log" 2>&1 || status=1
  grep -E "tests passed|Skipped|Failed|\*\*\*" "$build/ctest.log" | tee -a "$report" || true
  grep -E "max relative deviation" "$build/ctest.log" | tee -a "$report" || true
fi

# ---- speed ------------------------------------------------------------------
config=long3r_paper size=224
[ "$dry" = 1 ] && config=long3r_tiny size=64
say ""
say "== long3r_bench --config $config --size $size --frames $frames --device $device"
for prec in float32 bfloat16 float16; do
  extra=(--precision "$prec")
  [ "$device" = cpu ] && [ "$prec" = bfloat16 ] && extra+=(--allow-emulated-precision)
  if log=$("$bin/long3r_bench" --config "$config" --size "$size" --frames "$frames" \
             --device "$device" "${extra[@]}" 2>&1); then
    mean=$(echo "$log" | sed -n 's/^frames .*mean latency \(.*\) ms (\(.*\) FPS).*/\1 ms (\2 FPS)/p')
    rss=$(echo "$log" | sed -n 's/^peak RSS //p')
    say "$(printf '  %-9s mean latency %s, peak RSS %s' "$prec" "$mean" "$rss")"
  else
    say "$(printf '  %-9s not run: %s' "$prec" "$(echo "$log" | tail -1)")"
  fi
done
finish "$status"
