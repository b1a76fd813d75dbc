#!/usr/bin/python3
"""Publishes a live camera (wall-clock stamps) with hostile input between good
frames, and checks what Long3rNodelet does with each:

  a late camera_info (used from the next frame on), reordered, duplicate,
  zero and far-ahead stamps, NaN / inf / out-of-image / wrong-size camera_info,
  a stray frame of another size, a frame above max_image_pixels, two bad
  encodings within the throttle period, bayer and yuv422 frames (converted),
  malformed messages, ~pause / ~resume, ~save_trajectory, and finally time
  jumping far back (the one input here that starts a new stream).

Throughout: the node keeps publishing, every accepted frame gets exactly one
result, the frames of the one stream are numbered without a restart, the map
never loses points, each problem is named in the log (one line per kind), and
the diagnostics warn while a problem lasts and clear after.
"""
import glob
import math
import os
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticArray
from nodelet.srv import NodeletList
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_srvs.srv import Trigger

from long3r_ros.msg import Pointmap
from long3r_ros.srv import SaveTrajectory

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', 'scripts'))
import tum_to_bag  # noqa: E402 (the project's PNG and calibration readers)
from demo_record import FrameAccounting, wait_for  # noqa: E402

DATA = os.environ.get('LONG3R_REPLAY_DATA', '/tmp/long3r_replay_data')
MAX_IMAGE_PIXELS = 1000000  # live_input.test sets it


def load_sequence(folder):
    frames = [tum_to_bag.read_png(p)
              for p in sorted(glob.glob(os.path.join(folder, 'rgb', '*.png')))]
    return frames, tum_to_bag.read_calibration(os.path.join(folder, 'calibration.txt')).K


