#!/usr/bin/env python3
"""Converts a TUM RGB-D style folder (as written by long3r_synth) into a ROS 1 bag.

Topics (defaults):
  /camera/image_raw     sensor_msgs/Image, rgb8
  /camera/camera_info   sensor_msgs/CameraInfo from calibration.txt (or --calib)
  /tf                   tf2_msgs/TFMessage: ground truth T_W_C as map -> gt_camera
  (optional) --depth-topic: sensor_msgs/Image 32FC1 in metres

Runs with Debian's /usr/bin/python3 and python3-rosbag; needs no ROS workspace:
message classes come from the installed Python packages when present, otherwise
they are generated from the .msg definitions under /usr/share (ros-*-msgs).
PNGs are decoded with OpenCV or Pillow when available, else by a small
built-in decoder (8/16-bit grey, RGB, RGBA; not interlaced).
"""

import argparse
import bisect
import glob
import os
import struct
import sys
import zlib

import numpy as np

import genpy
import rosbag

IMAGE_MD5 = "060021388200f6f0f447d0fcd9c64743"
CAMERA_INFO_MD5 = "c9a58c1b0b154e0e6da7578cb991d214"
TF_MESSAGE_MD5 = "94810edda583a504dfda3829e70d7eec"


# --------------------------------------------------------------------------- messages

def _msg_search_path():
    roots = [p for p in os.environ.get("ROS_PACKAGE_PATH", "").split(":") if p]
    roots += sorted(glob.glob("/opt/ros/*/share")) + ["/usr/share"]
    path = {}
    for pkg in ("std_msgs", "geometry_msgs", "sensor_msgs", "tf2_msgs"):
        for root in roots:
            d = os.path.join(root, pkg, "msg")
            if os.path.isdir(d):
                path.setdefault(pkg, []).append(d)
    return path


def load_message_classes():
    """Returns (Image, CameraInfo, TFMessage, TransformStamped) classes."""
    try:
        from sensor_msgs.msg import CameraInfo, Image
        from tf2_msgs.msg import TFMessage
        from geometry_msgs.msg import TransformStamped
        return Image, CameraInfo, TFMessage, TransformStamped
    except ImportError:
        pass
    import genmsg
    import genmsg.msg_loader
    import genpy.dynamic

    ctx = genmsg.MsgContext.create_default()
    path = _msg_search_path()

    def build(type_name, text=None):
        if text is None:
            spec = genmsg.msg_loader.load_msg_by_type(ctx, type_name, path)
        else:
            spec = genmsg.msg_loader.load_msg_from_string(ctx, text, type_name)
        genmsg.msg_loader.load_depends(ctx, spec, path)
        return genpy.dynamic.generate_dynamic(type_name, genmsg.compute_full_text(ctx, spec))

    image = build("sensor_msgs/Image")["sensor_msgs/Image"]
    info = build("sensor_msgs/CameraInfo")["sensor_msgs/CameraInfo"]
    if "tf2_msgs" in path:
        tf = build("tf2_msgs/TFMessage")
    else:  # its one-line definition, when the .msg file is not installed
        tf = build("tf2_msgs/TFMessage", "geometry_msgs/TransformStamped[] transforms\n")
    classes = (image, info, tf["tf2_msgs/TFMessage"], tf["geometry_msgs/TransformStamped"])
    for cls, md5 in zip(classes[:3], (IMAGE_MD5, CAMERA_INFO_MD5, TF_MESSAGE_MD5)):
        if cls._md5sum != md5:
            raise RuntimeError("%s definition differs from the standard one (md5 %s)" % (cls._type, cls._md5sum))
    return classes


# --------------------------------------------------------------------------- PNG

def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    return b if pb <= pc else c


