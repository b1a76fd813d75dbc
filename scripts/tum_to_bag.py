#!/usr/bin/env python3
"""Converts a TUM RGB-D style folder (as written by long3r_synth) into a ROS 1 bag.

Topics (defaults):
  /camera/image_raw     sensor_msgs/Image, rgb8 (mono8 for grey PNGs)
  /camera/camera_info   sensor_msgs/CameraInfo from calibration.txt (or --calib):
                        K of the image, D and distortion_model (plumb_bob, zeros
                        when calibration.txt has none), R = I, P = [K | 0]
  /tf                   tf2_msgs/TFMessage: ground truth T_W_C as map -> gt_camera
  (optional) --depth-topic: sensor_msgs/Image 32FC1 in metres
  (optional) --compressed [jpeg|png]: the images as sensor_msgs/CompressedImage on
                        <image-topic>/compressed instead, with the format string
                        compressed_image_transport writes ("rgb8; jpeg compressed
                        bgr8", "mono8; png compressed mono8", ...); quality
                        --jpeg-quality (80, image_transport's default). Needs Pillow.

--robot (a sequence made with `long3r_synth --trajectory robot`, which writes
base_groundtruth.txt and camera_mount.txt) writes what a robot records instead
of the camera's ground truth:
  /tf_static  one TFMessage, latched (connection header latching=1, as rosbag
              record stores a latched topic, so rosbag play latches it again):
              base_link -> camera_link     the mount (camera_link: x forward,
                                           y left, z up)
              camera_link -> camera_color_optical_frame   rpy (-pi/2, 0, -pi/2)
  /tf         odom -> base_link at every frame (or at --odom-rate Hz), wheel
              odometry: the true base motion between samples, (dx, dy, dyaw) in
              the previous base frame, becomes ((1 + s) dx, (1 + s) dy,
              dyaw + a * dist + b * dt) with s = --odom-scale-error (0.03),
              a = --odom-yaw-drift deg/m (1.0), b = --odom-yaw-drift-rate deg/s
              (0.0), dist the true distance of the step; odom is the base pose
              at the first frame (identity there), so T_W_odom = T_W_B(t0).
  /odom       nav_msgs/Odometry with each odom -> base_link sample, as a base
              driver publishes it: the same pose, the twist in base_link, and a
              diagonal pose covariance that grows with the distance d driven:
              position std 0.005 m + max(|s|, 0.01) d (x, y), yaw std
              0.002 rad + max(|a|, 0.1 deg/m) d, z, roll and pitch 1e-3 (planar).
              Ground truth goes under its own root, gt_world -> gt_base_link
              (T_W_B; --tf-parent, --tf-child; --no-tf leaves it out), never
              under a frame the node publishes.
  Images, camera info and depth carry header.frame_id camera_color_optical_frame.
Frame names: --base-frame, --camera-frame, --optical-frame, --odom-frame.

Runs with Debian's /usr/bin/python3 and python3-rosbag; needs no ROS workspace:
message classes come from the installed Python packages when present, otherwise
they are generated from the .msg definitions under /usr/share (ros-*-msgs).
PNGs are decoded with OpenCV or Pillow when available, else by a small
built-in decoder (8/16-bit grey, RGB, RGBA; not interlaced).
"""

import argparse
import bisect
import collections
import glob
import io
import math
import os
import struct
import sys
import types
import zlib

import numpy as np

import genpy
import rosbag

IMAGE_MD5 = "060021388200f6f0f447d0fcd9c64743"
CAMERA_INFO_MD5 = "c9a58c1b0b154e0e6da7578cb991d214"
COMPRESSED_IMAGE_MD5 = "8f7a12909da2c9d3332d540a0977563f"
TF_MESSAGE_MD5 = "94810edda583a504dfda3829e70d7eec"
ODOMETRY_MD5 = "cd5e73d190d741a2f92e81eda573aca7"


# --------------------------------------------------------------------------- messages

