#!/usr/bin/env bash
# Side-by-side speed of the map scoring (ICP alignment, accuracy, completion,
# normal consistency: every nearest-neighbour search of `long3r_eval
# --est-map`) at two revisions of this repository, on the same generated
# clouds, in one run. Also checks that both print the same metrics.
#   bash scripts/bench_scoring.sh [--baseline REV] [--points N] [--repeats R] [--callgrind]
# --baseline: the revision to compare with (default f65af4e, the last one
# with the hand-written k-d tree); the working tree is the other side.
# --callgrind: instead of timing, count the instructions each side executes
# (valgrind --tool=callgrind, one run per side and case: the same count on a
# busy machine as on an idle one; about 50x slower than a plain run, so use
# it with --points 50000 or so).
# Work folder: $LONG3R_BENCH_SCORING_DIR, default /tmp/long3r_bench_scoring.
# Runs alternate (baseline, current, baseline, ...) so both meet the same
# load; the best and median wall and CPU times of each side are printed.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

baseline=f65af4e
points=200000
repeats=5
callgrind=0
long3r_parse_args --baseline=baseline --points=points --repeats=repeats --callgrind?callgrind -- "$@"

# Outside the package: a checkout of another revision inside it would give
# roslaunch two files of each launch name.
work=${LONG3R_BENCH_SCORING_DIR:-${TMPDIR:-/tmp}/long3r_bench_scoring}
mkdir -p "$work"
src_base="$work/src_baseline"
if [ ! -d "$src_base" ] || [ "$(git -C "$src_base" rev-parse HEAD)" != "$(git -C "$LONG3R_ROOT" rev-parse "$baseline^{commit}")" ]; then
  rm -rf "$src_base"
  git -C "$LONG3R_ROOT" worktree prune
  git -C "$LONG3R_ROOT" worktree add --detach "$src_base" "$baseline" >/dev/null
fi
build_tool() {  # source_dir build_dir
  cmake -S "$1" -B "$2" -DLONG3R_WITH_ROS=OFF -DLONG3R_BUILD_TESTS=OFF \
    -DCMAKE_BUILD_TYPE=Release "${LONG3R_CMAKE_PY_ARGS[@]}" >/dev/null
  cmake --build "$2" -j "$LONG3R_JOBS" --target app_long3r_eval >/dev/null
}
echo "building long3r_eval at $baseline and at the working tree"
build_tool "$src_base" "$work/build_baseline"
build_tool "$LONG3R_ROOT" "$work/build_current"

# Three cases: a room's surfaces sampled twice (pred = GT + noise, a small
# rigid offset ICP removes); a compact prediction inside a larger GT (most
# completion queries far from the prediction); duplicated points (coincident
# samples, as a voxel map's centres give).
/usr/bin/python3 - "$work" "$points" <<'EOF'
import sys, numpy as np
work, n = sys.argv[1], int(sys.argv[2])
rng = np.random.default_rng(7)
def room(m):
    # Floor, ceiling and four walls of a 6 x 4 x 3 m room, uniform per area.
    size = np.array([6.0, 4.0, 3.0])
    faces = [(a, s) for a in range(3) for s in (0.0, 1.0)]
    area = np.array([np.prod(np.delete(size, a)) for a, _ in faces])
    idx = rng.choice(len(faces), m, p=area / area.sum())
    p = rng.random((m, 3)) * size
    for f, (a, s) in enumerate(faces):
        p[idx == f, a] = s * size[a]
    return p
def save(name, p):
    p = p.astype('<f4')
    with open(f"{work}/{name}.ply", "wb") as f:
        f.write(f"ply\nformat binary_little_endian 1.0\nelement vertex {len(p)}\n"
                "property float x\nproperty float y\nproperty float z\nend_header\n".encode())
        f.write(p.tobytes())
