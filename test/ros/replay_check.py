#!/usr/bin/python3
"""Checks what Long3rNodelet publishes while a generated bag is replayed.

mode normal: per-frame outputs are consistent (one ~frame_cloud and one path
pose per ~pointmap, the last frame arrives after the flush), TF resolves at
every published stamp, the map is non-empty, ~save_map writes a readable PLY
and ~reset clears map and path.
mode bad: after an unsupported encoding, a size change and time going
backwards the node is alive and publishes the frames of the new streams.
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
from nav_msgs.msg import Path
from nodelet.srv import NodeletList
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

from long3r_ros.msg import Pointmap
from long3r_ros.srv import SaveMap

ARGS = None


class Recorder:
    def __init__(self):
        self.lock = threading.Lock()
        self.pointmaps = []
        self.frame_clouds = []
        self.maps = []
        self.paths = []
        rospy.Subscriber('/long3r/pointmap', Pointmap, self._add('pointmaps'), queue_size=100)
        rospy.Subscriber('/long3r/frame_cloud', PointCloud2, self._add('frame_clouds'), queue_size=100)
        rospy.Subscriber('/long3r/map', PointCloud2, self._add('maps'), queue_size=100)
        rospy.Subscriber('/long3r/path', Path, self._add('paths'), queue_size=100)

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


def wait_for(pred, timeout_s):
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        if pred():
            return True
        time.sleep(0.1)  # wall time: the bag's clock stops when it ends
    return pred()


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
        cls.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(600))
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)

    def _wait_until_quiet(self, timeout_s):
        # The replay is over when no new pointmap arrived for a few seconds
        # (this includes the flush of the last frame).
        last = [-1, time.time()]

        def quiet():
            n = self.rec.count('pointmaps')
            if n != last[0]:
                last[0], last[1] = n, time.time()
            return n > 0 and time.time() - last[1] > 4.0
        self.assertTrue(wait_for(quiet, timeout_s), 'no pointmap arrived')

    def test_replay(self):
        rospy.wait_for_service('/long3r/reset', timeout=60)
        self._wait_until_quiet(240)
        pms = self.rec.get('pointmaps')
        stamps = [p.header.stamp.to_sec() for p in pms]
        rospy.loginfo('received %d pointmaps: %s', len(pms), ['%.2f' % s for s in stamps])
        if ARGS.mode == 'normal':
            self._check_normal(pms)
        else:
            self._check_bad(stamps)

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
        for p in pms:  # TF resolves at every published stamp
            self.tf_buffer.lookup_transform('map', p.header.frame_id, p.header.stamp,
                                            rospy.Duration(2.0))
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
        # The half-size stream started at t0 + 0.3; the looped stream at t0 - 5.
        self.assertTrue(any(abs(s - (t0 + 0.3)) < 1e-3 for s in stamps),
                        'no output after the image size changed')
        self.assertTrue(any(abs(s - (t0 - 5.0)) < 1e-3 for s in stamps),
                        'no output after time went backwards')
        self.assertFalse(any(abs(s - (t0 + 0.2)) < 1e-3 for s in stamps),
                         'the unsupported-encoding frame was published')
        nodelets = rospy.ServiceProxy('/manager/list', NodeletList)().nodelets
        self.assertIn('/long3r', nodelets)


if __name__ == '__main__':
    parser = argparse.ArgumentParser()
    parser.add_argument('--mode', choices=['normal', 'bad'], default='normal')
    parser.add_argument('--frames', type=int, default=8)
    parser.add_argument('--t0', type=float, default=1000.0)
    parser.add_argument('--out', default='/tmp')
    parser.add_argument('--expect-all-frames', action='store_true')
    ARGS, rest = parser.parse_known_args(rospy.myargv()[1:])
    rospy.init_node('replay_check')
    rostest.rosrun('long3r_ros', 'replay_check', ReplayCheck, [sys.argv[0]] + rest)