def _msg_search_path():
    roots = [p for p in os.environ.get("ROS_PACKAGE_PATH", "").split(":") if p]
    roots += sorted(glob.glob("/opt/ros/*/share")) + ["/usr/share"]
    path = {}
    for pkg in ("std_msgs", "geometry_msgs", "sensor_msgs", "tf2_msgs", "nav_msgs"):
        for root in roots:
            d = os.path.join(root, pkg, "msg")
            if os.path.isdir(d):
                path.setdefault(pkg, []).append(d)
    return path


def load_message_classes():
    """Namespace of the classes Image, CameraInfo, CompressedImage, TFMessage, TransformStamped,
    Odometry (None when nav_msgs is not installed: --robot needs it)."""
    try:
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image
        from tf2_msgs.msg import TFMessage
        from geometry_msgs.msg import TransformStamped
        from nav_msgs.msg import Odometry
        return types.SimpleNamespace(Image=Image, CameraInfo=CameraInfo, CompressedImage=CompressedImage,
                                     TFMessage=TFMessage, TransformStamped=TransformStamped, Odometry=Odometry)
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

    if "tf2_msgs" in path:
        tf = build("tf2_msgs/TFMessage")
    else:  # its one-line definition, when the .msg file is not installed
        tf = build("tf2_msgs/TFMessage", "geometry_msgs/TransformStamped[] transforms\n")
    classes = types.SimpleNamespace(
        Image=build("sensor_msgs/Image")["sensor_msgs/Image"],
        CameraInfo=build("sensor_msgs/CameraInfo")["sensor_msgs/CameraInfo"],
        CompressedImage=build("sensor_msgs/CompressedImage")["sensor_msgs/CompressedImage"],
        TFMessage=tf["tf2_msgs/TFMessage"], TransformStamped=tf["geometry_msgs/TransformStamped"],
        Odometry=build("nav_msgs/Odometry")["nav_msgs/Odometry"] if "nav_msgs" in path else None)
    checks = [(classes.Image, IMAGE_MD5), (classes.CameraInfo, CAMERA_INFO_MD5),
              (classes.CompressedImage, COMPRESSED_IMAGE_MD5), (classes.TFMessage, TF_MESSAGE_MD5)]
    if classes.Odometry is not None:
        checks.append((classes.Odometry, ODOMETRY_MD5))
    for cls, md5 in checks:
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


def encode_compressed(img, fmt, jpeg_quality):
    """(format, bytes) of an 8-bit RGB or grey image as compressed_image_transport
    publishes it: "<encoding>; <fmt> compressed <bgr8|mono8>", the data decoding
    (cv::imdecode) to that target."""
    try:
        from PIL import Image as PILImage
    except ImportError:
        raise RuntimeError("--compressed needs Pillow (Debian: python3-pil)")
    colour = img.ndim == 3
    buf = io.BytesIO()
    pil = PILImage.fromarray(np.ascontiguousarray(img), "RGB" if colour else "L")
    if fmt == "jpeg":
        pil.save(buf, "JPEG", quality=jpeg_quality)
    else:
        pil.save(buf, "PNG")
    encoding, target = ("rgb8", "bgr8") if colour else ("mono8", "mono8")
    return "%s; %s compressed %s" % (encoding, fmt, target), buf.getvalue()


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


Calibration = collections.namedtuple("Calibration", "K size model D")
DISTORTION_COEFFICIENTS = {"plumb_bob": 5, "rational_polynomial": 8, "equidistant": 4}


def read_calibration(path):
    """calibration.txt -> Calibration: K = (fx, fy, cx, cy), size = (w, h) or None,
    model = "" or the distortion model, D = its coefficients ([] without)."""
    with open(path) as f:
        for line in f:
            v = line.split("#", 1)[0].split()
            if not v:
                continue
            if len(v) not in (4, 6) and len(v) < 7:
                raise ValueError("%s: expected 'fx fy cx cy [width height [model D...]]'" % path)
            K = tuple(float(x) for x in v[:4])
            size = (int(v[4]), int(v[5])) if len(v) >= 6 else None
            model, D = "", []
            if len(v) > 6:
                model = v[6]
                if model not in DISTORTION_COEFFICIENTS:
                    raise ValueError("%s: unknown distortion model %s" % (path, model))
                D = [float(x) for x in v[7:]]
                if len(D) != DISTORTION_COEFFICIENTS[model]:
                    raise ValueError("%s: %s needs %d coefficients, got %d"
                                     % (path, model, DISTORTION_COEFFICIENTS[model], len(D)))
            return Calibration(K, size, model, D)
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


