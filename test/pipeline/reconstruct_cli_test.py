#!/usr/bin/python3
"""End-to-end test of long3r_reconstruct: a short generated TUM sequence, a
random tiny model, all outputs checked for shape; plus the error cases."""
import argparse
import csv
import os
import shutil
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import check, fresh_dir, run  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--synth", required=True)
    ap.add_argument("--make-model", required=True)
    ap.add_argument("--reconstruct", required=True)
    ap.add_argument("--workdir", required=True)
    a = ap.parse_args()
    fresh_dir(a.workdir)
    # The help of a node parameter whose default here is not the node's says both.
    rc, log = run([a.reconstruct, "--help"])
    check(rc == 0, "--help: " + log)
    row = " ".join(log[log.index("--drop-zero-stamps"):].split("--")[1].split())
    check("the node's default is true, this tool's differs (default false)" in row,
          "--drop-zero-stamps help: " + row)
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

    check("1 stream(s)" in log and "(model units)" in log, "scale line: " + log)

    # The node's session: a fixed metric scale reaches every result; the
    # dataset's depth images and groundtruth.txt serve as scale sources.
    out_fixed = os.path.join(a.workdir, "out_fixed")
    rc, log = run([a.reconstruct, "--model", model, "--out", out_fixed, "--img-size", "64",
                   "--scale-source", "fixed", "--scale-m-per-unit", "2.5", seq])
    check(rc == 0 and "scale 2.5 m per model unit (metric)" in log, "fixed scale: " + log)
    rows = list(csv.DictReader(open(os.path.join(out_fixed, "frames.csv"))))
    check(rows and all(float(r["scale"]) == 2.5 for r in rows), "frames.csv scale column")
    check("metres" in open(os.path.join(out_fixed, "trajectory.txt")).readline(),
          "trajectory.txt header names its units")
    for source in ("depth", "odometry"):
        rc, log = run([a.reconstruct, "--model", model, "--out", os.path.join(a.workdir, source),
                       "--img-size", "64", "--scale-source", source, seq])
        check(rc == 0 and "summary: 6 frames used" in log, source + " scale: " + log)
    rc, log = run([a.reconstruct, "--model", model, "--out", out, "--scale-source", "sonar", seq])
    check(rc != 0 and '"odometry"' in log, "bad scale source: " + log)
    folder_only = os.path.join(a.workdir, "rgb_only")
    shutil.copytree(os.path.join(seq, "rgb"), folder_only)
    rc, log = run([a.reconstruct, "--model", model, "--out", out, "--scale-source", "depth",
                   folder_only])
    check(rc != 0 and "needs a TUM folder" in log, "depth scale without depth: " + log)

    # The tracker's true-depth control: the folder's depth images, the
    # keyframe tracker, an undistorted calibration of the folder's own.
    rc, log = run([a.reconstruct, "--model", model, "--out", os.path.join(a.workdir, "true_depth"),
                   "--img-size", "64", "--pose-source", "keyframes", "--tracker-true-depth", seq])
    check(rc == 0 and "summary: 6 frames used" in log and "no depth image" not in log,
          "--tracker-true-depth: " + log)
    for args, why in ((["--pose-source", "model", seq], "needs --pose-source keyframes"),
                      (["--pose-source", "keyframes", folder_only], "needs a TUM folder"),
                      (["--pose-source", "keyframes", "--calib", "50", "50", "48", "32", seq],
                       "its own undistorted calibration.txt"),
                      (["--pose-source", "keyframes", "--tracker-constant-depth", seq],
                       "give one of --tracker-true-depth and --tracker-constant-depth"),
                      (["--pose-source", "keyframes", "--scale-source", "depth", seq],
                       "lifts its features by the depth images already")):
        rc, log = run([a.reconstruct, "--model", model, "--out", out, "--img-size", "64",
                       "--tracker-true-depth"] + args)
        check(rc != 0 and why in log, "--tracker-true-depth %s: %s" % (args, log))

    # A camera with lens distortion (calibration.txt with plumb_bob) is
    # rectified, as the node rectifies camera_info's.
    lens = os.path.join(a.workdir, "lens")
    rc, log = run([a.synth, "--out", lens, "--frames", "4", "--width", "96", "--height", "64",
                   "--distortion", "-0.2", "0.05", "0", "0", "0", "--quiet"])
    check(rc == 0, "long3r_synth --distortion: " + log)
    rc, log = run([a.reconstruct, "--model", model, "--out", os.path.join(a.workdir, "lens_out"),
                   "--img-size", "64", lens])
    check(rc == 0 and "camera calibration from calibration.txt" in log and
          "images rectified" in log, "distorted calibration: " + log)

    # Continuity: a stamp jumping far back starts a new stream, named.
    jump = os.path.join(a.workdir, "jump")
    shutil.copytree(seq, jump)
    lines = open(os.path.join(jump, "rgb.txt")).read().splitlines()
    data = [l for l in lines if l and not l.startswith("#")]
    t, path = data[4].split()
    data[4] = "%.6f %s" % (float(t) - 100.0, path)
    data[5] = "%.6f %s" % (float(data[5].split()[0]) - 100.0, data[5].split()[1])
    open(os.path.join(jump, "rgb.txt"), "w").write("\n".join(data) + "\n")
    rc, log = run([a.reconstruct, "--model", model, "--out", os.path.join(a.workdir, "jump_out"),
                   "--img-size", "64", jump])
    check(rc == 0 and "time jumped back" in log and "2 stream(s)" in log, "time jump: " + log)

    # Sessions: frames 0-2 saved, then 3-5 continue them in another run; the
    # second run's path holds the first's poses unchanged, its map every
    # saved point, and its frame indices go on. Other settings are refused.
    session = os.path.join(a.workdir, "part1.l3s")
    part1, part2 = os.path.join(a.workdir, "part1"), os.path.join(a.workdir, "part2")
    rc, log = run([a.reconstruct, "--model", model, "--out", part1, "--img-size", "64",
                   "--max-frames", "3", "--save-session", session, seq])
    check(rc == 0 and "session saved to " + session in log, "save session: " + log)
    rc, log = run([a.reconstruct, "--model", model, "--out", part2, "--img-size", "64",
                   "--first-frame", "3", "--load-session", session, seq])
    check(rc == 0 and "session loaded from " + session in log and "3 frames used" in log,
          "load session: " + log)
    rows = list(csv.DictReader(open(os.path.join(part2, "frames.csv"))))
    check([int(r["frame"]) for r in rows] == [3, 4, 5], "frame indices go on: %s" % rows)
    t1 = [l for l in open(os.path.join(part1, "trajectory.txt")) if not l.startswith("#")]
    t2 = [l for l in open(os.path.join(part2, "trajectory.txt")) if not l.startswith("#")]
    check(t2[:len(t1)] == t1 and len(t2) >= len(t1), "joined trajectory: %s / %s" % (t1, t2))

    def ply_points(path):
        with open(path, "rb") as f:
            for line in f:
                if line.startswith(b"element vertex"):
                    return int(line.split()[2])
        return -1
    check(ply_points(os.path.join(part2, "map.ply")) >= ply_points(os.path.join(part1, "map.ply")),
          "the continued map keeps the saved points")
    rc, log = run([a.reconstruct, "--model", model, "--out", part2, "--img-size", "32",
                   "--load-session", session, seq])
    check(rc != 0 and "a model input size of 64x64, this one 32x32" in log, "other size: " + log)
    other = os.path.join(a.workdir, "other.safetensors")
    rc, log = run([a.make_model, "--out", other, "--size", "tiny", "--seed", "3"])
    check(rc == 0, "make_random_model: " + log)
    rc, log = run([a.reconstruct, "--model", other, "--out", part2, "--img-size", "64",
                   "--load-session", session, seq])
    check(rc != 0 and "other weights" in log, "other weights: " + log)
    rc, log = run([a.reconstruct, "--model", model, "--out", part2, "--img-size", "64",
                   "--load-session", model, seq])
    check(rc != 0 and "not a long3r session file" in log, "a checkpoint as session: " + log)

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
