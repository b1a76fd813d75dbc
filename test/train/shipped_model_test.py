#!/usr/bin/python3
"""The shipped model (models/default.safetensors) reconstructs held-out
generated sequences better than the constant-depth baseline at the model's
own input size: completion far below the baseline's, ATE and Acc clearly
below it, every frame posed. The bounds are the ratios measured on these
sequences (docs/model_card.md) plus a margin for thread-count and platform
float differences (PnP's poses move ATE by about 5 % between 1 and 2
threads)."""
import argparse
import json
import os
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'support'))
from cli_test import Tally, fail, run  # noqa: E402

# Measured (30 frames x 2 held-out sequences, stride 2, every fourth pixel,
# both at 64 x 64; Intel Xeon with AMX): model / baseline = ATE 0.192 / 0.289 m
# (0.67; 0.201 m, 0.70, at 1 thread), Acc 0.125 / 0.266 m (0.47), Comp
# 0.066 / 0.554 m (0.12).
MAX_ATE_RATIO = 0.78
MAX_ACC_RATIO = 0.53
MAX_COMP_RATIO = 0.16


def run_eval(exe, source, workdir, name, frames, sequences):
    out = os.path.join(workdir, name + '.json')
    cmd = [exe] + source + ['--frames', str(frames), '--sequences', str(sequences),
                            '--stride', '2', '--no-normals', '--pixel-step', '4',
                            '--threads', '2', '--json', out]
    rc, log = run(cmd, merge_output=True)
    print(log)
    if rc != 0:
        fail('%s exited %d' % (' '.join(cmd), rc))
    with open(out) as f:
        return json.load(f)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--eval', required=True, help='long3r_model_eval')
    ap.add_argument('--model', required=True)
    ap.add_argument('--frames', type=int, default=30)
    ap.add_argument('--sequences', type=int, default=2)
    a = ap.parse_args()
    if not os.path.exists(a.model):
        fail('the shipped model %s is missing' % a.model)
    with tempfile.TemporaryDirectory() as tmp:
        root = run_eval(a.eval, ['--model', a.model], tmp, 'model', a.frames, a.sequences)
        # The plane at the model's own input size (its pixels, its rays).
        base = run_eval(a.eval, ['--baseline', 'constant-depth', '--img-size',
                                 str(root['img_size'])], tmp, 'baseline', a.frames,
                        a.sequences)['mean']
        model = root['mean']
    tally = Tally()  # 'ok   ' / 'FAIL ' and what
    check = tally.check
    check(model['posed'] == a.frames, 'every frame posed (%s of %d)' % (model['posed'], a.frames))
    check(model['ate_rmse_m'] is not None and
          model['ate_rmse_m'] < MAX_ATE_RATIO * base['ate_rmse_m'],
          'ATE %.4f m < %.2f x baseline %.4f m' % (model['ate_rmse_m'] or float('nan'),
                                                  MAX_ATE_RATIO, base['ate_rmse_m']))
    check(model['acc_mean_m'] < MAX_ACC_RATIO * base['acc_mean_m'],
          'Acc %.4f m < %.2f x baseline %.4f m' % (model['acc_mean_m'], MAX_ACC_RATIO,
                                                  base['acc_mean_m']))
    check(model['comp_mean_m'] < MAX_COMP_RATIO * base['comp_mean_m'],
          'Comp %.4f m < %.2f x baseline %.4f m' % (model['comp_mean_m'], MAX_COMP_RATIO,
                                                   base['comp_mean_m']))
    sys.exit(0 if tally.passed else 1)


if __name__ == '__main__':
    main()
