#!/usr/bin/env python3
"""Robot-like bags: long3r_synth writes a robot sequence through a distorted lens,
scripts/tum_to_bag.py --robot converts it, and python rosbag reads it back: the
TF tree (one parent per frame, the static tree equal to the generator's mount,
ground truth apart), the odometry error model, the camera info with distortion,
and --compressed images (registered in synth.cmake)."""

import argparse
import io
import math
import os
import sys

import numpy as np
import rosbag

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import check, fresh_dir, load_script, run  # noqa: E402

FRAMES = 40
LENS = ["-0.25", "0.08", "0.001", "-0.0005", "-0.01"]


def tf_matrix(tr):
    t, q = tr.transform.translation, tr.transform.rotation
    return T2B.pose_matrix((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))


def read_bag(path):
    """{topic: [(msg, t, connection header)]}."""
    out = {}
    with rosbag.Bag(path) as bag:
        for topic, msg, t, header in bag.read_messages(return_connection_header=True):
            header = {k: v.decode() if isinstance(v, bytes) else v for k, v in header.items()}
            out.setdefault(topic, []).append((msg, t, header))
    return out


def convert(seq, bag, *extra):
    run([sys.executable, ARGS.script, seq, bag] + list(extra), check=True)
    return read_bag(bag)


def odometry(msgs, odom="odom", base="base_link"):
    """[(stamp, 4x4)] of odom -> base_link on /tf."""
    out = []
    for msg, _, _ in msgs["/tf"]:
        for tr in msg.transforms:
            if tr.header.frame_id == odom and tr.child_frame_id == base:
                out.append((tr.header.stamp.to_sec(), tf_matrix(tr)))
    return out


def yaw(T):
    return math.atan2(T[1, 0], T[0, 0])


