#!/usr/bin/env bash
# Speed of the official Spann3R Python code and of this package's engine on
# the same ViT-L model, the same frames and the same thread count, side by
# side in one run:
#   bash scripts/bench_vs_official.sh OFFICIAL_CHECKOUT [--frames N] [--threads T]
#        [--precisions "float32 bfloat16"] [--allow-emulated] [--keep]
#        [--ours-openblas openmp|pthread]
# OFFICIAL_CHECKOUT: a checkout of https://github.com/HengyiWang/spann3r (with
# its dust3r/ and croco/ folders) that you provide; nothing of it is copied
# into this repository. Steps:
#  1. the official code builds its ViT-L Spann3R with random weights and saves
#     it in the official .pth layout (scripts/bench_official_spann3r.py make;
#     Python modules Debian lacks are shimmed there, see its header);
#  2. scripts/convert_checkpoint.py converts that .pth to safetensors;
#  3. N generated 224 x 224 frames (PNG) go through Spann3R.forward of the
#     official code and through long3r_reconstruct, alternately per precision;
#  4. prints the median step time of each (the first step, which also encodes
#     frame 0, is left out), their ratio (ours / official in the same
#     precision), ours against the official's best float32 (the reference the
#     issue's targets use when float32 is among the precisions run) and the
#     peak RSS;
#  5. runs the paper-size LONG3R (long3r_bench --config long3r_paper, random
#     weights, 5 frames) in each precision and prints its median step against
#     our ViT-L Spann3R step.
# The official side runs with each OpenBLAS build installed (Debian's
# libopenblas0-openmp and libopenblas0-pthread, chosen per process through
# LD_LIBRARY_PATH; the pthread build at 1 and at T OpenBLAS threads, the
# OpenMP build at T), and the fastest is its figure ("its best setting"); ours
# runs with the project's defaults (the system's BLAS as scripts/install_deps.sh
# selects it, ThreadConfig's OpenBLAS threads); --ours-openblas picks an
# OpenBLAS build for it the same way (e.g. to measure a machine whose system
# choice is not the default one).
# bfloat16 is timed only on a CPU with native bfloat16 (AVX512-BF16 or
# AMX-BF16): elsewhere both sides would run emulated kernels, and the row says
# "not measurable (emulated)" unless --allow-emulated is given.
# Work folder (about 8 GB for the model files): $LONG3R_BENCH_OFFICIAL_DIR,
# default /tmp/long3r_bench_official; --keep keeps the model files for a rerun.
# Needs: a built package (bash scripts/build.sh), /usr/bin/python3 with torch,
# numpy and PIL (scripts/install_deps.sh installs them).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

official=""
frames=6
threads=$(nproc)
precisions="float32 bfloat16"
allow_emulated=0
keep=0
ours_blas=""
ours_openblas=""
long3r_parse_args @official --frames=frames --threads=threads --precisions=precisions \
  --allow-emulated?allow_emulated --keep?keep --ours-openblas=ours_openblas -- "$@"
[ -n "$official" ] || { echo "bench_vs_official.sh: the official checkout is missing (see --help)" >&2; exit 2; }
official=$(cd "$official" && pwd)
if [ -n "$ours_openblas" ]; then
  ours_blas=/usr/lib/x86_64-linux-gnu/openblas-$ours_openblas
  [ -e "$ours_blas/libopenblas.so.0" ] || { echo "no $ours_blas/libopenblas.so.0" >&2; exit 2; }
fi
[ "$frames" -ge 3 ] || { echo "--frames must be >= 3" >&2; exit 2; }

bin=${LONG3R_BIN:-$LONG3R_WS/devel/lib/long3r_ros}
[ -x "$bin/long3r_reconstruct" ] || {
  echo "no $bin/long3r_reconstruct: build the package first (bash scripts/build.sh)" >&2; exit 1; }
py=/usr/bin/python3
work=${LONG3R_BENCH_OFFICIAL_DIR:-${TMPDIR:-/tmp}/long3r_bench_official}
mkdir -p "$work"
[ "$keep" = 1 ] || trap 'rm -f "$work/spann3r_vitl.pth" "$work/spann3r_vitl.safetensors"' EXIT

