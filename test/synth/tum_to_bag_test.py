#!/usr/bin/env python3
"""Bag route test: long3r_synth writes a 5-frame sequence, scripts/tum_to_bag.py
converts it, and python rosbag reads it back (registered in synth.cmake)."""

import argparse
import os
import struct
import sys
import zlib

import numpy as np
import rosbag

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import check, fail, fresh_dir, load_script, run  # noqa: E402


def encode_png(arr, filters):
    """Minimal PNG writer using the given filter type per row (for decoder tests)."""
    h, w = arr.shape[:2]
    c = 1 if arr.ndim == 2 else arr.shape[2]
    depth = 16 if arr.dtype == np.uint16 else 8
    raw_rows = [(arr[y].astype(">u2") if depth == 16 else arr[y]).tobytes() for y in range(h)]
    bpp = c * depth // 8
    out, prev = b"", bytes(len(raw_rows[0]))
    for y, row in enumerate(raw_rows):
        f = filters[y % len(filters)]
        enc = bytearray(len(row))
        for i in range(len(row)):
            a = row[i - bpp] if i >= bpp else 0
            b = prev[i]
            cc = prev[i - bpp] if i >= bpp else 0
            if f == 0:
                pred = 0
            elif f == 1:
                pred = a
            elif f == 2:
                pred = b
            elif f == 3:
                pred = (a + b) >> 1
            else:
                p = a + b - cc
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - cc)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else cc)
            enc[i] = (row[i] - pred) & 0xFF
        out += bytes([f]) + bytes(enc)
        prev = row

    def chunk(t, body):
        return struct.pack(">I", len(body)) + t + body + struct.pack(">I", zlib.crc32(t + body) & 0xFFFFFFFF)

    colour = {1: 0, 3: 2, 4: 6}[c]
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(out)) + chunk(b"IEND", b""))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--synth", required=True)
    ap.add_argument("--script", required=True)
    ap.add_argument("--workdir", required=True)
    args = ap.parse_args()

    t2b = load_script(args.script, "tum_to_bag")

    # The built-in PNG decoder against every filter type, 8-bit RGB and 16-bit grey.
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, size=(7, 9, 3), dtype=np.uint8)
    grey16 = rng.integers(0, 65536, size=(5, 6), dtype=np.uint16)
    check(np.array_equal(t2b.decode_png_builtin(encode_png(rgb, [0, 1, 2, 3, 4])), rgb), "PNG rgb decode")
    check(np.array_equal(t2b.decode_png_builtin(encode_png(grey16, [4, 3, 2, 1, 0])), grey16), "PNG 16-bit decode")

    fresh_dir(args.workdir)
    seq = os.path.join(args.workdir, "seq")
    bag_path = os.path.join(args.workdir, "seq.bag")
    run([args.synth, "--out", seq, "--frames", "5", "--width", "64", "--height", "48",
         "--seed", "3", "--quiet"], check=True)
    # long3r_synth stamps its first frame 0 ("no time" in ROS): without an
    # offset the bag starts at 1000 s, and every frame is kept.
    run([sys.executable, args.script, seq, bag_path, "--depth-topic", "/camera/depth"], check=True)
    offset = t2b.AUTO_START_S
    check(t2b.resolve_time_offset(None, 1305031102.175) == 0.0, "positive stamps are kept")
    check(t2b.resolve_time_offset(2.5, 0.0) == 2.5, "an explicit offset is kept")
    rc, out = run([sys.executable, args.script, seq, os.path.join(args.workdir, "zero.bag"),
                   "--time-offset", "0"])
    check(rc != 0 and "must be > 0" in out, "a first frame at 0 refused: %s" % out)
    check(not os.path.exists(os.path.join(args.workdir, "zero.bag")), "no bag written when refused")

    rgb_list = t2b.read_list(os.path.join(seq, "rgb.txt"))
    gt = t2b.read_trajectory(os.path.join(seq, "groundtruth.txt"))
    calib = t2b.read_calibration(os.path.join(seq, "calibration.txt"))
    (fx, fy, cx, cy), size = calib.K, calib.size
    check(size == (64, 48) and calib.model == "" and calib.D == [], "calibration %s" % (calib,))
    # calibration.txt with a lens (as long3r_synth --distortion writes it), and bad ones.
    lens_file = os.path.join(args.workdir, "lens.txt")
    with open(lens_file, "w") as f:
        f.write("# c\n500 501 31.5 23.5 64 48 plumb_bob -0.28 0.0912345678901234 0.00015 -7e-05 0\n")
    lens = t2b.read_calibration(lens_file)
    check(lens.K == (500.0, 501.0, 31.5, 23.5) and lens.size == (64, 48), "lens K")
    check(lens.model == "plumb_bob" and lens.D == [-0.28, 0.0912345678901234, 0.00015, -7e-05, 0.0], "lens D")
    for bad in ("500 501 31.5 23.5 64 48 plumb_bob 0.1 0 0 0\n", "500 501 31.5 23.5 64 48 fisheye 0 0 0 0\n",
                "500 501 31.5 23.5 64\n"):
        with open(lens_file, "w") as f:
            f.write(bad)
        try:
            t2b.read_calibration(lens_file)
            fail("accepted " + bad)
        except ValueError:
            pass

    with rosbag.Bag(bag_path) as bag:
        info = bag.get_type_and_topic_info()
        topics = info.topics
        expected = {"/camera/image_raw": "sensor_msgs/Image", "/camera/camera_info": "sensor_msgs/CameraInfo",
                    "/tf": "tf2_msgs/TFMessage", "/camera/depth": "sensor_msgs/Image"}
        for topic, msg_type in expected.items():
            check(topic in topics, "missing topic " + topic)
            check(topics[topic].msg_type == msg_type, "type of " + topic)
            check(topics[topic].message_count == 5, "count on %s: %d" % (topic, topics[topic].message_count))
        md5 = {"sensor_msgs/Image": t2b.IMAGE_MD5, "sensor_msgs/CameraInfo": t2b.CAMERA_INFO_MD5,
               "tf2_msgs/TFMessage": t2b.TF_MESSAGE_MD5}
        for msg_type, h in info.msg_types.items():
            check(md5[msg_type] == h, "md5 of " + msg_type)

        images = [m for _, m, _ in bag.read_messages(topics=["/camera/image_raw"])]
        infos = [m for _, m, _ in bag.read_messages(topics=["/camera/camera_info"])]
        tfs = [m for _, m, _ in bag.read_messages(topics=["/tf"])]
        depths = [m for _, m, _ in bag.read_messages(topics=["/camera/depth"])]

    for i in range(5):
        stamp = rgb_list[i][0]
        img, ci, tf, dm = images[i], infos[i], tfs[i], depths[i]
        check(img.header.stamp.to_sec() > 0.0, "image %d stamped 0" % i)
        check(abs(img.header.stamp.to_sec() - (stamp + offset)) < 1e-6, "image stamp %d" % i)
        check(img.header.frame_id == "camera", "frame_id")
        check((img.width, img.height, img.encoding, img.step) == (64, 48, "rgb8", 192), "image layout")
        pixels = np.frombuffer(img.data, np.uint8).reshape(48, 64, 3)
        png = t2b.read_png(os.path.join(seq, rgb_list[i][1]))
        check(np.array_equal(pixels, png), "pixels %d" % i)
        check(pixels.std() > 5.0, "image %d looks blank" % i)
        check(abs(ci.header.stamp.to_sec() - (stamp + offset)) < 1e-6, "camera info stamp")
        check(list(ci.K) == [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0], "K")
        check(ci.distortion_model == "plumb_bob" and list(ci.D) == [0.0] * 5, "no distortion")
        check((ci.width, ci.height) == (64, 48), "camera info size")
        check(len(tf.transforms) == 1, "one transform")
        ts = tf.transforms[0]
        check(ts.header.frame_id == "map" and ts.child_frame_id == "gt_camera", "tf frames")
        _, t, q = gt[i]
        got_t = (ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z)
        got_q = (ts.transform.rotation.x, ts.transform.rotation.y, ts.transform.rotation.z, ts.transform.rotation.w)
        check(np.allclose(got_t, t, atol=1e-12) and np.allclose(got_q, q, atol=1e-12), "tf pose %d" % i)
        check(dm.encoding == "32FC1", "depth encoding")
        z = np.frombuffer(dm.data, "<f4")
        check(z.size == 64 * 48 and z.min() > 0.25 and z.max() < 15.0, "depth range %d" % i)
    print("5 passed, 0 failed")


if __name__ == "__main__":
    main()
