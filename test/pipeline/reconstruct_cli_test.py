#!/usr/bin/python3
"""End-to-end test of long3r_reconstruct: a short generated TUM sequence, a
random tiny model, all outputs checked for shape; plus the error cases."""
import argparse
import csv
import os
import shutil
import subprocess
import sys


def run(cmd):
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return p.returncode, p.stdout + p.stderr


def check(cond, what):
    if not cond:
        print("FAIL:", what)
        sys.exit(1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--synth", required=True)
    ap.add_argument("--make-model", required=True)
    ap.add_argument("--reconstruct", required=True)
    ap.add_argument("--workdir", required=True)
    a = ap.parse_args()
    shutil.rmtree(a.workdir, ignore_errors=True)
    os.makedirs(a.workdir)
    seq = os.path.join(a.workdir, "seq")
    model = os.path.join(a.workdir, "tiny.safetensors")
    out = os.path.join(a.workdir, "out")
    rc, log = run([a.synth, "--out", seq, "--frames", "6", "--width", "96", "--height", "64",
                   "--quiet"])
    check(rc == 0, "long3r_synth: " + log)
    rc, log = run([a.make_model, "--out", model, "--size", "tiny", "--seed", "2"])
    check(rc == 0 and "RANDOM" in log, "make_random_model: " + log)

    rc, log = run([a.reconstruct, "--model", model, "--out", out, "--threads", "2",
                   "--img-size", "64", "--conf-threshold", "1", seq])
    check(rc == 0, "reconstruct failed: " + log)
    check("RANDOM WEIGHTS" in log, "no random-weight warning")
    check("summary: 6 frames used" in log, "summary missing: " + log)
    with open(os.path.join(out, "map.ply"), "rb") as f:
        check(f.read(4) == b"ply\n", "map.ply header")
    rows = list(csv.DictReader(open(os.path.join(out, "frames.csv"))))
    check([int(r["frame"]) for r in rows] == list(range(6)), "frames.csv frame column")
    for r in rows:
        check(float(r["total_ms"]) > 0 and int(r["rss_kb"]) > 0 and int(r["mem_short"]) > 0,
              "frames.csv values: %s" % r)
    check(rows[0]["pnp_status"] == "ok", "frame 0 pose")
    traj = [l.split() for l in open(os.path.join(out, "trajectory.txt")) if not l.startswith("#")]
    good = sum(int(r["added_to_map"]) for r in rows)
    check(len(traj) == good and all(len(t) == 8 for t in traj), "trajectory.txt rows")
    check(float(traj[0][0]) == 0.0, "trajectory starts at frame 0")

    # Error cases.
    rc, log = run([a.reconstruct, "--out", out, seq])
    check(rc != 0 and "--model" in log, "missing --model: %d %s" % (rc, log))
    rc, log = run([a.reconstruct, "--model", os.path.join(a.workdir, "none.safetensors"),
                   "--out", out, seq])
    check(rc != 0 and "not found" in log, "missing model file: %d %s" % (rc, log))
    empty = os.path.join(a.workdir, "empty")
    os.makedirs(empty)
    rc, log = run([a.reconstruct, "--model", model, "--out", out, empty])
    check(rc != 0 and "error" in log, "empty folder: %d %s" % (rc, log))
    bad = os.path.join(a.workdir, "bad.safetensors")
    open(bad, "wb").write(b"not a checkpoint at all")
    rc, log = run([a.reconstruct, "--model", bad, "--out", out, seq])
    check(rc != 0 and "bad.safetensors" in log, "corrupt model: %d %s" % (rc, log))
    # A broken image in the middle of a folder is skipped with a warning.
    folder = os.path.join(a.workdir, "folder")
    shutil.copytree(os.path.join(seq, "rgb"), folder)
    names = sorted(os.listdir(folder))
    open(os.path.join(folder, names[2]), "wb").write(b"broken")
    rc, log = run([a.reconstruct, "--model", model, "--out", os.path.join(a.workdir, "out2"),
                   "--img-size", "64", folder])
    check(rc == 0 and "skipped" in log and "5 frames used" in log, "broken image: " + log)
    print("ok")


if __name__ == "__main__":
    main()