native_bf16=0
grep -qE '(^| )(avx512_bf16|amx_bf16)( |$)' /proc/cpuinfo && native_bf16=1

# 1-2. Official model with random weights, converted.
if [ ! -s "$work/spann3r_vitl.safetensors" ]; then
  echo "== building the official ViT-L Spann3R (random weights) and converting it"
  "$py" "$LONG3R_ROOT/scripts/bench_official_spann3r.py" make "$official" "$work/spann3r_vitl.pth"
  "$py" "$LONG3R_ROOT/scripts/convert_checkpoint.py" --kind spann3r \
    "$work/spann3r_vitl.pth" "$work/spann3r_vitl.safetensors"
fi

# 3. Frames: smooth shifted patterns, as a slowly moving camera would see.
rm -rf "$work/frames" && mkdir -p "$work/frames"
"$py" - "$work/frames" "$frames" <<'EOF'
import sys, numpy as np
from PIL import Image
out, n = sys.argv[1], int(sys.argv[2])
y, x = np.mgrid[0:224, 0:224] / 224.0
for t in range(n):
    s = 0.03 * t
    rgb = np.stack([0.5 + 0.4 * np.sin(6.0 * (x + s) + 2.0 * y),
                    0.5 + 0.4 * np.cos(5.0 * (y - s) + 1.5 * x),
                    0.5 + 0.4 * np.sin(4.0 * (x + y) + 3.0 * s)], axis=-1)
    Image.fromarray((rgb * 255).astype(np.uint8)).save("%s/%04d.png" % (out, t))
EOF

# OpenBLAS builds installed beside the system's choice.
blas_dirs=()
for v in openmp pthread; do
  d=/usr/lib/x86_64-linux-gnu/openblas-$v
  [ -e "$d/libopenblas.so.0" ] && blas_dirs+=("$d")
