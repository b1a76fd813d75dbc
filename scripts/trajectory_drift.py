#!/usr/bin/env python3
"""Where a long path's error comes from: a run of long3r_reconstruct against
its TUM-layout ground truth, in windows of frames. Per window: the estimated
path's step length over the true one before any alignment (a trend is scale
drift: the stream's scale shrinking or growing along the keyframe chain),
and the median angle between estimated and true steps after one Sim(3)
alignment of the whole path (rotation drift and step noise); then the same
step error by the tracker's status (frames.csv), so that frames placed by
the motion prior can be told from tracked ones (docs/model_card.md, "Poses
from keyframes").

    /usr/bin/python3 scripts/trajectory_drift.py RUN_DIR GT_DIR [--window 20]

RUN_DIR holds trajectory.txt and frames.csv; GT_DIR groundtruth.txt. Frames
are matched by their stamps.
"""
import argparse
import csv
import os

import numpy as np


def read_tum(path):
    poses = {}
    for line in open(path):
        if line.startswith('#') or not line.strip():
            continue
        v = [float(x) for x in line.split()]
        poses[round(v[0], 4)] = np.array(v[1:4])
    return poses


def sim3_align(est, gt):
    """Umeyama: s, R, t with gt ~ s R est + t."""
    mu_e, mu_g = est.mean(0), gt.mean(0)
    x, y = est - mu_e, gt - mu_g
    u, d, vt = np.linalg.svd(y.T @ x / len(est))
    s_fix = np.eye(3)
    s_fix[2, 2] = np.sign(np.linalg.det(u @ vt))
    r = u @ s_fix @ vt
    s = np.trace(np.diag(d) @ s_fix) / x.var(0).sum()
    return (s * (r @ x.T)).T + mu_g


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('run')
    ap.add_argument('gt')
    ap.add_argument('--window', type=int, default=20)
    a = ap.parse_args()
    est = read_tum(os.path.join(a.run, 'trajectory.txt'))
    gt = read_tum(os.path.join(a.gt, 'groundtruth.txt'))
    stamps = sorted(k for k in est if k in gt)
    if len(stamps) < 3:
        raise SystemExit('trajectory_drift.py: fewer than 3 frames with ground truth')
    e = np.array([est[k] for k in stamps])
    g = np.array([gt[k] for k in stamps])
    aligned = sim3_align(e, g)
    err = np.linalg.norm(aligned - g, axis=1)
    print('frames %d, ATE %.2f cm' % (len(stamps), 100 * np.sqrt((err ** 2).mean())))

    raw_e, raw_g = np.diff(e, axis=0), np.diff(g, axis=0)
    step_e, step_g = np.linalg.norm(raw_e, axis=1), np.linalg.norm(raw_g, axis=1)
    d_a = np.diff(aligned, axis=0)
    cos = np.einsum('ij,ij->i', d_a, raw_g) / (np.linalg.norm(d_a, axis=1) * step_g + 1e-12)
    angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    w = a.window
    windows = range(0, len(step_e), w)
    print('frames from:            ' + ' '.join('%5d' % i for i in windows))
    print('step length est / true: ' +
          ' '.join('%5.2f' % (step_e[i:i + w].sum() / step_g[i:i + w].sum()) for i in windows))
    print('step direction err deg: ' + ' '.join('%5.0f' % np.median(angle[i:i + w]) for i in windows))
    print('position error cm:      ' + ' '.join('%5.0f' % (100 * err[i:i + w].mean()) for i in windows))

    frames = os.path.join(a.run, 'frames.csv')
    if os.path.exists(frames):
        status = {}
        for row in csv.DictReader(open(frames)):
            status[round(float(row['stamp']), 4)] = row.get('tracking') or '(no tracker result)'
        by = {}
        for i in range(1, len(stamps)):
            by.setdefault(status.get(stamps[i], '?'), []).append(i - 1)
        for name, idx in sorted(by.items(), key=lambda kv: -len(kv[1])):
            step_err = np.linalg.norm(d_a[idx] - raw_g[idx], axis=1)
            print('%-22s %4d steps: aligned length / true %.2f, step error %.1f cm mean' %
                  (name, len(idx), np.linalg.norm(d_a[idx], axis=1).sum() / step_g[idx].sum(),
                   100 * step_err.mean()))


if __name__ == '__main__':
    main()