def model_intrinsics(fx, fy, cx, cy, w, h, size):
    """The calibration seen through the pipeline's resize (short side to the
    model's square input of side size, lround) and centre crop:
    scale_intrinsics() of the core."""
    s = max(size / w, size / h)
    rw, rh = max(size, int(math.floor(w * s + 0.5))), max(size, int(math.floor(h * s + 0.5)))
    ax, ay = w / rw, h / rh
    bx, by = ((rw - size) // 2 + 0.5) * ax - 0.5, ((rh - size) // 2 + 0.5) * ay - 0.5
    return fx / ax, fy / ay, (cx - bx) / ax, (cy - by) / ay


class Monitor:
    def __init__(self):
        self.lock = threading.Lock()
        self.pointmaps, self.results, self.map_sizes, self.logs, self.diags = [], [], [], [], []
        rospy.Subscriber('/long3r/pointmap', Pointmap, self._add('pointmaps'), queue_size=200)
        rospy.Subscriber('/long3r/camera_info', CameraInfo, self._add('results'), queue_size=200)
        rospy.Subscriber('/long3r/map', PointCloud2,
                         lambda m: self._append('map_sizes', m.width * m.height), queue_size=200)
        # What the node logs, as every node publishes it (rosout aggregates it later).
        rospy.Subscriber('/rosout', Log, self._log, queue_size=1000)
        rospy.Subscriber('/diagnostics', DiagnosticArray, self._diag, queue_size=100)

    def _append(self, name, value):
        with self.lock:
            getattr(self, name).append(value)

    def _add(self, name):
        return lambda m: self._append(name, m)

    def _log(self, m):
        if m.level >= Log.INFO and m.name == '/manager':
            self._append('logs', (m.level, m.msg))

    def _diag(self, m):
        for s in m.status:
            if s.name.endswith('reconstruction'):
                self._append('diags', (s.level, s.message, {kv.key: kv.value for kv in s.values},
                                       time.time()))

    def get(self, name):
        with self.lock:
            return list(getattr(self, name))

    def logged(self, text, level=None):
        return [msg for lvl, msg in self.get('logs') if text in msg and (level is None or lvl == level)]


class LiveInput(unittest.TestCase):
    def setUp(self):
        self.frames, (self.fx, self.fy, self.cx, self.cy) = load_sequence(os.path.join(DATA, 'live'))
        self.h, self.w = self.frames[0].shape[:2]
        # A ping-pong walk through the sequence: a plausible, endless video.
        self.order = list(range(len(self.frames))) + list(range(len(self.frames) - 2, 0, -1))
        self.k = 0
        self.sent = 0  # images published, hostile ones included
        self.accepted = []  # stamps of frames the node should take
        self.image_pub = rospy.Publisher('/camera/image_raw', Image, queue_size=20)
        self.info_pub = rospy.Publisher('/camera/camera_info', CameraInfo, queue_size=20)
        self.mon = Monitor()
        self.accounting = FrameAccounting()
        rospy.wait_for_service('/long3r/reset', timeout=120)
        self.assertTrue(wait_for(lambda: self.image_pub.get_num_connections() > 0
                                 and self.info_pub.get_num_connections() > 0, 30))

    # ------------------------------------------------------------ publishing

    def image(self, rgb, stamp, encoding='rgb8'):
        msg = Image()
        msg.header.stamp = stamp
        msg.header.frame_id = 'camera'
        msg.height, msg.width = rgb.shape[0], rgb.shape[1]
        msg.encoding = encoding
        if encoding == 'rgb8':
            data = np.ascontiguousarray(rgb, dtype=np.uint8)
        elif encoding == 'bayer_rggb8':
            data = np.zeros(rgb.shape[:2], np.uint8)
            data[0::2, 0::2] = rgb[0::2, 0::2, 0]
            data[0::2, 1::2] = rgb[0::2, 1::2, 1]
            data[1::2, 0::2] = rgb[1::2, 0::2, 1]
            data[1::2, 1::2] = rgb[1::2, 1::2, 2]
        elif encoding == 'yuv422':  # UYVY
            f = rgb.astype(np.float32)
            y = 0.299 * f[..., 0] + 0.587 * f[..., 1] + 0.114 * f[..., 2]
            u = (f[..., 2] - y) * 0.564 + 128
            v = (f[..., 0] - y) * 0.713 + 128
            data = np.zeros((rgb.shape[0], rgb.shape[1] * 2), np.uint8)
            data[:, 0::4] = np.clip(u[:, 0::2], 0, 255)
            data[:, 1::2] = np.clip(y, 0, 255)
            data[:, 2::4] = np.clip(v[:, 0::2], 0, 255)
        else:
            raise ValueError(encoding)
        msg.step = data.shape[1] * (3 if data.ndim == 3 else 1)
        msg.data = data.tobytes()
        return msg

    def info(self, stamp, **override):
        m = CameraInfo()
        m.header.stamp = stamp
        m.header.frame_id = 'camera'
        m.width, m.height = self.w, self.h
        m.distortion_model = 'plumb_bob'
        m.D = [0.0] * 5
        fx, fy, cx, cy = override.pop('fx', self.fx), self.fy, override.pop('cx', self.cx), self.cy
        m.K = [fx, 0, cx, 0, fy, cy, 0, 0, 1]
        m.R = [1, 0, 0, 0, 1, 0, 0, 0, 1]
        m.P = [fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0]
        for key, value in override.items():
            setattr(m, key, value)
        return m

    def send(self, msg, info=None, pause_s=0.25):
        if info is not None:
            self.info_pub.publish(info)
        self.image_pub.publish(msg)
        self.sent += 1
        time.sleep(pause_s)

    def good(self, n=1, info=True, encoding='rgb8', info_override=None, accepted=True,
             pause_s=0.25):
        for _ in range(n):
            stamp = rospy.Time.now()
            rgb = self.frames[self.order[self.k % len(self.order)]]
            self.k += 1
            info_msg = self.info(stamp, **(info_override or {})) if info else None
            self.send(self.image(rgb, stamp, encoding), info_msg, pause_s)
            if accepted:
                self.accepted.append(stamp.to_sec())
        return stamp

    def settle(self, timeout_s=60):
        """Waits until the node has accounted for every image sent so far (the
        last one after flush_after_s) and their results have arrived; every
        accepted frame must have one."""
        accounted = self.accounting.wait(self.sent, timeout_s)
        results = {round(m.header.stamp.to_sec(), 6) for m in self.mon.get('results')}
        ok = accounted and len(self.mon.get('results')) >= len(self.accepted)
        self.assertTrue(ok, '%s; %d results for %d accepted frames; without a result: %s; %s' % (
            self.accounting.describe(self.sent),
            len(results), len(self.accepted),
            ['%.3f' % (t - self.accepted[0]) for t in self.accepted if round(t, 6) not in results],
            self.mon.get('diags')[-1][2] if self.mon.get('diags') else ''))

    def expect_warning(self, text):
        self.assertTrue(wait_for(lambda: self.mon.logged(text, Log.WARN), 10),
                        'no warning containing "%s"; warnings: %s' %
                        (text, [m for l, m in self.mon.get('logs') if l == Log.WARN][-8:]))

    # ------------------------------------------------------------ the scenario

    def test_hostile_input(self):
        # A camera_info arriving after the first frames is used from then on.
        self.good(4, info=False)
        self.settle()
        self.assertTrue(self.mon.logged('intrinsics in use estimated'),
                        [m for _, m in self.mon.get('logs')][-10:])
        self.good(4)
        self.settle()
        self.assertTrue(self.mon.logged('camera calibration from camera_info'))
        last = self.mon.get('pointmaps')[-1]
        # The model runs at the size its checkpoint records (a square input).
        self.assertEqual(last.width, last.height)
        fx, fy, cx, cy = model_intrinsics(self.fx, self.fy, self.cx, self.cy, self.w, self.h,
                                          last.width)
        for got, want in ((last.fx, fx), (last.fy, fy), (last.cx, cx), (last.cy, cy)):
            self.assertAlmostEqual(got, want, delta=1e-6 * abs(want))

        # Time: a small reordering, a duplicate, a zero stamp, one stamp an hour ahead.
        stamp = self.good()
        frame = self.frames[0]
        self.send(self.image(frame, stamp - rospy.Duration(0.05)))
        self.send(self.image(frame, stamp))
        self.send(self.image(frame, rospy.Time(0)))
        self.send(self.image(frame, rospy.Time.now() + rospy.Duration(3600)))
        self.good(3)
        self.settle()
        self.expect_warning('duplicate or out of order')
        self.expect_warning('has no time stamp')
        self.expect_warning('ran ahead of the clock')
        self.expect_warning('far ahead of the frames around it')

        # Calibrations that cannot be used: the last valid one stays in use.
        for override, named in (({'fx': float('nan')}, 'K[0] (fx) is nan'),
                                ({'cx': float('inf')}, 'K[2] (cx) is inf'),
                                ({'cx': 500.0}, 'K[2] (cx) = 500 is outside the image'),
                                ({'width': 2 * self.w}, 'but they are')):
            # Two frames: the image and its camera_info travel on separate
            # topics, so the first frame may be processed before its info
            # arrives (it then keeps the previous calibration).
            self.good(2, info_override=override)
            self.expect_warning(named)
        self.assertTrue(wait_for(lambda: any('camera_info not used' in d[1]
                                             for d in self.mon.get('diags')), 10),
                        'the diagnostics did not warn about the camera_info')
        self.good(3)
        self.settle()
        pm = self.mon.get('pointmaps')[-1]
        self.assertAlmostEqual(pm.fx, fx, delta=1e-6 * fx)

        # Images: a stray frame of another size, one above max_image_pixels, two
        # bad encodings within the throttle period (both named), bayer and yuv422
        # (converted and used), malformed messages.
        big = np.zeros((1000, 1200, 3), np.uint8)
        self.send(self.image(np.zeros((480, 640, 3), np.uint8), rospy.Time.now()))
        self.send(self.image(big, rospy.Time.now()))
        for encoding in ('yuv444', '32FC1'):
            bad = self.image(frame, rospy.Time.now())
            bad.encoding = encoding
            if encoding == '32FC1':
                bad.step, bad.data = bad.width * 4, bytes(bad.width * 4 * bad.height)
            self.send(bad)
        self.good(encoding='bayer_rggb8')
        self.good(encoding='yuv422')
        short_step = self.image(frame, rospy.Time.now())
        short_step.step = 3
        short_data = self.image(frame, rospy.Time.now())
        short_data.data = short_data.data[:100]
        empty = self.image(frame, rospy.Time.now())
        empty.width, empty.step, empty.data = 0, 0, b''
        for msg in (short_step, short_data, empty):
            self.send(msg)
        self.good(3)
        self.settle()
        self.expect_warning("the frame's size differs from the stream's")
        self.expect_warning('larger than max_image_pixels')
        self.expect_warning("'yuv444' cannot be converted")
        self.expect_warning("'32FC1' cannot be converted")
        self.expect_warning('malformed image message')
        self.expect_warning('empty image')

        # ~pause drops and counts frames; ~resume continues the same stream.
        self.assertTrue(rospy.ServiceProxy('/long3r/pause', Trigger)().success)
        paused = [self.good(accepted=False).to_sec() for _ in range(3)]
        res = rospy.ServiceProxy('/long3r/resume', Trigger)()
        self.assertTrue(res.success)
        self.assertIn('3 frame(s) dropped while paused', res.message)
        self.good(4)
        self.settle()

        # Everything so far was one stream: every accepted frame has exactly
        # one result, in order, numbered without a restart; the map kept growing.
        results = [m.header.stamp.to_sec() for m in self.mon.get('results')]
        self.assertEqual(sorted(results), sorted(self.accepted))
        self.assertFalse(set(paused) & set(results))
        indices = [p.frame_index for p in self.mon.get('pointmaps')]
        self.assertEqual(indices, sorted(indices))
        self.assertEqual(len(set(indices)), len(indices))
        sizes = self.mon.get('map_sizes')
        self.assertTrue(all(b >= a for a, b in zip(sizes, sizes[1:])), sizes)
        self.assertGreater(sizes[-1], 0)
        self.assertFalse(self.mon.logged('starting a new stream'))
        # Throttled per kind: the reordering and the duplicate 0.25 s apart are one report.
        self.assertEqual(len(self.mon.logged('duplicate or out of order')), 1)

        # ~save_trajectory writes the path of the stream (TUM).
        out = os.path.join(DATA, 'live_trajectory.txt')
        res = rospy.ServiceProxy('/long3r/save_trajectory', SaveTrajectory)(out)
        self.assertTrue(res.success, res.message)
        with open(out) as f:
            lines = [l for l in f if l.strip() and not l.startswith('#')]
        self.assertEqual(len(lines), len(self.mon.get('pointmaps')))

        # The diagnostics clear once the problems are gone: after a clean window
        # (5 updates) of steady input, while the input lasts.
        start = time.time()
        self.good(20, pause_s=0.4)
        clean = [d for d in self.mon.get('diags') if d[3] > start + 6.0]
        self.settle()
        self.assertTrue(any(d[0] != 0 for d in self.mon.get('diags')), 'no warning at all')
        self.assertTrue(clean, 'no diagnostics during the clean input')
        self.assertEqual(clean[-1][0], 0, 'still warning: %s' % [d[1] for d in clean])
        latency = clean[-1][2]['latency min / mean / max (s)']
        self.assertLess(float(latency.split("/")[2]), 60.0, latency)  # not the outlier's hour

        # Time far back (a looped bag): a new stream, named in a warning.
        n_before = len(self.mon.get('pointmaps'))
        base = rospy.Time.now() - rospy.Duration(100.0)
        for i in range(3):
            rgb = self.frames[self.order[self.k % len(self.order)]]
            self.k += 1
            stamp = base + rospy.Duration(0.25 * i)
            self.send(self.image(rgb, stamp), self.info(stamp))
            self.accepted.append(stamp.to_sec())
        self.settle()
        self.expect_warning('time jumped back')
        self.assertEqual(self.mon.get('pointmaps')[n_before].frame_index, 0)

        nodelets = rospy.ServiceProxy('/manager/list', NodeletList)().nodelets
        self.assertIn('/long3r', nodelets)


if __name__ == '__main__':
    rospy.init_node('live_input_check')
    rostest.rosrun('long3r_ros', 'live_input_check', LiveInput, sys.argv)
