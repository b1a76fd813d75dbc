#!/usr/bin/env python3
"""End-to-end test of the command-line tools: long3r_synth writes a sequence;
long3r_eval scores the ground truth against itself (all errors ~0) and a
scaled, shifted copy of it (errors still ~0 after Sim(3) alignment), and a
noisy trajectory (ATE > 0). Registered in synth.cmake."""

import argparse
import json
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import check, fresh_dir, run  # noqa: E402


def run_eval(tool, out, *extra):
    run([tool, "--out", out, *extra], check=True)
    with open(os.path.join(out, "metrics.json")) as f:
        return json.load(f)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--synth", required=True)
    ap.add_argument("--eval", required=True)
    ap.add_argument("--workdir", required=True)
    a = ap.parse_args()
    fresh_dir(a.workdir)
    seq = os.path.join(a.workdir, "seq")
    run([a.synth, "--out", seq, "--frames", "30", "--width", "64", "--height", "48",
         "--trajectory", "orbit", "--speed", "0.05", "--quiet"], check=True)
    gt = os.path.join(seq, "groundtruth.txt")

    # 1. GT against itself, map = the GT cloud (written by a first run).
    out1 = os.path.join(a.workdir, "self")
    run_eval(a.eval, out1, "--gt", seq, "--save-gt-cloud")
    m = run_eval(a.eval, out1, "--gt", seq, "--est-traj", gt, "--est-map", os.path.join(out1, "gt_cloud.ply"))
    t, r = m["trajectory"], m["reconstruction"]
    check(t["matched"] == 30, "matched")
    check(t["ate_m"]["rmse"] < 1e-6 and t["rpe_translation_m"]["rmse"] < 1e-6, "self ATE/RPE")
    check(t["rpe_rotation_deg"]["rmse"] < 1e-4, "self RPE rot")
    check(r["accuracy_mean_m"] < 1e-4 and r["completion_mean_m"] < 1e-4, "self acc/comp")
    check(r["nc_mean"] > 0.999, "self NC")
    for png in ("trajectory.png", "map_error.png"):
        check(os.path.getsize(os.path.join(out1, png)) > 1000, png)

    # 2. The estimate in another frame and scale: Sim(3) alignment undoes it.
    est = os.path.join(a.workdir, "est.txt")
    noisy = os.path.join(a.workdir, "noisy.txt")
    with open(gt) as f, open(est, "w") as e, open(noisy, "w") as n:
        k = 0
        for line in f:
            if line.startswith("#"):
                continue
            v = [float(x) for x in line.split()]
            e.write("%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n" % (v[0], 0.5 * v[1] + 1, 0.5 * v[2] - 2, 0.5 * v[3], *v[4:]))
            d = 0.01 if k % 2 == 0 else -0.01
            n.write("%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n" % (v[0], v[1], v[2], v[3] + d, *v[4:]))
            k += 1
    m = run_eval(a.eval, os.path.join(a.workdir, "scaled"), "--gt", seq, "--est-traj", est)
    check(abs(m["trajectory"]["sim3"]["scale"] - 2.0) < 1e-6, "scale %f" % m["trajectory"]["sim3"]["scale"])
    check(m["trajectory"]["ate_m"]["rmse"] < 1e-6, "scaled ATE")
    # 3. Alternating +-1 cm in z: ATE about 1 cm, RPE about 2 cm.
    m = run_eval(a.eval, os.path.join(a.workdir, "noisy"), "--gt", seq, "--est-traj", noisy, "--no-scale")
    ate = m["trajectory"]["ate_m"]["rmse"]
    check(0.008 < ate <= 0.0101, "noisy ATE %f" % ate)
    check(abs(m["trajectory"]["rpe_translation_m"]["median"] - 0.02) < 0.002, "noisy RPE")
    print("3 passed, 0 failed")


if __name__ == "__main__":
    main()