def decode_png_builtin(data):
    """Decodes PNG bytes to a numpy array (H, W) or (H, W, C); uint8 or uint16."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG file")
    pos, idat, header = 8, [], None
    while pos < len(data):
        length, ctype = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        pos += 12 + length
        if ctype == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif ctype == b"IDAT":
            idat.append(body)
        elif ctype == b"IEND":
            break
    if header is None:
        raise ValueError("PNG without IHDR")
    width, height, depth, colour, _, _, interlace = header
    channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(colour)
    if channels is None or depth not in (8, 16) or interlace != 0:
        raise ValueError("unsupported PNG (colour type %d, depth %d, interlace %d)" % (colour, depth, interlace))
    bpp = channels * depth // 8
    stride = width * bpp
    raw = zlib.decompress(b"".join(idat))
    if len(raw) != height * (stride + 1):
        raise ValueError("PNG data size mismatch")
    out = bytearray(height * stride)
    prev = bytearray(stride)
    for y in range(height):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        if f == 1:
            for i in range(bpp, stride):
                line[i] = (line[i] + line[i - bpp]) & 0xFF
        elif f == 2:
            line = bytearray((np.frombuffer(line, np.uint8) + np.frombuffer(prev, np.uint8)).tobytes())
        elif f == 3:
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + ((left + prev[i]) >> 1)) & 0xFF
        elif f == 4:
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                upleft = prev[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + _paeth(left, prev[i], upleft)) & 0xFF
        elif f != 0:
            raise ValueError("bad PNG filter %d" % f)
        out[y * stride:(y + 1) * stride] = line
        prev = line
    arr = np.frombuffer(bytes(out), dtype=">u2" if depth == 16 else np.uint8)
    arr = arr.astype(np.uint16) if depth == 16 else arr
    return arr.reshape((height, width, channels)) if channels > 1 else arr.reshape((height, width))


def read_png(path):
    """Image as numpy, colour in RGB(A) order."""
    try:
        import cv2
        img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError("cannot read " + path)
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
        return img
    except ImportError:
        pass
    try:
        from PIL import Image as PILImage
        return np.array(PILImage.open(path))
    except ImportError:
        pass
    with open(path, "rb") as f:
        return decode_png_builtin(f.read())


# --------------------------------------------------------------------------- TUM

def read_list(path):
    """rgb.txt / depth.txt -> [(stamp, path)]."""
    out = []
    with open(path) as f:
        for line in f:
            line = line.split("#", 1)[0].replace(",", " ").split()
            if line:
                out.append((float(line[0]), line[1]))
    return out


def read_trajectory(path):
    """groundtruth.txt -> sorted [(stamp, (tx, ty, tz), (qx, qy, qz, qw))]."""
    out = []
    with open(path) as f:
        for line in f:
            v = line.split("#", 1)[0].replace(",", " ").split()
            if not v:
                continue
            if len(v) != 8:
                raise ValueError("%s: expected 8 values, got %d" % (path, len(v)))
            v = [float(x) for x in v]
            out.append((v[0], tuple(v[1:4]), tuple(v[4:8])))
    out.sort(key=lambda e: e[0])
    return out


def read_calibration(path):
    with open(path) as f:
        for line in f:
            v = line.split("#", 1)[0].split()
            if v:
                vals = [float(x) for x in v]
                return vals[:4], (int(vals[4]), int(vals[5])) if len(vals) >= 6 else None
    raise ValueError(path + ": no calibration line")


def nearest(stamps, t, max_diff):
    i = bisect.bisect_left(stamps, t)
    best = None
    for j in (i - 1, i):
        if 0 <= j < len(stamps) and (best is None or abs(stamps[j] - t) < abs(stamps[best] - t)):
            best = j
    return best if best is not None and abs(stamps[best] - t) <= max_diff else None


def associate(a, b, max_diff):
    """TUM associate.py: closest pairs first, each used once, |dt| < max_diff."""
    order = sorted(range(len(b)), key=lambda j: b[j])
    bs = [b[j] for j in order]
    cand = []
    for i, ta in enumerate(a):
        k = bisect.bisect_left(bs, ta - max_diff)
        while k < len(bs) and bs[k] <= ta + max_diff:
            if abs(ta - bs[k]) < max_diff:
                cand.append((abs(ta - bs[k]), ta, bs[k], i, order[k]))
            k += 1
    cand.sort()
    used_a, used_b, out = set(), set(), {}
    for _, _, _, i, j in cand:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            out[i] = j
    return out


# --------------------------------------------------------------------------- main

def convert(args):
    Image, CameraInfo, TFMessage, TransformStamped = load_message_classes()
    root = args.tum_dir
    rgb = read_list(os.path.join(root, "rgb.txt"))
    if args.calib:
        intr, size = [float(x) for x in args.calib.split()], None
        if len(intr) != 4:
            raise ValueError("--calib needs 'fx fy cx cy'")
    else:
        intr, size = read_calibration(os.path.join(root, "calibration.txt"))
    gt = []
    gt_path = os.path.join(root, "groundtruth.txt")
    if not args.no_tf and os.path.exists(gt_path):
        gt = read_trajectory(gt_path)
    gt_stamps = [g[0] for g in gt]
    depth, depth_of = [], {}
    if args.depth_topic:
        depth = read_list(os.path.join(root, "depth.txt"))
        depth_of = associate([r[0] for r in rgb], [d[0] for d in depth], args.max_diff)

    frames = rgb[args.start:]
    if args.max_frames > 0:
        frames = frames[:args.max_frames]
    fx, fy, cx, cy = intr
    counts = {"image": 0, "info": 0, "tf": 0, "depth": 0}
    with rosbag.Bag(args.output, "w", compression=args.compression) as bag:
        for k, (stamp, rel) in enumerate(frames):
            index = args.start + k
            t = genpy.Time.from_sec(stamp + args.time_offset)
            img = read_png(os.path.join(root, rel))
            if img.ndim == 3 and img.shape[2] == 4:
                img = img[:, :, :3]
            if img.dtype != np.uint8:
                raise ValueError("%s: expected an 8-bit colour image" % rel)
            msg = Image()
            msg.header.stamp = t
            msg.header.seq = k
            msg.header.frame_id = args.frame_id
            msg.height, msg.width = img.shape[0], img.shape[1]
            msg.encoding = "rgb8" if img.ndim == 3 else "mono8"
            msg.is_bigendian = 0
            msg.step = msg.width * (3 if img.ndim == 3 else 1)
            msg.data = np.ascontiguousarray(img).tobytes()
            bag.write(args.image_topic, msg, t)
            counts["image"] += 1

            info = CameraInfo()
            info.header = msg.header
            info.height, info.width = (size[1], size[0]) if size else (msg.height, msg.width)
            info.distortion_model = "plumb_bob"
            info.D = [0.0] * 5
            info.K = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
            info.R = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
            info.P = [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
            bag.write(args.info_topic, info, t)
            counts["info"] += 1

            if index in depth_of:
                d = read_png(os.path.join(root, depth[depth_of[index]][1]))
                if d.ndim != 2:
                    raise ValueError("depth image is not single-channel")
                metres = (d.astype(np.float32) / np.float32(args.depth_factor)).astype("<f4")
                dm = Image()
                dm.header = msg.header
                dm.height, dm.width = metres.shape
                dm.encoding = "32FC1"
                dm.is_bigendian = 0
                dm.step = dm.width * 4
                dm.data = metres.tobytes()
                bag.write(args.depth_topic, dm, t)
                counts["depth"] += 1

            g = nearest(gt_stamps, stamp, args.max_diff) if gt else None
            if g is not None:
                _, (tx, ty, tz), (qx, qy, qz, qw) = gt[g]
                ts = TransformStamped()
                ts.header.stamp = t
                ts.header.frame_id = args.tf_parent
                ts.child_frame_id = args.tf_child
                ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z = tx, ty, tz
                ts.transform.rotation.x, ts.transform.rotation.y = qx, qy
                ts.transform.rotation.z, ts.transform.rotation.w = qz, qw
                bag.write("/tf", TFMessage(transforms=[ts]), t)
                counts["tf"] += 1
    return counts


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("tum_dir", help="folder with rgb.txt, rgb/, calibration.txt, groundtruth.txt")
    p.add_argument("output", help="bag file to write")
    p.add_argument("--image-topic", default="/camera/image_raw")
    p.add_argument("--info-topic", default="/camera/camera_info")
    p.add_argument("--depth-topic", default="", help="also write depth (32FC1, metres) on this topic")
    p.add_argument("--frame-id", default="camera", help="header.frame_id of images and camera info")
    p.add_argument("--tf-parent", default="map", help="world frame of the ground-truth transform")
    p.add_argument("--tf-child", default="gt_camera", help="camera frame of the ground-truth transform")
    p.add_argument("--no-tf", action="store_true", help="do not write the ground truth on /tf")
    p.add_argument("--calib", default="", help="'fx fy cx cy' when there is no calibration.txt")
    p.add_argument("--depth-factor", type=float, default=5000.0, help="depth PNG value per metre")
    p.add_argument("--max-diff", type=float, default=0.02, help="timestamp association tolerance (s)")
    p.add_argument("--time-offset", type=float, default=0.0, help="added to every stamp (s)")
    p.add_argument("--start", type=int, default=0, help="first frame")
    p.add_argument("--max-frames", type=int, default=0, help="at most this many frames (0: all)")
    p.add_argument("--compression", default="none", choices=["none", "bz2", "lz4"])
    args = p.parse_args(argv)
    counts = convert(args)
    print("wrote %s: %d images, %d camera infos, %d depth images, %d tf messages"
          % (args.output, counts["image"], counts["info"], counts["depth"], counts["tf"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