def test_tree_and_camera(seq, work):
    msgs = convert(seq, os.path.join(work, "robot.bag"), "--robot", "--depth-topic", "/camera/depth",
                   "--time-offset", "1000")
    for topic, n in (("/camera/image_raw", FRAMES), ("/camera/camera_info", FRAMES), ("/camera/depth", FRAMES),
                     ("/tf_static", 1), ("/tf", 2 * FRAMES)):
        check(len(msgs.get(topic, [])) == n, "%s: %d messages, expected %d" % (topic, len(msgs.get(topic, [])), n))

    # /tf_static: latched as rosbag record stores a latched topic.
    static, t_static, header = msgs["/tf_static"][0]
    check(header.get("latching") == "1", "tf_static connection not latched: %s" % header)
    check(header.get("type") == "tf2_msgs/TFMessage" and header.get("md5sum") == T2B.TF_MESSAGE_MD5,
          "tf_static connection header")
    check(abs(t_static.to_sec() - 1000.0) < 1e-6, "tf_static at the first frame")
    check("latching" not in msgs["/tf"][0][2] or msgs["/tf"][0][2]["latching"] == "0", "/tf must not latch")

    # One parent per child frame across /tf and /tf_static, throughout.
    parents = {}
    for topic in ("/tf", "/tf_static"):
        for msg, _, _ in msgs[topic]:
            for tr in msg.transforms:
                parents.setdefault(tr.child_frame_id, set()).add(tr.header.frame_id)
    for child, ps in parents.items():
        check(len(ps) == 1, "%s has parents %s" % (child, ps))
    check(parents == {"camera_link": {"base_link"}, "camera_color_optical_frame": {"camera_link"},
                      "base_link": {"odom"}, "gt_base_link": {"gt_world"}}, "tree %s" % parents)

    # The static tree composes to the generator's mount; camera_link is the
    # REP-103 body frame: 0.2 m ahead, 1.3 m up, pitched 12 deg down, no roll.
    mount = T2B.read_pose_file(os.path.join(seq, "camera_mount.txt"))
    by_child = {tr.child_frame_id: tf_matrix(tr) for tr in static.transforms}
    composed = by_child["camera_link"] @ by_child["camera_color_optical_frame"]
    check(np.allclose(composed, mount, atol=1e-9), "static tree != camera_mount.txt")
    link = by_child["camera_link"]
    check(np.allclose(link[:3, 3], [0.2, 0.0, 1.3], atol=1e-9), "mount offset %s" % link[:3, 3])
    check(abs(math.degrees(math.asin(-link[2, 0])) - 12.0) < 1e-6, "mount pitch")
    check(abs(link[2, 1]) < 1e-12 and abs(link[1, 0]) < 1e-12, "mount roll/yaw")
    optical = by_child["camera_color_optical_frame"][:3, :3]
    check(np.allclose(optical, [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], atol=1e-12), "optical rotation")

    # Ground truth apart: gt_world -> gt_base_link is the base path, and with the
    # mount it gives the camera ground truth.
    base_gt = T2B.read_trajectory(os.path.join(seq, "base_groundtruth.txt"))
    cam_gt = T2B.read_trajectory(os.path.join(seq, "groundtruth.txt"))
    gt = [tr for msg, _, _ in msgs["/tf"] for tr in msg.transforms if tr.child_frame_id == "gt_base_link"]
    check(len(gt) == FRAMES, "gt count")
    for k, tr in enumerate(gt):
        B = T2B.pose_matrix(base_gt[k][1], base_gt[k][2])
        check(np.allclose(tf_matrix(tr), B, atol=1e-9), "gt base %d" % k)
        check(abs(B[2, 3]) < 1e-12 and abs(B[2, 2] - 1) < 1e-12, "base planar %d" % k)
        C = T2B.pose_matrix(cam_gt[k][1], cam_gt[k][2])
        check(np.allclose(B @ mount, C, atol=1e-8), "T_W_B * mount != T_W_C at %d" % k)

    # Images, camera info and depth in the optical frame; the lens in CameraInfo.
    calib = T2B.read_calibration(os.path.join(seq, "calibration.txt"))
    check(calib.model == "plumb_bob" and calib.D == [float(x) for x in LENS], "calibration.txt D %s" % (calib.D,))
    fx, fy, cx, cy = calib.K
    for (img, t, _), (info, _, _), (depth, _, _) in zip(msgs["/camera/image_raw"], msgs["/camera/camera_info"],
                                                         msgs["/camera/depth"]):
        check(img.header.frame_id == info.header.frame_id == depth.header.frame_id == "camera_color_optical_frame",
              "frame ids")
        check(img.encoding == "rgb8" and depth.encoding == "32FC1", "encodings")
        check(info.distortion_model == "plumb_bob" and list(info.D) == calib.D, "camera info D")
        check(list(info.K) == [fx, 0, cx, 0, fy, cy, 0, 0, 1], "K")
        check(list(info.P) == [fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], "P = [K | 0]")
        check(list(info.R) == [1, 0, 0, 0, 1, 0, 0, 0, 1], "R = I")
        check(info.header.stamp == img.header.stamp == depth.header.stamp, "stamps")
    return msgs