# --------------------------------------------------------------------------- poses

def quat_to_matrix(q):
    """(qx, qy, qz, qw) -> 3x3 rotation (normalised first)."""
    x, y, z, w = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_to_quat(R):
    """3x3 rotation -> (qx, qy, qz, qw) with qw >= 0."""
    m = np.asarray(R, float)
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = np.array([(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4])
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = np.zeros(4)
        q[i] = s / 4
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
        q[3] = (m[k, j] - m[j, k]) / s
    q /= np.linalg.norm(q)
    return tuple(-q if q[3] < 0 else q)


def pose_matrix(t, q):
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(q)
    T[:3, 3] = t
    return T


def read_pose_file(path):
    """camera_mount.txt: one line 'tx ty tz qx qy qz qw' -> 4x4."""
    rows = []
    with open(path) as f:
        for line in f:
            v = line.split("#", 1)[0].replace(",", " ").split()
            if v:
                rows.append([float(x) for x in v])
    if len(rows) != 1 or len(rows[0]) != 7:
        raise ValueError("%s: expected one line 'tx ty tz qx qy qz qw'" % path)
    return pose_matrix(rows[0][:3], rows[0][3:])


# camera_link (x forward, y left, z up) -> optical (x right, y down, z forward): rpy (-pi/2, 0, -pi/2).
LINK_TO_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0, 0, 0, 1.0]])


def planar(T, what):
    """4x4 on the floor, yaw only -> (x, y, yaw); refuses anything else."""
    if abs(T[2, 3]) > 1e-6 or abs(T[2, 2] - 1.0) > 1e-9:
        raise ValueError("%s is not planar (z = %g, R_zz = %g)" % (what, T[2, 3], T[2, 2]))
    return T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def interpolate_planar(stamps, poses, t):
    """(x, y, yaw) at t, linear between the samples around it (yaw the short way)."""
    if len(stamps) == 1 or t <= stamps[0]:
        return poses[0]
    if t >= stamps[-1]:
        return poses[-1]
    i = bisect.bisect_right(stamps, t) - 1
    f = (t - stamps[i]) / (stamps[i + 1] - stamps[i])
    (x0, y0, a0), (x1, y1, a1) = poses[i], poses[i + 1]
    return x0 + f * (x1 - x0), y0 + f * (y1 - y0), a0 + f * wrap(a1 - a0)


def wheel_odometry(stamps, base, scale_error, yaw_drift_deg_per_m, yaw_drift_deg_per_s):
    """Odometry (x, y, yaw) of the base in the odom frame (the base at stamps[0])
    from its true planar poses `base` at `stamps`: each step's true motion
    (dx, dy, dyaw) in the previous base frame is integrated as
    ((1 + s) dx, (1 + s) dy, dyaw + a * dist + b * dt) (see the module docstring)."""
    a, b = math.radians(yaw_drift_deg_per_m), math.radians(yaw_drift_deg_per_s)
    x = y = th = 0.0
    out = [(x, y, th)]
    for k in range(1, len(stamps)):
        (x0, y0, a0), (x1, y1, a1) = base[k - 1], base[k]
        c, s = math.cos(a0), math.sin(a0)
        dx, dy = c * (x1 - x0) + s * (y1 - y0), -s * (x1 - x0) + c * (y1 - y0)
        dist = math.hypot(dx, dy)
        dth = wrap(a1 - a0) + a * dist + b * (stamps[k] - stamps[k - 1])
        dx, dy = (1.0 + scale_error) * dx, (1.0 + scale_error) * dy
        x += math.cos(th) * dx - math.sin(th) * dy
        y += math.sin(th) * dx + math.cos(th) * dy
        th += dth
        out.append((x, y, th))
    return out


