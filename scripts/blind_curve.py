#!/usr/bin/env python3
"""The blind control against pairs seen, from a training run's train_log.csv
(validation rows with val_blind_ratio; docs/model_card.md, "Registration
against pairs seen"). Prints a markdown table: step, pairs (or sequences)
seen, validation regression, blind ratio, shape error (where logged),
rotation error and the true relative rotation; then, where the run wrote
blind_control.csv beside its log, the blind ratio and shape error at each
stride of its validation.

  python3 scripts/blind_curve.py RUN/train_log.csv [--batch 16] [--frames 2] [--every N]
"""
import argparse
import csv
import math
import os


def seen(frames):
    return "pairs seen" if frames == 2 else "%d-frame sequences seen" % frames


def per_stride(path, batch, frames, every):
    """The table of blind_control.csv: a row per validation, a column pair
    (blind ratio / shape error) per stride."""
    rows = list(csv.DictReader(open(path)))
    if not rows:
        return
    strides = sorted({int(r["stride"]) for r in rows})
    steps = sorted({int(r["step"]) for r in rows})
    at = {(int(r["step"]), int(r["stride"])): r for r in rows}
    print("\nper stride (blind_control.csv, %s-frame sequences): blind ratio / shape error" %
          rows[0]["frames"])
    print("| step | %s | " % seen(frames) + " | ".join("stride %d" % s for s in strides) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in strides) + " |")
    for i, step in enumerate(steps):
        if i % every and i != len(steps) - 1:
            continue
        cells = []
        for s in strides:
            r = at.get((step, s))
            cells.append("%.3f / %.3f" % (float(r["blind_ratio"]), float(r["shape_err"]))
                         if r else "-")
        print("| %d | %d | %s |" % (step, step * batch, " | ".join(cells)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", help="train_log.csv of a run with validation.blind_scenes > 0")
    ap.add_argument("--batch", type=int, default=16, help="sequences per step (the stage's batch_size)")
    ap.add_argument("--frames", type=int, default=2, help="frames per sequence (the stage's frames)")
    ap.add_argument("--every", type=int, default=1, help="print every N-th validation row")
    a = ap.parse_args()
    rows = [r for r in csv.DictReader(open(a.log))
            if r.get("val_blind_ratio", "nan") not in ("nan", "")]
    if not rows:
        raise SystemExit("%s: no validation row with the blind control" % a.log)
    print("| step | %s | val regression | blind ratio | shape err | rot err (deg) | "
          "true rot (deg) |" % seen(a.frames))
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for i, r in enumerate(rows):
        if i % a.every and i != len(rows) - 1:
            continue
        f = lambda k: float(r.get(k, "nan") or "nan")
        shape = f("val_shape_err")
        print("| %d | %d | %.4f | %.3f | %s | %.2f | %.2f |" % (
            int(r["step"]), int(r["step"]) * a.batch, f("val_regression"), f("val_blind_ratio"),
            "-" if math.isnan(shape) else "%.3f" % shape, f("val_rot_err_deg"),
            f("val_rot_true_deg")))
    best = min(rows, key=lambda r: float(r["val_blind_ratio"]))
    print("\nlowest blind ratio %.3f at step %s" % (float(best["val_blind_ratio"]), best["step"]))
    strides = os.path.join(os.path.dirname(os.path.abspath(a.log)), "blind_control.csv")
    if os.path.exists(strides):
        per_stride(strides, a.batch, a.frames, 1)


if __name__ == "__main__":
    main()
