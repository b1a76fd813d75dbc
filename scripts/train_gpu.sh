#!/usr/bin/env bash
# Trains LONG3R on a machine with an NVIDIA GPU and a Python torch built with
# CUDA (no ROS, no OpenCV, no PCL, no apt needed), in one command:
#   bash scripts/train_gpu.sh [--out DIR] [--config FILE] [--model-config NAME]
#                             [--minutes M] [--render-threads N] [--torch-dir DIR]
#                             [--build-dir DIR] [--deps-dir DIR] [--jobs N]
#                             [--max-steps N] [--cpu-dry-run]
#   bash scripts/train_gpu.sh --pack-deps [--deps-dir DIR]
# 1. builds long3r_train without OpenCV or PCL (the generator's core renders
#    scenes into tensors) against that torch's libtorch (--torch-dir
#    overrides), with the header-only nlohmann-json and Eigen from --deps-dir
#    (default build/gpu-deps, what --pack-deps writes on a machine that has
#    them) or the system;
# 2. trains --config (default config/train_gpu.json: long3r_small, 224 x 224)
#    on CUDA for at most --minutes of training (default 9; the run validates
#    and writes its outputs when the next step would pass it), rendering the
#    training scenes on --render-threads CPU cores (default: all but two) on a
#    data thread that keeps two batches ready while the GPU computes;
# 3. writes everything to bring back under --out (default
#    build-train-gpu/run): model.safetensors, train_log.csv, validation.json
#    (loss, shape error left after registration, pointmap error; the
#    point-cloud and pose metrics need the OpenCV side: run
#    long3r_model_eval on the model back home), checkpoint/ (resumable with
#    long3r_train --resume), train_config.json, train.log and report.txt.
# Without a usable CUDA GPU it says why and exits 3. --cpu-dry-run runs the
# same steps on the CPU with the long3r_tiny model and 2 steps (unless
# --max-steps), to check the script and the build where no GPU is at hand.
# PYTHON selects the interpreter (default python3).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
# shellcheck source=scripts/torch_only.sh
source "$root/scripts/torch_only.sh"
start=$(date +%s)

out="" config="$root/config/train_gpu.json" model="" minutes=9 render_threads=""
torch_dir="" build="$root/build-train-gpu" deps="$root/build/gpu-deps" jobs=$(nproc)
max_steps="" dry=0 pack=0
long3r_parse_args --out=out --config=config --model-config=model --minutes=minutes \
  --render-threads=render_threads --torch-dir=torch_dir --build-dir=build --deps-dir=deps \
  --jobs=jobs --max-steps=max_steps --cpu-dry-run?dry --pack-deps?pack -- "$@"
if [ "$pack" = 1 ]; then
  header_deps_pack "$deps"
  exit $?
fi
out=${out:-$build/run}
mkdir -p "$build"
report_open "$out/report.txt"

say "== long3r train_gpu $(git -C "$root" rev-parse --short HEAD 2>/dev/null || echo '?') $(date -u +%Y-%m-%dT%H:%M:%SZ)"
[ "$dry" = 1 ] && say "MODE: --cpu-dry-run (CPU, long3r_tiny, a few steps: checks the script and the build, measures nothing about a GPU)"

# ---- torch and the GPU -------------------------------------------------------
torch_setup "$dry" "$torch_dir" "$deps"

# ---- build ------------------------------------------------------------------
say "== build ($build, libtorch ${torch_dir:-system}, no OpenCV / PCL)"
torch_only_build "$build" OFF app_long3r_train
# What it links itself (its NEEDED entries; a libtorch may bring more, as
# Debian's does): libtorch and the C++ runtime, never OpenCV, PCL or ROS.
if command -v readelf >/dev/null 2>&1; then
  needed=$(readelf -d "$build/long3r_train" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p' | tr '\n' ' ')
  say "long3r_train needs: $needed"
  if echo "$needed" | grep -Eq "opencv|pcl|ros"; then
    say "BUILD CHECK FAILED: long3r_train links OpenCV, PCL or ROS"
    finish 1
  fi
fi
say "built in $(( $(date +%s) - start )) s"

# ---- train ------------------------------------------------------------------
cores=$(nproc)
threads=2  # the GPU computes; two cores feed it and run the optimiser
[ "$dry" = 1 ] && threads=$cores  # the CPU trains too here: the renderer shares the cores
render_threads=${render_threads:-$(( cores > 3 ? cores - 2 : 1 ))}
args=(--config "$config" --out "$out" --device "$device" --threads "$threads"
      --render-threads "$render_threads" --prefetch 2
      --time-budget-s "$(( minutes * 60 ))")
if [ "$dry" = 1 ]; then
  model=${model:-long3r_tiny}
  args+=(--max-steps "${max_steps:-2}")
elif [ -n "$max_steps" ]; then
  args+=(--max-steps "$max_steps")
fi
[ -n "$model" ] && args+=(--model-config "$model")
say ""
say "== long3r_train ${args[*]}"
mkdir -p "$out"
train_start=$(date +%s)
if ! OMP_NUM_THREADS=$threads "$build/long3r_train" "${args[@]}" >"$out/train.log" 2>&1; then
  say "TRAINING FAILED (log: $out/train.log):"
  tail -20 "$out/train.log" | tee -a "$report"
  finish 1
fi
train_s=$(( $(date +%s) - train_start ))
say "$(tail -1 "$out/train.log")"
steps=$(( $(wc -l < "$out/train_log.csv") - 1 ))
say "long3r_train ran $steps steps in $train_s s (its validations and outputs included)"
say "mean step $("$py" - "$out/train_log.csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
step = [float(r["step_s"]) for r in rows[1:]] or [float(rows[0]["step_s"])]
data = [float(r["data_s"]) for r in rows[1:]] or [float(rows[0]["data_s"])]
print("%.3f s, of which waiting for data %.3f s" % (sum(step) / len(step), sum(data) / len(data)))
PY
)"
say ""
say "== validation (validation.json; NaN/null: figures that need the OpenCV side)"
sed 's/^/  /' "$out/validation.json" | tee -a "$report"
finish 0