def planar_matrix(x, y, yaw):
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3], T[1, 3] = x, y
    return T


# --------------------------------------------------------------------------- main

def transform_msg(classes, stamp, parent, child, t, q):
    """TransformStamped parent -> child: translation t, rotation q = (qx, qy, qz, qw)."""
    ts = classes.TransformStamped()
    ts.header.stamp = stamp
    ts.header.frame_id = parent
    ts.child_frame_id = child
    ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z = (float(v) for v in t)
    ts.transform.rotation.x, ts.transform.rotation.y, ts.transform.rotation.z, ts.transform.rotation.w = (
        float(v) for v in q)
    return ts


def transform_of(classes, stamp, parent, child, T):
    return transform_msg(classes, stamp, parent, child, T[:3, 3], matrix_to_quat(T[:3, :3]))


def latched_header(topic, cls):
    """The connection header rosbag record stores for a latched publisher."""
    return {"topic": topic, "type": cls._type, "md5sum": cls._md5sum, "message_definition": cls._full_text,
            "callerid": "/tum_to_bag", "latching": "1"}


class Robot:
    """What --robot adds: the static tree and the odometry samples."""

    def __init__(self, root, args, frame_stamps):
        for name in ("camera_mount.txt", "base_groundtruth.txt"):
            if not os.path.exists(os.path.join(root, name)):
                raise ValueError("--robot needs %s in %s (long3r_synth --trajectory robot writes it)" % (name, root))
        self.mount = read_pose_file(os.path.join(root, "camera_mount.txt"))  # T_B_C (optical)
        gt = read_trajectory(os.path.join(root, "base_groundtruth.txt"))
        gt_stamps = [g[0] for g in gt]
        gt_planar = [planar(pose_matrix(t, q), "base_groundtruth.txt at %.6f" % s) for s, t, q in gt]
        first, last = frame_stamps[0], frame_stamps[-1]
        if args.odom_rate > 0:
            if len(frame_stamps) > 1:
                camera_rate = 1.0 / float(np.median(np.diff(frame_stamps)))
                if args.odom_rate < camera_rate * (1 - 1e-6):
                    raise ValueError("--odom-rate %g is below the camera's %g Hz" % (args.odom_rate, camera_rate))
            n = int(math.floor((last - first) * args.odom_rate + 1e-9))
            stamps = [first + k / args.odom_rate for k in range(n + 1)]
            if stamps[-1] < last - 1e-9:
                stamps.append(last)  # so that a lookup at the last image needs no extrapolation
        else:
            stamps = list(frame_stamps)
        self.odom_stamps = stamps
        true = [interpolate_planar(gt_stamps, gt_planar, t) for t in stamps]
        self.odom = wheel_odometry(stamps, true, args.odom_scale_error, args.odom_yaw_drift,
                                   args.odom_yaw_drift_rate)

    def odometry_message(self, classes, args, k, stamp):
        """nav_msgs/Odometry of odometry sample k (see the module docstring)."""
        if classes.Odometry is None:
            raise ValueError("--robot needs nav_msgs (ros-nav-msgs) for /odom")
        if not hasattr(self, "_driven"):
            self._driven = [0.0]
            for (x0, y0, _), (x1, y1, _) in zip(self.odom, self.odom[1:]):
                self._driven.append(self._driven[-1] + math.hypot(x1 - x0, y1 - y0))
        d = self._driven[k]
        x, y, yaw = self.odom[k]
        msg = classes.Odometry()
        msg.header.stamp = stamp
        msg.header.frame_id = args.odom_frame
        msg.child_frame_id = args.base_frame
        p = msg.pose.pose
        p.position.x, p.position.y = x, y
        p.orientation.z, p.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
        pos_std = 0.005 + max(abs(args.odom_scale_error), 0.01) * d
        yaw_std = 0.002 + math.radians(max(abs(args.odom_yaw_drift), 0.1)) * d
        cov = [0.0] * 36
        for i, var in enumerate((pos_std ** 2, pos_std ** 2, 1e-6, 1e-6, 1e-6, yaw_std ** 2)):
            cov[7 * i] = var
        msg.pose.covariance = cov
        if k > 0:  # the step's velocity in the base frame
            (x0, y0, a0), dt = self.odom[k - 1], self.odom_stamps[k] - self.odom_stamps[k - 1]
            c, s_ = math.cos(a0), math.sin(a0)
            msg.twist.twist.linear.x = (c * (x - x0) + s_ * (y - y0)) / dt
            msg.twist.twist.linear.y = (-s_ * (x - x0) + c * (y - y0)) / dt
            msg.twist.twist.angular.z = wrap(yaw - a0) / dt
        tcov = [0.0] * 36
        for i, var in enumerate((1e-4, 1e-4, 1e-6, 1e-6, 1e-6, 1e-4)):
            tcov[7 * i] = var
        msg.twist.covariance = tcov
        return msg

    def write_tum(self, path):
        """The odometry as the camera's optical frame in odom (T_odom_B T_B_C),
        a TUM trajectory at the sequence's own stamps: long3r_reconstruct's
        --odometry, the same odometry the bag's /tf carries."""
        with open(path, "w") as f:
            f.write("# wheel odometry: T_odom_C (camera optical frame), tum_to_bag.py --robot\n")
            f.write("# timestamp tx ty tz qx qy qz qw\n")
            for t, (x, y, yaw) in zip(self.odom_stamps, self.odom):
                T = planar_matrix(x, y, yaw) @ self.mount
                q = matrix_to_quat(T[:3, :3])
                f.write("%.6f %s\n" % (t, " ".join("%.9f" % v for v in list(T[:3, 3]) + list(q))))

    def static_message(self, classes, args, stamp):
        base_to_link = self.mount @ np.linalg.inv(LINK_TO_OPTICAL)
        return classes.TFMessage(transforms=[
            transform_of(classes, stamp, args.base_frame, args.camera_frame, base_to_link),
            transform_of(classes, stamp, args.camera_frame, args.optical_frame, LINK_TO_OPTICAL)])


