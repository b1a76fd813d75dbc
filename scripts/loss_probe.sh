#!/usr/bin/env bash
# The loss probe of docs/model_card.md ("Why the model does not register"):
# what the training loss charges for registration at each camera baseline.
# On held-out generated sequences (seeds 2000000..) of FRAMES frames at
# several strides of the 2 cm path, it scores a model, the same model without
# any memory (K = 0, L = 0: each frame decoded with its neighbour only, so
# nothing can tell it where camera 0 is), and three oracles built
# from the ground truth (perfect depth without motion, frame 0's geometry for
# every frame, the constant-depth plane) by the loss's regression term
# (`loss`) and by what is left of it once each frame is placed by its own
# best similarity transform (`loss_reg`, shape error only). Writes one JSON per
# row and stride into OUT_DIR and prints a table.
#   bash scripts/loss_probe.sh [OUT_DIR] [--model FILE] [--frames N]
#        [--strides "1 2 4 8 16"] [--sequences S] [--img-size N] [--threads N]
#        [--bin DIR]
# --bin: use the long3r_model_eval found in DIR (e.g. the catkin build's
# build/.ws/devel/lib/long3r_ros) instead of building build/core.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

out="$LONG3R_ROOT/build/loss_probe"
model="$LONG3R_ROOT/models/default.safetensors"
frames=5
strides="1 2 4 8 16"
sequences=4
img_size=224
threads=$(nproc)
bin=""
long3r_parse_args --model=model --frames=frames --strides=strides --sequences=sequences \
  --img-size=img_size --threads=threads --bin=bin @out -- "$@"
if [ -z "$bin" ]; then
  bin=$LONG3R_CORE
  long3r_build_core app_long3r_model_eval
fi
mkdir -p "$out"

rows=(model model_no_memory true_depth_no_motion frame0_geometry constant_depth)
for stride in $strides; do
  for name in "${rows[@]}"; do
    case "$name" in
      model) src=(--model "$model") ;;
      model_no_memory) src=(--model "$model" --short-term-frames 0 --long-term-capacity 0) ;;
      *) src=(--baseline "${name//_/-}") ;;  # e.g. frame0_geometry: --baseline frame0-geometry
    esac
    "$bin/long3r_model_eval" "${src[@]}" --frames "$frames" --sequences "$sequences" \
      --stride "$stride" --img-size "$img_size" --pixel-step 4 --no-normals \
      --threads "$threads" --json "$out/${name}_s${stride}.json" >/dev/null
  done
done

/usr/bin/python3 - "$out" "$frames" "$model" $strides <<'EOF'
import json, os, sys
out, frames, model = sys.argv[1], int(sys.argv[2]), sys.argv[3]
strides = [int(s) for s in sys.argv[4:]]
rows = ['model', 'model_no_memory', 'true_depth_no_motion', 'frame0_geometry',
        'constant_depth']
print('loss probe: %d-frame held-out sequences; model %s' % (frames, model))
# reg_left: the registration part (loss - loss_reg) as a fraction of the
# still oracle's loss (which is all registration): 1 = no better than not
# moving the frames at all, 0 = registered exactly.
print('%-7s %-8s %-22s %8s %8s %9s %8s %8s %8s' % ('stride', 'cm/frame', 'prediction', 'loss',
      'loss_reg', 'reg_share', 'reg_left', 'Acc_m', 'ATE_m'))
for s in strides:
    means = {}
    for r in rows:
        with open(os.path.join(out, '%s_s%d.json' % (r, s))) as f:
            means[r] = json.load(f)['mean']
    still = means['true_depth_no_motion']['loss_regression']
    for r in rows:
        m = means[r]
        loss, reg = m['loss_regression'], m['loss_registered']
        share = (loss - reg) / loss if loss > 0 else float('nan')
        left = (loss - reg) / still if still > 0 else float('nan')
        ate = m['ate_rmse_m']
        print('%-7d %-8d %-22s %8.4f %8.4f %8.1f%% %8.2f %8.4f %8s' %
              (s, 2 * s, r, loss, reg, 100 * share, left, m['acc_mean_m'],
               '%.4f' % ate if ate is not None else 'n/a'))
EOF
