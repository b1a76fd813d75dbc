#!/usr/bin/python3
"""Compares one metric of two long3r_eval runs: fails when B's value exceeds
A's by more than --max-rel (relative). Used to hold the distorted-camera replay
to the map accuracy of the undistorted run of the same scene.
Usage: compare_metrics.py A/metrics.json B/metrics.json --key reconstruction.accuracy_mean_m
"""
import argparse
import json
import sys


def value(path, key):
    with open(path) as f:
        v = json.load(f)
    for k in key.split('.'):
        v = v[k]
    return float(v)


def main():
    p = argparse.ArgumentParser()
    p.add_argument('reference')
    p.add_argument('candidate')
    p.add_argument('--key', default='reconstruction.accuracy_mean_m')
    p.add_argument('--max-rel', type=float, default=0.05)
    a = p.parse_args()
    ref, cand = value(a.reference, a.key), value(a.candidate, a.key)
    rel = (cand - ref) / ref
    print('%s: reference %.5f, candidate %.5f (%+.2f %%, bound %+.2f %%)'
          % (a.key, ref, cand, 100 * rel, 100 * a.max_rel))
    return 0 if rel <= a.max_rel else 1


if __name__ == '__main__':
    sys.exit(main())
