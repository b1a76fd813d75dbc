#!/usr/bin/env bash
# What the 3-D occupancy costs a frame and what its ray subsampling
# (grid_pixel_step) gives up: the demo's robot sequence (seed 7, 60 frames,
# 224 x 224, the shipped model, frames placed by the ground truth, scale
# from depth) through long3r_reconstruct with the occupancy off and with
# grid_pixel_step 1, 2, 4 and 8, the maps updated in line. Prints, side by
# side, the map stage's median time a frame (frames.csv map_ms: the voxel
# map, plus the occupancy when on), the voxels known, the grid's occupied and
# free cells, and each grid
# against the true surfaces in its band (the depth images placed by the
# ground truth): the share of its occupied cells within one cell of a true
# one, of the true cells within one cell of an occupied one (walls found),
# and of its free cells on a true surface (free where a wall is).
# Then the default step with the occupancy updated in line and on its own
# thread (maps_in_background), with the model on 2 torch threads and on 1,
# alternating for --rounds rounds: the stream's mean FPS (long3r_reconstruct's
# summary: the model's thread's time a frame, plus the map thread's catch-up
# at the end), and the median model, map and total milliseconds a frame.
#   bash scripts/occupancy_cost.sh [--frames N] [--model FILE] [--out DIR]
#                                  [--rounds N]
# Run it on a quiet machine: the figures are times.
set -euo pipefail
source "$(dirname "$0")/env.sh"
root=$LONG3R_ROOT
frames=60
model="$root/models/default.safetensors"
out="$root/build/occupancy_cost"
rounds=3
long3r_parse_args --frames=frames --model=model --out=out --rounds=rounds -- "$@"
bin=$LONG3R_CORE
long3r_build_core app_long3r_synth app_long3r_reconstruct
mkdir -p "$out"
seq="$out/seq_robot_$frames"
if [ ! -f "$seq/groundtruth.txt" ]; then
  "$bin/long3r_synth" --out "$seq" --frames "$frames" --seed 7 --width 224 --height 224 \
    --trajectory robot --quiet >/dev/null
fi
cpu=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')
echo "CPU: $cpu, $(nproc) cores; $frames frames, the robot sequence (seed 7)"
for step in off 1 2 4 8; do
  run="$out/run_$step"
  grid=(--grid-enabled true --grid-pixel-step "$step")
  [ "$step" = off ] && grid=(--grid-enabled false)
  "$bin/long3r_reconstruct" "$seq" --model "$model" --out "$run" --img-size 224 --threads 2 \
    --scale-source depth --poses groundtruth --maps-in-background false "${grid[@]}" \
    >"$run.log" 2>&1 || { echo "long3r_reconstruct failed: see $run.log" >&2; exit 1; }
done
/usr/bin/python3 - "$out" "$seq" <<'PY'
import csv, os, re, statistics, sys
import numpy as np
from PIL import Image
out, seq = sys.argv[1], sys.argv[2]

def grid(run):
    """The run's grid.pgm / grid.yaml as {(cell x, cell y): occupied?}, known cells only."""
    yaml = os.path.join(out, run, "grid.yaml")
    if not os.path.exists(yaml):
        return None, None
    text = open(yaml).read()
    res = float(re.search(r"resolution: (\S+)", text).group(1))
    ox, oy = (float(v) for v in re.search(r"origin: \[(\S+), (\S+),", text).groups())
    pix = np.array(Image.open(os.path.join(out, run, "grid.pgm")))
    h, w = pix.shape
    x0, y0 = round(ox / res), round(oy / res)
    cells = {}
    for r, c in zip(*np.nonzero(pix != 205)):
        cells[(x0 + int(c), y0 + h - 1 - int(r))] = bool(pix[r, c] == 0)
    return cells, res

