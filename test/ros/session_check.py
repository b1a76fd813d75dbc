#!/usr/bin/python3
"""Sessions on a robot: map, stop, restart, continue in the same map frame.

The robot bag (make_replay_data.sh: TF tree, wheel odometry with scale error
and yaw drift) is cut in two parts. Each run starts the nodelet
(session_nodes.launch: base_link, odom, pose from the odometry, a fixed
scale) on one master, plays a part, and ends the nodes:

  1. part A; ~save_session, ~save_map, ~save_trajectory;
  2. a fresh node with session_path (the odometry continues, as in a replay):
     a damaged file through ~load_session is refused and the session kept;
     then part B. The joined path holds run 1's poses unchanged and every
     later pose in the same map frame: placed by the odometry, map stays the
     odom frame of run 1, so each pose equals the bag's odom -> base_link at
     its stamp (this does not hinge on the model's registration); the map
     keeps every saved point (each within a voxel diagonal of a point of the
     new map);
  3. a fresh node with session_path on part B whose odometry started over
     (odom -> base_link is the identity at B's first frame): map -> odom
     follows from the first frame the model places (logged), the path goes
     on from the saved one, and every frame has one parent in TF.
"""
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import unittest

import numpy as np
from map_checks import lost_points

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'support'))
from cli_test import free_port  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DATA = os.environ.get('LONG3R_REPLAY_DATA', '/tmp/long3r_replay_data')
SPLIT = 20  # images in part A
RATE = 0.5  # bag playback rate: every frame gets processed on two cores


def matrix(tr):
    """4x4 of a geometry_msgs/Transform."""
    q = tr.rotation
    x, y, z, w = q.x, q.y, q.z, q.w
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = [tr.translation.x, tr.translation.y, tr.translation.z]
    return m


def set_transform(tr, m):
    tr.translation.x, tr.translation.y, tr.translation.z = m[:3, 3]
    r = m[:3, :3]
    w = math.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    tr.rotation.w = w
    tr.rotation.x = (r[2, 1] - r[1, 2]) / (4 * w)
    tr.rotation.y = (r[0, 2] - r[2, 0]) / (4 * w)
    tr.rotation.z = (r[1, 0] - r[0, 1]) / (4 * w)


def split_bag(src, part_a, part_b, part_b_restart):
    """Writes parts A and B of the robot bag (the static tree at the start of
    each), and B with its odometry started over (odom -> base_link the
    identity at B's first sample). Returns the bag's odom -> base_link by stamp."""
    import copy
    import rosbag
    with rosbag.Bag(src) as bag:
        msgs = list(bag.read_messages(return_connection_header=True))
    images = sorted(t.to_sec() for topic, _, t, _ in msgs if topic == '/camera/image_raw')
    cut = images[SPLIT] - 1e-6
    static = [m for m in msgs if m[0] == '/tf_static']
    rest = [m for m in msgs if m[0] != '/tf_static']
    odom = {}
    for topic, msg, _, _ in rest:
        if topic == '/tf':
            for tr in msg.transforms:
                if tr.header.frame_id == 'odom' and tr.child_frame_id == 'base_link':
                    odom[round(tr.header.stamp.to_sec(), 6)] = matrix(tr.transform)
    part_a_msgs = [m for m in rest if m[2].to_sec() < cut]
    part_b_msgs = [m for m in rest if m[2].to_sec() >= cut]
    b_odom = [odom[k] for k in sorted(odom) if k >= cut]
    restart = np.linalg.inv(b_odom[0])

    def write(path, part, odom_from=None):
        with rosbag.Bag(path, 'w') as out:
            t0 = part[0][2]
            for _, msg, _, header in static:
                out.write('/tf_static', msg, t0, connection_header=header)
            for topic, msg, t, header in part:
                if odom_from is not None and topic == '/tf':
                    msg = copy.deepcopy(msg)
                    for tr in msg.transforms:
                        if tr.header.frame_id == 'odom' and tr.child_frame_id == 'base_link':
                            set_transform(tr.transform, odom_from.dot(matrix(tr.transform)))
                out.write(topic, msg, t, connection_header=header)
    write(part_a, part_a_msgs)
    write(part_b, part_b_msgs)
    write(part_b_restart, part_b_msgs, restart)
    return odom


def read_tum(path):
    with open(path) as f:
        return np.array([[float(x) for x in line.split()] for line in f
                         if line.strip() and not line.startswith('#')])


def read_text(path):
    with open(path) as f:
        return f.read()


def read_ply_xyz(path):
    with open(path, 'rb') as f:
        n = 0
        while True:
            line = f.readline().decode().strip()
            if line.startswith('element vertex'):
                n = int(line.split()[2])
            if line == 'end_header':
                break
        raw = np.frombuffer(f.read(n * 15), dtype=np.uint8).reshape(n, 15)
    return raw[:, :12].copy().view(np.float32).reshape(n, 3)