gt = room(n)
save("gt", gt)
c, s = np.cos(0.02), np.sin(0.02)
R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
save("pred_room", room(n) @ R.T + [0.03, -0.02, 0.01] + rng.normal(0, 0.01, (n, 3)))
compact = room(n)
save("pred_compact", compact[compact[:, 0] < 1.0] + rng.normal(0, 0.01, (np.sum(compact[:, 0] < 1.0), 3)))
dup = np.round(room(n // 4) / 0.02) * 0.02
save("pred_duplicates", np.repeat(dup, 4, axis=0))
EOF

run() {  # side case -> prints "wall_s cpu_s" (cpu: user + system of the process)
  local out="$work/out_${1}_$2"
  /usr/bin/time -f "%e %U %S" -o "$work/time.txt" \
    "$work/build_$1/long3r_eval" --gt-cloud "$work/gt.ply" --est-map "$work/pred_$2.ply" \
    --map-align none --out "$out" >/dev/null
  awk '{printf "%.3f %.3f", $1, $2 + $3}' "$work/time.txt"
}
stats() {  # seconds... -> "best median"
  printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {printf "%.2f %.2f", a[1], a[int((NR+1)/2)]}'
}

compare_metrics() {  # case -> "identical" or "DIFFER in ..."
  /usr/bin/python3 - "$work/out_baseline_$1/metrics.json" "$work/out_current_$1/metrics.json" <<'EOF'
import json, sys
a, b = (json.load(open(p))["reconstruction"] for p in sys.argv[1:])
a.pop("prediction"); b.pop("prediction")
if a == b:
    print("identical")
else:
    diff = [k for k in a if a[k] != b.get(k)]
    print("DIFFER in " + ", ".join(diff))
EOF
}

if [ "$callgrind" = 1 ]; then
  count() {  # side case -> instructions executed (callgrind's Ir)
    valgrind --tool=callgrind --callgrind-out-file=/dev/null \
      "$work/build_$1/long3r_eval" --gt-cloud "$work/gt.ply" --est-map "$work/pred_$2.ply" \
      --map-align none --out "$work/out_${1}_$2" 2>&1 >/dev/null |
      sed -n 's/.*refs: *//p' | tr -d ,
  }
  printf '%-11s %7s | %16s %16s %6s | %s\n' case points "baseline Ir" "current Ir" ratio metrics
  for case in room compact duplicates; do
    ib=$(count baseline "$case")
    ic=$(count current "$case")
    n=$(head -c 200 "$work/pred_$case.ply" | sed -n 's/^element vertex //p')
    printf '%-11s %7s | %16s %16s %6.3f | %s\n' "$case" "$n" "$ib" "$ic" \
      "$(echo "$ic / $ib" | bc -l)" "$(compare_metrics "$case")"
  done
  echo "Ir: instructions executed by the whole long3r_eval run (valgrind callgrind);"
  echo "ratio: current / baseline"
  exit 0
fi

# The wall time swings with other load on a shared machine; the CPU time is
# the work done, and the ratio to trust there.
printf '%-11s %7s | %-23s %-23s %5s | %-23s %-23s %5s | %s\n' case points \
  "baseline wall best/med" "current wall best/med" ratio "baseline cpu best/med" \
  "current cpu best/med" ratio metrics
for case in room compact duplicates; do
  wb=() wc=() cb=() cc=()
  for ((i = 0; i < repeats; ++i)); do
    read -r w c <<<"$(run baseline "$case")"; wb+=("$w"); cb+=("$c")
    read -r w c <<<"$(run current "$case")"; wc+=("$w"); cc+=("$c")
  done
  read -r wbb wbm <<<"$(stats "${wb[@]}")"
  read -r wcb wcm <<<"$(stats "${wc[@]}")"
  read -r cbb cbm <<<"$(stats "${cb[@]}")"
  read -r ccb ccm <<<"$(stats "${cc[@]}")"
  same=$(compare_metrics "$case")
  n=$(head -c 200 "$work/pred_$case.ply" | sed -n 's/^element vertex //p')
  printf '%-11s %7s | %-23s %-23s %5.2f | %-23s %-23s %5.2f | %s\n' "$case" "$n" \
    "$wbb / $wbm" "$wcb / $wcm" "$(echo "$wcm / $wbm" | bc -l)" \
    "$cbb / $cbm" "$ccb / $ccm" "$(echo "$ccm / $cbm" | bc -l)" "$same"
done
echo "ratio: current / baseline of the medians; metrics: the reconstruction section of"
echo "metrics.json (NC may differ where neighbours tie at equal distance: the current"
echo "search breaks ties by index, as brute force does)"