def test_odometry(seq, work, msgs):
    base_gt = T2B.read_trajectory(os.path.join(seq, "base_groundtruth.txt"))
    stamps = [b[0] + 1000.0 for b in base_gt]
    B = [T2B.pose_matrix(t, q) for _, t, q in base_gt]
    rel = [np.linalg.inv(B[0]) @ b for b in B]  # the true motion since the first frame
    steps = [np.linalg.norm((np.linalg.inv(B[k - 1]) @ B[k])[:2, 3]) for k in range(1, len(B))]
    travelled = np.concatenate([[0.0], np.cumsum(steps)])
    check(travelled[-1] > 0.5, "the base must move (%.3f m)" % travelled[-1])

    # Defaults: 3 % scale error on the distance, 1 deg/m yaw drift.
    odom = odometry(msgs)
    check(len(odom) == FRAMES, "one odometry sample per frame")
    check(all(abs(o[0] - s) < 1e-6 for o, s in zip(odom, stamps)), "odometry stamps = image stamps")
    check(np.allclose(odom[0][1], np.eye(4), atol=1e-12), "odom -> base_link is identity at the first frame")
    odom_steps = [np.linalg.norm((np.linalg.inv(odom[k - 1][1]) @ odom[k][1])[:2, 3]) for k in range(1, FRAMES)]
    check(np.allclose(odom_steps, 1.03 * np.array(steps), rtol=1e-9, atol=1e-12), "3 % scale error per step")
    for k in range(FRAMES):
        drift = T2B.wrap(yaw(odom[k][1]) - yaw(rel[k]))
        check(abs(drift - math.radians(1.0) * travelled[k]) < 1e-9, "yaw drift at %d: %g" % (k, drift))
        check(abs(odom[k][1][2, 3]) < 1e-12 and abs(odom[k][1][2, 2] - 1) < 1e-12, "odometry planar")
    # Its error grows as the parameters say: position error ~ 3 % of the distance plus the drift's share.
    err = np.linalg.norm(odom[-1][1][:2, 3] - rel[-1][:2, 3])
    check(err > 0.02 * travelled[-1], "odometry drifts (%.4f m over %.3f m)" % (err, travelled[-1]))

    # Without errors odometry is the true base motion, also sampled at 90 Hz.
    msgs = convert(seq, os.path.join(work, "exact.bag"), "--robot", "--time-offset", "1000",
                   "--odom-scale-error", "0", "--odom-yaw-drift", "0", "--odom-rate", "90")
    odom = odometry(msgs)
    check(len(odom) == 3 * (FRAMES - 1) + 1, "90 Hz odometry over the 30 Hz frames: %d" % len(odom))
    check(abs(odom[-1][0] - stamps[-1]) < 1e-6, "odometry reaches the last image")
    for k in range(FRAMES):
        o = odom[3 * k]
        check(abs(o[0] - stamps[k]) < 1e-6, "90 Hz samples include every image stamp")
        # (odometry runs on its own 1/90 s clock; the image stamps are rounded
        # to microseconds: up to 1 us apart, 1e-6 m at this speed)
        check(np.allclose(o[1], rel[k], atol=1e-6), "exact odometry %d" % k)
    # A drift per second adds to the yaw with time.
    odom = odometry(convert(seq, os.path.join(work, "rate.bag"), "--robot", "--time-offset", "1000",
                            "--odom-scale-error", "0", "--odom-yaw-drift", "0", "--odom-yaw-drift-rate", "2"))
    for k in range(FRAMES):
        drift = T2B.wrap(yaw(odom[k][1]) - yaw(rel[k]))
        check(abs(drift - math.radians(2.0) * (stamps[k] - stamps[0])) < 1e-9, "yaw rate drift %d" % k)
    # Renamed frames and a rate below the camera's are honoured / refused.
    msgs = convert(seq, os.path.join(work, "names.bag"), "--robot", "--no-tf", "--base-frame", "robot",
                   "--odom-frame", "wheels", "--camera-frame", "cam", "--optical-frame", "cam_optical")
    frames = {(tr.header.frame_id, tr.child_frame_id) for topic in ("/tf", "/tf_static")
              for msg, _, _ in msgs[topic] for tr in msg.transforms}
    check(frames == {("wheels", "robot"), ("robot", "cam"), ("cam", "cam_optical")}, "renamed %s" % frames)
    check(msgs["/camera/image_raw"][0][0].header.frame_id == "cam_optical", "renamed optical frame")
    rc, _ = run([sys.executable, ARGS.script, seq, os.path.join(work, "slow.bag"), "--robot", "--odom-rate", "10"])
    check(rc != 0, "an odometry rate below the camera's is refused")


def decode(data):
    from PIL import Image as PILImage
    return np.array(PILImage.open(io.BytesIO(bytes(data))))