class Sessions(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix='long3r_session_')
        cls.bag_a = os.path.join(cls.tmp, 'a.bag')
        cls.bag_b = os.path.join(cls.tmp, 'b.bag')
        cls.bag_r = os.path.join(cls.tmp, 'b_restart.bag')
        cls.odom = split_bag(os.path.join(DATA, 'robot.bag'), cls.bag_a, cls.bag_b, cls.bag_r)
        cls.port = free_port('localhost')
        cls.env = dict(os.environ, ROS_MASTER_URI='http://localhost:%d' % cls.port)
        cls.env.pop('ROS_IP', None)
        os.environ.update(cls.env)
        cls.core = subprocess.Popen(['roscore', '-p', str(cls.port)], env=cls.env,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        import rospy
        for _ in range(100):
            try:
                rospy.get_master().getPid()
                break
            except Exception:
                time.sleep(0.2)
        rospy.init_node('session_check', anonymous=True, disable_signals=True)
        from tf2_msgs.msg import TFMessage
        cls.parents = {}  # child frame -> every parent seen in /tf and /tf_static

        def on_tf(msg):
            for tr in msg.transforms:
                cls.parents.setdefault(tr.child_frame_id, set()).add(tr.header.frame_id)
        cls.tf_subs = [rospy.Subscriber(t, TFMessage, on_tf, queue_size=1000)
                       for t in ('/tf', '/tf_static')]

    @classmethod
    def tearDownClass(cls):
        cls.core.send_signal(signal.SIGINT)
        cls.core.wait(timeout=30)
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def run_part(self, bag, name, session_path='', odometry_continues=False, before_play=None):
        """Starts the nodes, plays `bag`, saves the outputs; returns the log."""
        import rospy
        from long3r_ros.srv import LoadSession, SaveMap, SaveSession, SaveTrajectory
        log_path = os.path.join(self.tmp, name + '.log')
        log = open(log_path, 'w')
        nodes = subprocess.Popen(
            ['roslaunch', '--wait', 'long3r_ros', 'session_nodes.launch',
             'session_path:=' + session_path,
             'session_odometry_continues:=' + ('true' if odometry_continues else 'false')],
            env=self.env, stdout=log, stderr=subprocess.STDOUT)
        try:
            rospy.wait_for_service('/long3r/save_session', timeout=120)
            sys.path.insert(0, os.path.join(ROOT, 'scripts'))
            from demo_record import FrameAccounting, bag_images
            accounting = FrameAccounting()
            if before_play:
                before_play(rospy.ServiceProxy('/long3r/load_session', LoadSession))
            frames = bag_images(bag)
            # Once the node takes images, and after a delay that lets it
            # connect to the player: rosbag sends to whoever is connected.
            subprocess.run([os.path.join(ROOT, 'scripts', 'play_when_subscribed.py'), '/camera/image_raw',
                            '--', '--clock', '--delay', '2', '--rate', str(RATE), '--quiet', bag],
                           env=self.env, check=True, timeout=600)
            # Every frame of the part handled (the last one after
            # flush_after_s), however loaded the machine.
            self.assertTrue(accounting.wait(frames, 600), accounting.describe(frames))
            out = {}
            for what, srv, ext in (('session', SaveSession, 'l3s'), ('map', SaveMap, 'ply'),
                                   ('trajectory', SaveTrajectory, 'txt')):
                path = os.path.join(self.tmp, '%s_%s.%s' % (name, what, ext))
                res = rospy.ServiceProxy('/long3r/save_' + what, srv)(path)
                self.assertTrue(res.success, res.message)
                out[what] = path
            return out, log_path
        finally:
            nodes.send_signal(signal.SIGINT)
            try:
                nodes.wait(timeout=60)
            except subprocess.TimeoutExpired:
                nodes.kill()
            log.close()

    def expect_odometry_poses(self, traj):
        for row in traj:
            T = self.odom.get(round(row[0], 6))
            self.assertIsNotNone(T, 'no odometry at the stamp %.6f' % row[0])
            self.assertLess(np.linalg.norm(T[:3, 3] - row[1:4]), 1e-4,
                            'pose at %.3f off the odometry: %s vs %s' % (row[0], row[1:4], T[:3, 3]))

    def test_sessions(self):
        first, _ = self.run_part(self.bag_a, 'run1')
        t1 = read_tum(first['trajectory'])
        self.assertGreaterEqual(len(t1), SPLIT - 2, 'run 1 posed too few frames')
        self.expect_odometry_poses(t1)
        map1 = read_ply_xyz(first['map'])
        self.assertGreater(len(map1), 1000)

        # A damaged file through the service: refused, the loaded session kept.
        damaged = os.path.join(self.tmp, 'damaged.l3s')
        with open(first['session'], 'rb') as f:
            data = f.read()
        with open(damaged, 'wb') as f:
            f.write(data[:len(data) // 3])

        def refuse(load):
            res = load(damaged)
            self.assertFalse(res.success)
            self.assertIn('damaged.l3s', res.message)
            self.assertIn('the running session is kept', res.message)

        second, log2 = self.run_part(self.bag_b, 'run2', first['session'], True, refuse)
        t2 = read_tum(second['trajectory'])
        self.assertGreater(len(t2), len(t1) + 10, 'part B added too few poses')
        np.testing.assert_allclose(t2[:len(t1)], t1, atol=1e-6,
                                   err_msg='the saved path changed in the new run')
        self.expect_odometry_poses(t2)
        map2 = read_ply_xyz(second['map'])
        missing = lost_points(map1, map2, 0.02)
        self.assertEqual(missing, 0, '%d of %d saved map points lost' % (missing, len(map1)))
        print('run 1: %d poses, %d map points; run 2 (continued): %d poses, %d map points'
              % (len(t1), len(map1), len(t2), len(map2)))
        self.assertIn('session loaded from ' + first['session'], read_text(log2))

        third, log3 = self.run_part(self.bag_r, 'run3', first['session'], False)
        t3 = read_tum(third['trajectory'])
        text = read_text(log3)
        self.assertIn('relocalised in the loaded session', text)
        self.assertGreater(len(t3), len(t1) + 10)
        np.testing.assert_allclose(t3[:len(t1)], t1, atol=1e-6)
        self.assertIn('odom', self.parents)
        for child, parents in self.parents.items():
            self.assertEqual(len(parents), 1, '%s has the parents %s' % (child, parents))
        print('run 3 (odometry restarted): %d poses; %s' % (
            len(t3), [l for l in text.splitlines() if 'relocalised' in l][0].strip()))


if __name__ == '__main__':
    unittest.main()
