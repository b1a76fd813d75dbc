#!/usr/bin/python3
"""Checks what Long3rNodelet publishes while a generated bag is replayed.

mode normal: per-frame outputs are consistent (one ~frame_cloud and one path
pose per ~pointmap, the last frame arrives after the flush), TF resolves at
every published stamp, the map is non-empty, ~save_map writes a readable PLY
and ~reset clears map and path.
mode bad: through an unsupported encoding, a stray frame of another size, a
lasting size change and time going backwards (make_bad_bag.py) the node is
alive and publishes exactly the frames it should.
mode pause: a pause several times flush_after_s long in the middle
(make_timing_bag.py --pause-after): the frame before it is published during
the pause, and the frames after it continue the same stream (frame indices,
path, map all kept).
mode slow: a camera slower than flush_after_s (make_timing_bag.py --period):
every frame gets its result, each before the next frame arrives.
mode lost: no frame can be posed (pnp_reprojection_error_px of a millionth of a pixel)
and lost_reset_frames is 3: every frame still gets its result (~camera_info),
only the first frame of each stream is posed, and after 3 unposed frames the
node warns, names the cause and starts a new stream (at least one restart);
the diagnostics say tracking is lost while it is, and the node keeps running.
"""
import argparse
import os
import sys
import threading
import time
import unittest

import rospy
import rostest
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray
from rosgraph_msgs.msg import Log
from nav_msgs.msg import Path
from nodelet.srv import NodeletList
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_srvs.srv import Trigger

from long3r_ros.msg import Pointmap
from map_checks import cloud_points, lost_points
from long3r_ros.srv import SaveMap, SaveTrajectory

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', 'scripts'))
from demo_record import FrameAccounting, bag_images, lookup_transform_wall, wait_for  # noqa: E402

ARGS = None


class Recorder:
    def __init__(self):
        self.lock = threading.Lock()
        self.pointmaps = []
        self.pointmap_wall = []
        self.pointmap_clock = []  # the (simulated) ROS clock at receipt
        self.frame_clouds = []
        self.maps = []
        self.paths = []
        self.infos = []
        self.logs = []
        self.diagnostics = []
        rospy.Subscriber('/long3r/pointmap', Pointmap, self._pointmap, queue_size=100)
        rospy.Subscriber('/long3r/frame_cloud', PointCloud2, self._add('frame_clouds'), queue_size=100)
        rospy.Subscriber('/long3r/map', PointCloud2, self._add('maps'), queue_size=100)
        rospy.Subscriber('/long3r/path', Path, self._add('paths'), queue_size=100)
        # ~camera_info comes with every result, posed or not.
        rospy.Subscriber('/long3r/camera_info', CameraInfo, self._add('infos'), queue_size=100)
        rospy.Subscriber('/rosout', Log, self._log, queue_size=1000)
        rospy.Subscriber('/diagnostics', DiagnosticArray, self._diag, queue_size=100)

    def _log(self, msg):
        with self.lock:
            self.logs.append(msg.msg)

    def _diag(self, msg):
        with self.lock:
            self.diagnostics.extend(s.message for s in msg.status)

    def _pointmap(self, msg):
        with self.lock:
            self.pointmaps.append(msg)
            self.pointmap_wall.append(time.time())
            self.pointmap_clock.append(rospy.Time.now().to_sec())

    def _add(self, name):
        def cb(msg):
            with self.lock:
                getattr(self, name).append(msg)
        return cb

    def count(self, name):
        with self.lock:
            return len(getattr(self, name))

    def get(self, name):
        with self.lock:
            return list(getattr(self, name))


def read_ply_vertex_count(path):
    with open(path, 'rb') as f:
        head = f.read(4096)
    assert head.startswith(b'ply'), 'not a PLY file'
    for line in head.split(b'\n'):
        if line.startswith(b'element vertex'):
            return int(line.split()[2])
    raise AssertionError('no vertex element in PLY header')


class ReplayCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.rec = Recorder()
        cls.accounting = FrameAccounting()
        cls.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(600))
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)

    def _wait_for_every_frame(self, timeout_s):
        # The replay is over when the node has accounted for every image of
        # the bag (the last one after flush_after_s), never after a quiet spell.
        frames = bag_images(ARGS.bag)
        done = self.accounting.wait(frames, timeout_s)
        rospy.loginfo('frame accounting: %s', self.accounting.describe(frames))
        self.assertTrue(done, 'the node did not account for every frame: ' + self.accounting.describe(frames))

    def test_replay(self):
        rospy.wait_for_service('/long3r/reset', timeout=60)
        self._wait_for_every_frame(240)
        pms = self.rec.get('pointmaps')
        stamps = [p.header.stamp.to_sec() for p in pms]
        rospy.loginfo('received %d pointmaps: %s', len(pms), ['%.2f' % s for s in stamps])
        if ARGS.mode == 'normal':
            self._check_normal(pms)
        elif ARGS.mode == 'bad':
            self._check_bad([m.header.stamp.to_sec() for m in self.rec.get('infos')])
        elif ARGS.mode == 'lost':
            self._check_lost(pms)
        else:
            self._check_continuity(pms)

    def _check_normal(self, pms):
        n = len(pms)
        self.assertGreaterEqual(n, 1)
        self.assertLessEqual(n, ARGS.frames)
        self.assertEqual(pms[0].frame_index, 0)
        self.assertEqual(sorted(p.frame_index for p in pms), [p.frame_index for p in pms])
        for p in pms:
            self.assertEqual(len(p.points), p.width * p.height * 3)
            self.assertEqual(len(p.confidence), p.width * p.height)
            self.assertGreater(p.fx, 0.0)
        self.assertEqual(self.rec.count('frame_clouds'), n, 'one frame_cloud per pointmap')
        for cloud in self.rec.get('frame_clouds'):
            self.assertEqual((cloud.height, cloud.width), (pms[0].height, pms[0].width))
            self.assertIn('confidence', [f.name for f in cloud.fields])
        paths = self.rec.get('paths')
        self.assertTrue(paths)
        self.assertEqual(len(paths[-1].poses), n, 'one path pose per published frame')
        # config/default.yaml: scale_source none, so the map frame's name says
        # its lengths are model units.
        self.assertEqual({p.map_frame_id for p in pms}, {'map_model_units'})
        self.assertEqual(paths[-1].header.frame_id, 'map_model_units')
        for p in pms:  # TF resolves at every published stamp
            lookup_transform_wall(self.tf_buffer, 'map_model_units', p.header.frame_id,
                                  p.header.stamp, 2.0)
        if ARGS.expect_all_frames:
            self.assertEqual(n, ARGS.frames, 'one pointmap per input frame')
            sizes = [m.width * m.height for m in self.rec.get('maps')]
            self.assertGreater(sizes[-1], sizes[0], 'the map grows')

        self.assertTrue(wait_for(lambda: any(m.width > 0 for m in self.rec.get('maps')), 10),
                        'the map is empty')
        out = os.path.join(ARGS.out, 'saved_map.ply')
        if os.path.exists(out):
            os.remove(out)
        save = rospy.ServiceProxy('/long3r/save_map', SaveMap)
        res = save(out)
        self.assertTrue(res.success, res.message)
        self.assertGreater(read_ply_vertex_count(out), 0)
        bad = save(os.path.join(ARGS.out, 'map.unknown_extension'))
        self.assertFalse(bad.success)

        n_maps = self.rec.count('maps')
        res = rospy.ServiceProxy('/long3r/reset', Trigger)()
        self.assertTrue(res.success)
        self.assertTrue(wait_for(lambda: self.rec.count('maps') > n_maps, 10), 'no map after reset')
        self.assertEqual(self.rec.get('maps')[-1].width, 0, 'reset did not clear the map')
        self.assertTrue(wait_for(lambda: len(self.rec.get('paths')[-1].poses) == 0, 10),
                        'reset did not clear the path')

    def _check_bad(self, stamps):
        t0 = ARGS.t0
        expected = [t0, t0 + 0.1, t0 + 0.4, t0 + 0.7, t0 + 0.8, t0 - 5.0, t0 - 4.9]
        dropped = [t0 + 0.2, t0 + 0.3, t0 + 0.5, t0 + 0.6]
        for t in expected:
            self.assertTrue(any(abs(s - t) < 1e-3 for s in stamps), 'no output for t0%+.1f' % (t - t0))
        for t in dropped:
            self.assertFalse(any(abs(s - t) < 1e-3 for s in stamps),
                             'the frame at t0%+.1f should have been dropped' % (t - t0))
        self.assertEqual(len(stamps), len(expected), 'one output per accepted frame')
        nodelets = rospy.ServiceProxy('/manager/list', NodeletList)().nodelets
        self.assertIn('/long3r', nodelets)

    def _check_lost(self, pms):
        infos = self.rec.get('infos')
        # Every frame gets its result but the one the model holds at a reset.
        self.assertGreaterEqual(len(infos), ARGS.frames - 2, 'frames without a result')
        self.assertGreaterEqual(len(pms), 2, 'no new stream after the lost frames')
        self.assertEqual([p.frame_index for p in pms], [0] * len(pms),
                         'only the first frame of a stream can be posed here')
        restart = 'tracking lost for 3 consecutive frames (lost_reset_frames): starting a new stream'
        self.assertTrue(wait_for(lambda: any(restart in m for m in self.rec.get('logs')), 10),
                        'no warning naming the restart')
        self.assertTrue(any(m.startswith('tracking lost for') for m in self.rec.get('diagnostics')),
                        'the diagnostics never said tracking was lost')
        # A new stream never wipes the map: the ended streams' points stay in ~map.
        self.assertTrue(wait_for(lambda: any('map points stay in the map' in m for m in self.rec.get('logs')), 10),
                        'no log line keeping the ended stream\'s map')
        maps = [m for m in self.rec.get('maps') if m.width > 0]
        self.assertGreaterEqual(len(maps), 2)
        first, last = cloud_points(maps[0]), cloud_points(maps[-1])
        self.assertEqual(lost_points(first, last, 0.02), 0,
                         'the first stream\'s map points are gone from ~map')
        nodelets = rospy.ServiceProxy('/manager/list', NodeletList)().nodelets
        self.assertIn('/long3r', nodelets)

    def _check_continuity(self, pms):
        n = len(pms)
        self.assertEqual(n, ARGS.frames, 'one pointmap per input frame')
        self.assertEqual([p.frame_index for p in pms], list(range(n)), 'one stream, no restart')
        paths = self.rec.get('paths')
        self.assertEqual(len(paths[-1].poses), n, 'the path holds every frame')
        sizes = [m.width * m.height for m in self.rec.get('maps')]
        self.assertTrue(all(b >= a for a, b in zip(sizes, sizes[1:])),
                        'the map lost points: %s' % sizes)
        wall = self.rec.get('pointmap_wall')
        if ARGS.mode == 'pause':
            k = ARGS.pause_after
            gap = wall[k + 1] - wall[k]
            self.assertGreater(gap, 3.0, 'frame %d was not published during the pause (%.1f s '
                               'before frame %d)' % (k, gap, k + 1))
        else:
            # slow: every frame from the second on is published before the next
            # one arrives (the first comes with the second: the model needs a pair).
            clock = self.rec.get('pointmap_clock')
            for k in range(1, n - 1):
                self.assertLess(clock[k], pms[k + 1].header.stamp.to_sec(),
                                'frame %d waited for the next frame' % k)
        out = os.path.join(ARGS.out, 'saved_map_%s.ply' % ARGS.mode)
        res = rospy.ServiceProxy('/long3r/save_map', SaveMap)(out)
        self.assertTrue(res.success, res.message)
        self.assertEqual(read_ply_vertex_count(out), sizes[-1])
        traj = os.path.join(ARGS.out, 'trajectory_%s.txt' % ARGS.mode)
        res = rospy.ServiceProxy('/long3r/save_trajectory', SaveTrajectory)(traj)
        self.assertTrue(res.success, res.message)
        with open(traj) as f:
            lines = [l for l in f if l.strip() and not l.startswith('#')]
        self.assertEqual(len(lines), n)
        for line, p in zip(lines, pms):  # TUM stamps have 6 decimals
            self.assertAlmostEqual(float(line.split()[0]), p.header.stamp.to_sec(), places=5)


if __name__ == '__main__':
    parser = argparse.ArgumentParser()
    parser.add_argument('--mode', choices=['normal', 'bad', 'pause', 'slow', 'lost'], default='normal')
    parser.add_argument('--pause-after', type=int, default=3)
    parser.add_argument('--frames', type=int, default=8)
    parser.add_argument('--bag', required=True, help='the bag replayed (its images are counted)')
    parser.add_argument('--t0', type=float, default=1000.0)
    parser.add_argument('--out', default='/tmp')
    parser.add_argument('--expect-all-frames', action='store_true')
    ARGS, rest = parser.parse_known_args(rospy.myargv()[1:])
    rospy.init_node('replay_check')
    rostest.rosrun('long3r_ros', 'replay_check', ReplayCheck, [sys.argv[0]] + rest)