done
[ ${#blas_dirs[@]} -gt 0 ] || blas_dirs=("")

median() {  # numbers... -> median
  printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {if (NR % 2) print a[(NR+1)/2]; else print (a[NR/2]+a[NR/2+1])/2}'
}
peak_kb() { awk '{print $1}' "$1"; }

results=()
paper_rows=()
best_f32=""
for prec in $precisions; do
  if [ "$prec" = bfloat16 ] && [ "$native_bf16" = 0 ] && [ "$allow_emulated" = 0 ]; then
    results+=("$prec|not measurable: this CPU has no native bfloat16 (AVX512-BF16 / AMX), both sides would run emulated kernels|||||")
    continue
  fi
  # Official, with each OpenBLAS build, at 1 and at T OpenBLAS threads.
  best_off="" best_blas="" best_rss=""
  for d in "${blas_dirs[@]}"; do
    # The OpenMP build shares torch's pool: only at T threads (at 1 it is the
    # pthread build's single-threaded case again).
    counts=$(printf '%s\n' "$threads" 1 | sort -un)
    [[ "$d" == *openmp* ]] && counts=$threads
    for bt in $counts; do
      tag=${d##*/}; tag="${tag:-system} x$bt"
      echo "== official $prec, $threads torch threads, OpenBLAS $tag"
      LD_LIBRARY_PATH=${d}${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH} OMP_NUM_THREADS=$threads \
        OPENBLAS_NUM_THREADS=$bt /usr/bin/time -f "%M" -o "$work/rss_off.txt" \
        "$py" "$LONG3R_ROOT/scripts/bench_official_spann3r.py" time "$official" \
        "$work/spann3r_vitl.pth" "$work/frames" --threads "$threads" --precision "$prec" \
        --out "$work/official.json"
      mapfile -t steps < <("$py" -c 'import json,sys; print("\n".join(str(s) for s in json.load(open(sys.argv[1]))["steps_s"][1:]))' "$work/official.json")
      m=$(median "${steps[@]}")
      echo "   median step $m s"
      if [ -z "$best_off" ] || [ "$(echo "$m < $best_off" | bc -l)" = 1 ]; then
        best_off=$m best_blas=$tag best_rss=$(peak_kb "$work/rss_off.txt")
      fi
    done
  done
  # Ours at the project's defaults.
  ours_tag=${ours_blas##*/}
  echo "== long3r_reconstruct $prec, $threads threads, OpenBLAS ${ours_tag:-system}"
  extra=()
  [ "$prec" = float32 ] || extra=(--precision "$prec")
  [ "$allow_emulated" = 1 ] && [ "$prec" = bfloat16 ] && extra+=(--allow-emulated-precision)
  ours_env=()
  [ -n "$ours_blas" ] && ours_env=(env "LD_LIBRARY_PATH=$ours_blas${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}")
  "${ours_env[@]}" /usr/bin/time -f "%M" -o "$work/rss_ours.txt" "$bin/long3r_reconstruct" \
    --model "$work/spann3r_vitl.safetensors" --out "$work/ours_$prec" --threads "$threads" \
    --conf-threshold 1 "${extra[@]}" "$work/frames" >/dev/null
  # frames.csv: frame k comes from the step that ran the pair (k, k+1); the
  # last row is the flush (no step). Leave out step 0 and the flush.
  mapfile -t ours < <(awk -F, -v n="$frames" 'NR > 2 && $1 < n - 1 {print $4 / 1000}' "$work/ours_$prec/frames.csv")
  mo=$(median "${ours[@]}")
  echo "   median step $mo s"
  ratio=$(echo "$mo / $best_off" | bc -l)
  [ "$prec" = float32 ] && best_f32=$best_off
  ratio_f32="-"
  [ -n "$best_f32" ] && ratio_f32=$(printf '%.2f' "$(echo "$mo / $best_f32" | bc -l)")
  # 5. The paper-size LONG3R, same precision (frames 2-5; frame 1 has no memory yet).
  echo "== long3r_bench --config long3r_paper $prec"
  "$bin/long3r_bench" --config long3r_paper --frames 5 --threads "$threads" --precision "$prec" \
    "${extra[@]:2}" > "$work/paper_$prec.txt"
  mapfile -t paper < <(awk '$1 ~ /^[2-5]$/ && NF == 11 {print $2 / 1000}' "$work/paper_$prec.txt")
  mp=$(median "${paper[@]}")
  echo "   median step $mp s"
  paper_rows+=("$prec|$(printf '%.2f' "$mp") s|$(printf '%.2f' "$mo") s|$(printf '%.2f' "$(echo "$mp / $mo" | bc -l)")|$(awk '/^peak RSS/ {print $3}' "$work/paper_$prec.txt") MiB")
  results+=("$prec|$(printf '%.2f' "$best_off") s (OpenBLAS $best_blas)|$(printf '%.2f' "$mo") s (OpenBLAS ${ours_tag:-system})|$(printf '%.2f' "$ratio")|$ratio_f32|$((best_rss / 1024)) / $(($(peak_kb "$work/rss_ours.txt") / 1024)) MiB")
done

echo
echo "Spann3R ViT-L 224x224, $frames frames ($((frames - 2)) steps timed), $threads threads, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')"
printf '%-9s | %-28s | %-28s | %-14s | %-18s | %s\n' precision "official median step" "ours median step" "ratio ours/off" "ours/off float32" "peak RSS off / ours"
for r in "${results[@]}"; do
  IFS='|' read -r p o u ra rf rss <<<"$r"
  printf '%-9s | %-28s | %-28s | %-14s | %-18s | %s\n' "$p" "$o" "$u" "$ra" "$rf" "$rss"
done
echo
echo "paper-size LONG3R (long3r_bench --config long3r_paper, random weights) against our ViT-L Spann3R step"
printf '%-9s | %-18s | %-18s | %-14s | %s\n' precision "LONG3R paper step" "Spann3R ViT-L step" "ratio" "LONG3R peak RSS"
for r in "${paper_rows[@]}"; do
  IFS='|' read -r p lp sp ra rss <<<"$r"
  printf '%-9s | %-18s | %-18s | %-14s | %s\n' "$p" "$lp" "$sp" "$ra" "$rss"
done
