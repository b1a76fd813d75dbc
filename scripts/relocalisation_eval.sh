#!/usr/bin/env bash
# Relocalisation by images (pose_source keyframes) into saved sessions, with
# long3r_reconstruct and the shipped model on the held-out generated
# sequences at a camera's resolution (640 x 480, every 2nd frame):
#   saved     frames 0-29 of a sequence, saved as a session;
#   revisit   the session loaded, frames 10-29 again: the first frame must
#             be relocalised and the path must land where the saved one was;
#   continue  the session loaded, frames 30-59 (where the camera went on);
#   elsewhere the session loaded, another sequence's frames 0-29: every
#             frame must be refused and the map must not grow.
# Per part: how the tracker took the frames (frames.csv's tracking column),
# map points, and the position error of the part's poses against the truth
# after the saved part's Sim(3) alignment, beside the same frames' error in
# an uninterrupted run of frames 0-59 (aligned the same way: its frames
# 0-29), so that what the load costs shows apart from the tracker's drift.
#   bash scripts/relocalisation_eval.sh [--model FILE] [--out DIR]
set -euo pipefail
source "$(dirname "$0")/env.sh"
root=$LONG3R_ROOT
model="$root/models/default.safetensors"
out="$root/build/relocalisation_eval"
long3r_parse_args --model=model --out=out -- "$@"
bin=$LONG3R_CORE
long3r_build_core app_long3r_synth app_long3r_reconstruct
mkdir -p "$out"
sequence() {  # seed -> folder of 120 frames at 640 x 480
  local seq="$out/seq_$1"
  if [ ! -f "$seq/groundtruth.txt" ]; then
    "$bin/long3r_synth" --out "$seq" --seed "$1" --frames 120 --width 640 --height 480 \
      --quiet >/dev/null
  fi
  echo "$seq"
}
reconstruct() {  # out-dir sequence first-frame frames [args...]
  local run=$1 seq=$2 first=$3 frames=$4
  shift 4
  "$bin/long3r_reconstruct" --model "$model" --out "$run" --stride 2 --first-frame "$first" \
    --max-frames "$frames" --pose-source keyframes "$@" "$seq" > "$run.log" 2>&1
}
for seed in 2000000 2000001 2000002; do
  seq=$(sequence "$seed")
  other=$(sequence $((seed + 100)))
  run="$out/$seed"
  reconstruct "$run.saved" "$seq" 0 30 --save-session "$run.l3s"
  reconstruct "$run.revisit" "$seq" 20 20 --load-session "$run.l3s"
  reconstruct "$run.continue" "$seq" 60 30 --load-session "$run.l3s"
  reconstruct "$run.elsewhere" "$other" 0 30 --load-session "$run.l3s"
  reconstruct "$run.whole" "$seq" 0 60
  /usr/bin/python3 - "$seq/groundtruth.txt" "$run" <<'EOF'
import csv, collections, math, sys
import numpy as np

gt_rows = [l.split() for l in open(sys.argv[1]) if l.strip() and not l.startswith('#')]
gt = {round(float(r[0]), 6): np.array([float(v) for v in r[1:4]]) for r in gt_rows}
run = sys.argv[2]

def trajectory(part):
    rows = [l.split() for l in open(f'{run}.{part}/trajectory.txt') if l.strip() and not l.startswith('#')]
    return {round(float(r[0]), 6): np.array([float(v) for v in r[1:4]]) for r in rows}

def frames(part):
    return list(csv.DictReader(open(f'{run}.{part}/frames.csv')))

def alignment(traj, stamps):
    # Sim(3) (Umeyama) of the poses at `stamps` onto the truth.
    X = np.array([traj[s] for s in stamps]); Y = np.array([gt[s] for s in stamps])
    mx, my = X.mean(0), Y.mean(0)
    U, D, Vt = np.linalg.svd((Y - my).T @ (X - mx) / len(X))
    S = np.eye(3); S[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ S @ Vt; c = np.trace(np.diag(D) @ S) / ((X - mx) ** 2).sum(1).mean()
    return lambda p: c * R @ (p - mx) + my

saved_stamps = sorted(s for s in trajectory('saved') if s in gt)
to_gt = alignment(trajectory('saved'), saved_stamps)
whole = trajectory('whole')
whole_to_gt = alignment(whole, saved_stamps)

def rms(traj, align, stamps):
    return 100 * math.sqrt(np.mean([np.sum((align(traj[s]) - gt[s]) ** 2) for s in stamps]))

def error(part):
    traj = trajectory(part)
    rows = frames(part)
    new = [round(float(r['stamp']), 6) for r in rows if r['tracking'] in ('relocalised', 'tracked', 'keyframe')]
    new = [s for s in new if s in traj and s in gt]
    if not new:
        return 'no poses'
    still = math.sqrt(np.mean([np.sum((gt[s] - np.mean([gt[t] for t in new], 0)) ** 2) for s in new]))
    uninterrupted = rms(whole, whole_to_gt, [s for s in new if s in whole])
    return (f'position error {rms(traj, to_gt, new):.1f} cm (uninterrupted {uninterrupted:.1f}, '
            f'a still camera {100 * still:.1f})')

line = [f'seed {run.rsplit("/", 1)[1]}:']
for part in ('saved', 'revisit', 'continue', 'elsewhere'):
    rows = frames(part)
    counts = collections.Counter(r['tracking'] for r in rows)
    first = rows[0]['tracking'] if rows else '-'
    points = rows[-1]['map_points'] if rows else '0'
    what = ', '.join(f'{n} {k}' for k, n in sorted(counts.items()))
    line.append(f'  {part}: first {first}; {what}; map {points} points; {error(part)}')
print('\n'.join(line))
EOF
done
