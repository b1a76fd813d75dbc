#!/usr/bin/env bash
# The shipped model end to end (long3r_reconstruct: preprocessing, model,
# PnP-RANSAC, voxel map) in each precision, convolution precision, host
# allocator setting and PnP RANSAC (classic / usac), side by side in one run,
# alternating settings between rounds so that a shared machine's load falls
# on all of them alike.
#
#   scripts/bench_shipped.sh [--rounds N] [--threads N] [--frames N] [--model FILE]
#
# --model: another checkpoint in place of models/default.safetensors (run at
# the input size it records).
#
# Needs a build (scripts/build.sh). Prints the CPU (model, ISA, oneDNN's ISA)
# and one row per setting and round: mean / median FPS and the per-frame
# stage means from frames.csv. bfloat16 rows are left out where the CPU has
# no native bfloat16 (they would be emulated: slower than float32).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
rounds=2 threads=2 frames=100
model_path=""
# shellcheck source=/dev/null
source "$root/scripts/env.sh" >/dev/null
long3r_parse_args --rounds=rounds --threads=threads --frames=frames --model=model_path -- "$@"
model_path=$(realpath "${model_path:-$root/models/default.safetensors}")
bin="$root/build/.ws/devel/lib/long3r_ros"
[ -x "$bin/long3r_reconstruct" ] || { echo "build first: scripts/build.sh" >&2; exit 1; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$bin/long3r_synth" --out "$work/seq" --frames "$frames" --width 224 --height 224 \
  --seed 2000005 --quiet >/dev/null
"$bin/long3r_load_bench" "$model_path" --threads "$threads" | sed -n 1p

settings=("float32 auto reuse classic" "float32 auto return classic" "float32 auto reuse usac")
if grep -qE 'avx512_bf16|amx_bf16' /proc/cpuinfo; then
  settings+=("bfloat16 auto reuse classic" "bfloat16 float32 reuse classic"
             "bfloat16 auto return classic" "bfloat16 auto reuse usac")
fi
printf '%-10s %-6s %-7s %-8s %-5s %9s %11s %10s %9s %8s %9s\n' precision convs freed pnp round \
  "mean_FPS" "median_FPS" "model_ms" "pose_ms" "map_ms" "total_ms"
for round in $(seq 1 "$rounds"); do
  for s in "${settings[@]}"; do
    read -r precision convs freed pnp <<<"$s"
    args=(--model "$model_path" --out "$work/out" --threads "$threads"
          --precision "$precision" --conv-precision "$convs" --pnp-ransac "$pnp")
    [ "$freed" = return ] && args+=(--return-freed-memory)
    summary="$("$bin/long3r_reconstruct" "${args[@]}" "$work/seq" 2>&1 | grep -m1 'mean .* FPS')"
    mean="$(sed -E 's/.*mean ([0-9.]+) FPS.*/\1/' <<<"$summary")"
    median="$(sed -E 's/.*median ([0-9.]+) FPS.*/\1/' <<<"$summary")"
    # Stage means over the frames (frames.csv columns by name).
    stages="$(/usr/bin/python3 - "$work/out/frames.csv" <<'EOF'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
def mean(k):
    return sum(float(r[k]) for r in rows) / max(1, len(rows))
print("%.1f %.1f %.1f %.1f" % (mean("model_ms"), mean("pose_ms"), mean("map_ms"), mean("total_ms")))
EOF
)"
    read -r model pose map total <<<"$stages"
    printf '%-10s %-6s %-7s %-8s %-5s %9s %11s %10s %9s %8s %9s\n' "$precision" "$convs" \
      "$freed" "$pnp" "$round" "$mean" "$median" "$model" "$pose" "$map" "$total"
  done
done
