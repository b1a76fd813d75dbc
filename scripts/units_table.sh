#!/usr/bin/env bash
# Which pose_source x scale_source pairs reach metres with a model (default:
# the shipped one), and when: runs the robot demo (scripts/demo.sh --robot:
# 60 frames of a wheeled base, wheel odometry with a 3 % scale error,
# registered depth) once per pair and prints a Markdown table: the first
# frame whose ~pointmap is metric (the outputs that carry metres are held
# until then, README "Units"), the scale applied, and the saved map's Sim(3)
# scale against the ground truth (1 = metric). Not a CI test: about 3 minutes
# a pair on two cores.
#   bash scripts/units_table.sh [OUT_DIR] [--frames N] [--model FILE]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

out="$LONG3R_ROOT/build/units_table"
demo_args=()
while [ $# -gt 0 ]; do
  case "$1" in
    --frames|--model) demo_args+=("$1" "$2"); shift 2 ;;
    -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) out=$1; shift ;;
  esac
done
mkdir -p "$out"
out=$(cd "$out" && pwd)

pairs=("model odometry" "model depth" "keyframes depth" "odometry odometry" "odometry depth")
for pair in "${pairs[@]}"; do
  read -r pose scale <<<"$pair"
  echo "== pose_source $pose, scale_source $scale"
  bash "$LONG3R_ROOT/scripts/demo.sh" "$out/${pose}_${scale}" --robot --pose-source "$pose" \
    --scale-source "$scale" "${demo_args[@]}" >"$out/${pose}_${scale}.log" 2>&1 ||
    echo "   (the demo failed: $out/${pose}_${scale}.log)"
done

/usr/bin/python3 - "$out" "${pairs[@]}" <<'PY'
import json, os, sys
out, pairs = sys.argv[1], sys.argv[2:]
print("\n| `pose_source` | `scale_source` | first frame in metres | scale applied (m / unit) | map's Sim(3) scale vs truth |")
print("| --- | --- | --- | --- | --- |")
for pair in pairs:
    pose, scale = pair.split()
    d = os.path.join(out, "%s_%s" % (pose, scale))
    try:
        with open(os.path.join(d, "summary.json")) as f:
            s = json.load(f)
    except OSError:
        print("| `%s` | `%s` | (no run) | | |" % (pose, scale))
        continue
    first = s["first_metric_frame"]
    when = "never (%d frames posed)" % s["posed"] if first is None else \
        "%d of %d posed" % (first, s["posed"])
    applied = "%.4f +- %.4f" % (s["scale"], s["scale_stddev"]) if first is not None else "-"
    sim3 = "-"
    try:
        with open(os.path.join(d, "eval", "metrics.json")) as f:
            sim3 = "%.3f" % json.load(f)["reconstruction"]["sim3"]["scale"]
    except (OSError, KeyError, ValueError):
        pass
    print("| `%s` | `%s` | %s | %s | %s |" % (pose, scale, when, applied, sim3))
PY