def test_compressed(seq, mono_seq, work):
    rgb = T2B.read_list(os.path.join(seq, "rgb.txt"))
    for fmt, extra in (("png", ["--compressed", "png"]), ("jpeg", ["--compressed"])):
        msgs = convert(seq, os.path.join(work, "c_%s.bag" % fmt), "--robot", *extra)
        check("/camera/image_raw" not in msgs, "compressed bags carry no raw images")
        comp = msgs["/camera/image_raw/compressed"]
        check(len(comp) == FRAMES and len(msgs["/camera/camera_info"]) == FRAMES, "compressed counts")
        check(comp[0][2]["type"] == "sensor_msgs/CompressedImage"
              and comp[0][2]["md5sum"] == T2B.COMPRESSED_IMAGE_MD5, "CompressedImage type")
        worst = 0.0
        for k, (msg, _, _) in enumerate(comp):
            check(msg.format == "rgb8; %s compressed bgr8" % fmt, "format %r" % msg.format)
            check(msg.header.frame_id == "camera_color_optical_frame", "compressed frame id")
            ref = T2B.read_png(os.path.join(seq, rgb[k][1])).astype(float)
            got = decode(msg.data).astype(float)
            check(got.shape == ref.shape, "decoded shape")
            if fmt == "png":
                check(np.array_equal(got, ref), "png is lossless (frame %d)" % k)
            else:
                # Quality 80 (image_transport's default) with 4:2:0 chroma on
                # 64 x 48 textured frames: about 5.4 levels mean error, 30.5 dB.
                # Bounds that a wrong decode fails: channel means within 1.5
                # levels (0.5 measured; swapping R and B moves them by 8.7 or
                # more), and well below the error of a one-pixel shift (0.67 of
                # it measured, so < 0.8).
                mse = np.mean((got - ref) ** 2)
                worst = max(worst, mse)
                means = np.abs(got.mean(axis=(0, 1)) - ref.mean(axis=(0, 1))).max()
                check(means < 1.5, "jpeg frame %d: channel means differ by %.2f" % (k, means))
                aligned = np.mean(np.abs(got - ref))
                for shifted in (np.mean(np.abs(got[:, 1:] - ref[:, :-1])), np.mean(np.abs(got[1:] - ref[:-1]))):
                    check(aligned < 0.8 * shifted, "jpeg frame %d: %.2f vs %.2f shifted" % (k, aligned, shifted))
        if fmt == "jpeg":
            check(10 * math.log10(255 ** 2 / worst) > 28.0, "jpeg PSNR %.1f dB" % (10 * math.log10(255 ** 2 / worst)))
    # Grey sequences: mono8 in raw and compressed bags.
    msgs = convert(mono_seq, os.path.join(work, "mono.bag"))
    check(msgs["/camera/image_raw"][0][0].encoding == "mono8", "mono8 image")
    msgs = convert(mono_seq, os.path.join(work, "mono_c.bag"), "--compressed")
    msg = msgs["/camera/image_raw/compressed"][0][0]
    check(msg.format == "mono8; jpeg compressed mono8", "mono format %r" % msg.format)
    check(decode(msg.data).ndim == 2, "mono jpeg decodes to one channel")


def main():
    global ARGS, T2B
    ap = argparse.ArgumentParser()
    ap.add_argument("--synth", required=True)
    ap.add_argument("--script", required=True)
    ap.add_argument("--workdir", required=True)
    ARGS = ap.parse_args()
    T2B = load_script(ARGS.script, "tum_to_bag")

    work = fresh_dir(ARGS.workdir)
    seq, mono = os.path.join(work, "robot"), os.path.join(work, "mono")
    common = ["--frames", str(FRAMES), "--width", "64", "--height", "48", "--quiet"]
    run([ARGS.synth, "--out", seq, "--seed", "3", "--trajectory", "robot", "--distortion"] + LENS + common,
        check=True)
    run([ARGS.synth, "--out", mono, "--seed", "4", "--mono", "--read-noise", "1", "--frames", "3",
         "--width", "64", "--height", "48", "--quiet"], check=True)
    msgs = test_tree_and_camera(seq, work)
    test_odometry(seq, work, msgs)
    test_compressed(seq, mono, work)
    print("3 passed, 0 failed")


if __name__ == "__main__":
    main()