def write_image(bag, classes, args, topic, header, img):
    if args.compressed:
        msg = classes.CompressedImage()
        msg.header = header
        msg.format, msg.data = encode_compressed(img, args.compressed, args.jpeg_quality)
        bag.write(topic + "/compressed", msg, header.stamp)
        return
    msg = classes.Image()
    msg.header = header
    msg.height, msg.width = img.shape[0], img.shape[1]
    msg.encoding = "rgb8" if img.ndim == 3 else "mono8"
    msg.is_bigendian = 0
    msg.step = msg.width * (3 if img.ndim == 3 else 1)
    msg.data = np.ascontiguousarray(img).tobytes()
    bag.write(topic, msg, header.stamp)


# Where the stamps go when the sequence starts at 0 (long3r_synth's do) and
# no --time-offset is given.
AUTO_START_S = 1000.0


def resolve_time_offset(offset, first_stamp):
    """The offset added to every stamp. A stamp of 0 is "no time" in ROS: the
    node drops such frames (drop_zero_stamps) and so would a bag's reader, so
    a sequence that starts at or before 0 is moved to start at AUTO_START_S
    unless an offset is given, and an offset that leaves the first frame at
    or before 0 is refused."""
    if offset is None:
        if first_stamp > 0.0:
            return 0.0
        offset = AUTO_START_S - first_stamp
        sys.stderr.write("tum_to_bag: the first frame is stamped %.6f s (0 is \"no time\" in ROS); "
                         "every stamp moved by %+.3f s (--time-offset to choose)\n" % (first_stamp, offset))
        return offset
    if first_stamp + offset <= 0.0:
        raise ValueError("--time-offset %g puts the first frame at %.6f s: stamps must be > 0 "
                         "(0 is \"no time\" in ROS, and its frame would be dropped)"
                         % (offset, first_stamp + offset))
    return offset


