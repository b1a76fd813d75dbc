#!/usr/bin/env python3
"""The blind control against pairs seen, from a training run's train_log.csv
(validation rows with val_blind_ratio; docs/model_card.md, "Registration
against pairs seen"). Prints a markdown table: step, pairs (or sequences)
seen, validation regression, blind ratio, rotation error and the true
relative rotation.

  python3 scripts/blind_curve.py RUN/train_log.csv [--batch 16] [--every N]
"""
import argparse
import csv
import math


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", help="train_log.csv of a run with validation.blind_scenes > 0")
    ap.add_argument("--batch", type=int, default=16, help="sequences per step (the stage's batch_size)")
    ap.add_argument("--every", type=int, default=1, help="print every N-th validation row")
    a = ap.parse_args()
    rows = [r for r in csv.DictReader(open(a.log))
            if r.get("val_blind_ratio", "nan") not in ("nan", "")]
    if not rows:
        raise SystemExit("%s: no validation row with the blind control" % a.log)
    print("| step | pairs seen | val regression | blind ratio | rot err (deg) | true rot (deg) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for i, r in enumerate(rows):
        if i % a.every and i != len(rows) - 1:
            continue
        f = lambda k: float(r[k])
        print("| %d | %d | %.4f | %.3f | %.2f | %.2f |" % (
            int(r["step"]), int(r["step"]) * a.batch, f("val_regression"), f("val_blind_ratio"),
            f("val_rot_err_deg"), f("val_rot_true_deg")))
    best = min(rows, key=lambda r: float(r["val_blind_ratio"]))
    print("\nlowest blind ratio %.3f at step %s" % (float(best["val_blind_ratio"]), best["step"]))


if __name__ == "__main__":
    main()