def truth(res, lo=0.10, hi=1.80):
    """Cells of the true surfaces the frames saw in the band above the room's
    floor (z = 0): every pixel of the depth images, placed by groundtruth.txt."""
    k = [l for l in open(os.path.join(seq, "calibration.txt")) if not l.startswith("#")][0].split()
    fx, fy, cx, cy = (float(v) for v in k[:4])
    poses = [l.split() for l in open(os.path.join(seq, "groundtruth.txt")) if not l.startswith("#")]
    depths = [l.split() for l in open(os.path.join(seq, "depth.txt")) if not l.startswith("#")]
    cells = set()
    for (t, tx, ty, tz, qx, qy, qz, qw), (_, f) in zip(poses, depths):
        x, y, z, w_ = float(qx), float(qy), float(qz), float(qw)
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w_), 2 * (x * z + y * w_)],
                      [2 * (x * y + z * w_), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w_)],
                      [2 * (x * z - y * w_), 2 * (y * z + x * w_), 1 - 2 * (x * x + y * y)]])
        d = np.array(Image.open(os.path.join(seq, f)), dtype=np.float64) / 5000.0
        v, u = np.nonzero(d > 0)
        zc = d[v, u]
        pc = np.stack([(u - cx) / fx * zc, (v - cy) / fy * zc, zc])
        pw = R @ pc + np.array([[float(tx)], [float(ty)], [float(tz)]])
        band = (pw[2] > lo) & (pw[2] < hi)
        for cx_, cy_ in np.floor(pw[:2, band] / res).astype(int).T:
            cells.add((int(cx_), int(cy_)))
    return cells

def map_ms(run):
    rows = [r for r in csv.DictReader(open(os.path.join(out, run, "frames.csv")))
            if r["added_to_map"] == "1"]
    return statistics.median(float(r["map_ms"]) for r in rows)

def voxels(run):
    m = re.search(r"occupancy: (\d+) voxels", open(os.path.join(out, run + ".log")).read())
    return m.group(1) if m else "-"

def near(cell, cells):
    return any((cell[0] + dx, cell[1] + dy) in cells for dx in (-1, 0, 1) for dy in (-1, 0, 1))

print("against the true surfaces in the band (10-180 cm above the floor), within one cell:")
print("%-5s %9s %8s %9s %6s %11s %11s %12s" % ("step", "map ms", "voxels", "occupied", "free",
                                               "occ. true", "walls found", "free on wall"))
gt = None
for step in ["off", "1", "2", "4", "8"]:
    run = "run_" + step
    g, res = grid(run)
    if g is None:
        print("%-5s %9.2f %8s" % (step, map_ms(run), "-"))
        continue
    gt = gt or truth(res)
    occ = {k for k, v in g.items() if v}
    free = [k for k, v in g.items() if not v]
    print("%-5s %9.2f %8s %9d %6d %10.1f%% %10.1f%% %11.1f%%" % (
        step, map_ms(run), voxels(run), len(occ), len(free),
        100.0 * sum(near(k, gt) for k in occ) / max(1, len(occ)),
        100.0 * sum(near(k, occ) for k in gt) / max(1, len(gt)),
        100.0 * sum(k in gt for k in free) / max(1, len(free))))
PY

echo
echo "the occupancy (grid_pixel_step 4) in line and in the background, $rounds rounds:"
printf '%-6s %-8s %-11s %9s %9s %9s %9s\n' round threads background mean_FPS model_ms map_ms \
  total_ms
for round in $(seq 1 "$rounds"); do
  for setting in "2 false" "2 true" "1 false" "1 true"; do
    read -r threads background <<<"$setting"
    run="$out/background_${background}_${threads}_$round"
    "$bin/long3r_reconstruct" "$seq" --model "$model" --out "$run" --img-size 224 \
      --threads "$threads" \
      --scale-source depth --poses groundtruth --grid-pixel-step 4 \
      --maps-in-background "$background" >"$run.log" 2>&1 ||
      { echo "long3r_reconstruct failed: see $run.log" >&2; exit 1; }
    fps=$(sed -nE 's/.*mean ([0-9.]+) FPS.*/\1/p' "$run.log" | head -1)
    read -r model_ms map_ms total_ms < <(/usr/bin/python3 - "$run/frames.csv" <<'PY'
import csv, statistics, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print(" ".join("%.1f" % statistics.median(float(r[k]) for r in rows)
               for k in ("model_ms", "map_ms", "total_ms")))
PY
)
    printf '%-6s %-8s %-11s %9s %9s %9s %9s\n' "$round" "$threads" "$background" "$fps" \
      "$model_ms" "$map_ms" "$total_ms"
  done
done