def convert(args):
    classes = load_message_classes()
    root = args.tum_dir
    rgb = read_list(os.path.join(root, "rgb.txt"))
    if args.calib:
        intr = [float(x) for x in args.calib.split()]
        if len(intr) != 4:
            raise ValueError("--calib needs 'fx fy cx cy'")
        calib = Calibration(tuple(intr), None, "", [])
    else:
        calib = read_calibration(os.path.join(root, "calibration.txt"))
    frame_id = args.frame_id
    if args.robot:
        if frame_id not in (None, args.optical_frame):
            raise ValueError("--robot: images are in --optical-frame (%s), not --frame-id %s"
                             % (args.optical_frame, frame_id))
        frame_id = args.optical_frame
    elif frame_id is None:
        frame_id = "camera"
    tf_parent = args.tf_parent or ("gt_world" if args.robot else "map")
    tf_child = args.tf_child or ("gt_base_link" if args.robot else "gt_camera")
    gt = []
    gt_path = os.path.join(root, "base_groundtruth.txt" if args.robot else "groundtruth.txt")
    if not args.no_tf and os.path.exists(gt_path):
        gt = read_trajectory(gt_path)
    gt_stamps = [g[0] for g in gt]
    depth, depth_of = [], {}
    if args.depth_topic:
        depth = read_list(os.path.join(root, "depth.txt"))
        depth_of = associate([r[0] for r in rgb], [d[0] for d in depth], args.max_diff)

    frames = rgb[args.start::args.stride]
    if args.max_frames > 0:
        frames = frames[:args.max_frames]
    if frames:
        args.time_offset = resolve_time_offset(args.time_offset, frames[0][0])
    robot = Robot(root, args, [f[0] for f in frames]) if args.robot and frames else None
    if robot and args.odom_tum:
        robot.write_tum(args.odom_tum)
    fx, fy, cx, cy = calib.K
    counts = {"image": 0, "info": 0, "tf": 0, "depth": 0, "odom": 0, "tf_static": 0}
    odom_next = 0

    def stamp_of(t):
        return genpy.Time.from_sec(t + args.time_offset)

    with rosbag.Bag(args.output, "w", compression=args.compression) as bag:
        if robot:
            t = stamp_of(frames[0][0])
            bag.write("/tf_static", robot.static_message(classes, args, t), t,
                      connection_header=latched_header("/tf_static", classes.TFMessage))
            counts["tf_static"] += 1
        for k, (stamp, rel) in enumerate(frames):
            index = args.start + k * args.stride
            t = stamp_of(stamp)
            while robot and odom_next < len(robot.odom_stamps) and robot.odom_stamps[odom_next] <= stamp + 1e-9:
                ot = stamp_of(robot.odom_stamps[odom_next])
                T = planar_matrix(*robot.odom[odom_next])
                bag.write("/tf", classes.TFMessage(transforms=[
                    transform_of(classes, ot, args.odom_frame, args.base_frame, T)]), ot)
                bag.write("/odom", robot.odometry_message(classes, args, odom_next, ot), ot)
                counts["odom"] += 1
                odom_next += 1
            img = read_png(os.path.join(root, rel))
            if img.ndim == 3 and img.shape[2] == 4:
                img = img[:, :, :3]
            if img.dtype != np.uint8:
                raise ValueError("%s: expected an 8-bit colour image" % rel)
            header = classes.Image().header  # a std_msgs/Header, shared by the frame's messages
            header.stamp = t
            header.seq = k
            header.frame_id = frame_id
            write_image(bag, classes, args, args.image_topic, header, img)
            counts["image"] += 1

            info = classes.CameraInfo()
            info.header = header
            info.height, info.width = (calib.size[1], calib.size[0]) if calib.size else img.shape[:2]
            info.distortion_model = calib.model or "plumb_bob"
            info.D = list(calib.D) if calib.model else [0.0] * 5
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
                dm = classes.Image()
                dm.header = header
                dm.height, dm.width = metres.shape
                dm.encoding = "32FC1"
                dm.is_bigendian = 0
                dm.step = dm.width * 4
                dm.data = metres.tobytes()
                bag.write(args.depth_topic, dm, t)
                counts["depth"] += 1

            g = nearest(gt_stamps, stamp, args.max_diff) if gt else None
            if g is not None:
                _, tr, q = gt[g]
                bag.write("/tf", classes.TFMessage(transforms=[transform_msg(classes, t, tf_parent, tf_child, tr, q)]), t)
                counts["tf"] += 1
    return counts


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("tum_dir", help="folder with rgb.txt, rgb/, calibration.txt, groundtruth.txt")
    p.add_argument("output", help="bag file to write")
    p.add_argument("--image-topic", default="/camera/image_raw")
    p.add_argument("--info-topic", default="/camera/camera_info")
    p.add_argument("--depth-topic", default="", help="also write depth (32FC1, metres) on this topic")
    p.add_argument("--frame-id", default=None,
                   help="header.frame_id of images and camera info (default camera; --robot: --optical-frame)")
    p.add_argument("--tf-parent", default=None,
                   help="parent frame of the ground-truth transform (default map; --robot: gt_world)")
    p.add_argument("--tf-child", default=None,
                   help="child frame of the ground-truth transform (default gt_camera; --robot: gt_base_link)")
    p.add_argument("--no-tf", action="store_true", help="do not write the ground truth on /tf")
    p.add_argument("--calib", default="", help="'fx fy cx cy' when there is no calibration.txt")
    p.add_argument("--depth-factor", type=float, default=5000.0, help="depth PNG value per metre")
    p.add_argument("--max-diff", type=float, default=0.02, help="timestamp association tolerance (s)")
    p.add_argument("--time-offset", type=float, default=None,
                   help="added to every stamp (s); default 0, or, when the first frame is stamped 0 "
                        "or earlier, what moves it to %g s (a zero stamp is dropped in ROS)" % AUTO_START_S)
    p.add_argument("--start", type=int, default=0, help="first frame")
    p.add_argument("--stride", type=int, default=1,
                   help="every N-th frame from --start (a slower camera on the same path)")
    p.add_argument("--max-frames", type=int, default=0, help="at most this many frames (0: all)")
    p.add_argument("--compression", default="none", choices=["none", "bz2", "lz4"])
    p.add_argument("--compressed", nargs="?", const="jpeg", default=None, choices=["jpeg", "png"],
                   help="images as sensor_msgs/CompressedImage on <image-topic>/compressed (default jpeg)")
    p.add_argument("--jpeg-quality", type=int, default=80, help="JPEG quality of --compressed jpeg (1-100)")
    r = p.add_argument_group("robot (--robot)")
    r.add_argument("--robot", action="store_true", help="write /tf_static, odometry on /tf, ground truth apart")
    r.add_argument("--base-frame", default="base_link")
    r.add_argument("--camera-frame", default="camera_link")
    r.add_argument("--optical-frame", default="camera_color_optical_frame")
    r.add_argument("--odom-frame", default="odom")
    r.add_argument("--odom-rate", type=float, default=0.0, help="odometry samples per second (0: one per frame)")
    r.add_argument("--odom-scale-error", type=float, default=0.03,
                   help="relative error of the odometry's travelled distance")
    r.add_argument("--odom-yaw-drift", type=float, default=1.0, help="odometry yaw drift, degrees per metre")
    r.add_argument("--odom-yaw-drift-rate", type=float, default=0.0, help="odometry yaw drift, degrees per second")
    r.add_argument("--odom-tum", default="",
                   help="also write the odometry as a TUM trajectory of the camera in odom "
                        "(the sequence's stamps; long3r_reconstruct --odometry)")
    args = p.parse_args(argv)
    if not 1 <= args.jpeg_quality <= 100:
        p.error("--jpeg-quality must be within 1-100")
    if args.odom_rate < 0:
        p.error("--odom-rate must be >= 0")
    if args.stride < 1:
        p.error("--stride must be >= 1")
    try:
        counts = convert(args)
    except ValueError as e:
        p.error(str(e))
    print("wrote %s: %d images, %d camera infos, %d depth images, %d tf messages"
          % (args.output, counts["image"], counts["info"], counts["depth"], counts["tf"])
          + (", %d odometry transforms, %d tf_static" % (counts["odom"], counts["tf_static"]) if args.robot else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
