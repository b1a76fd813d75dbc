#!/usr/bin/python3
"""Checks Long3rNodelet on a robot-like bag (tum_to_bag.py --robot: /tf_static
base_link -> camera_link -> optical frame, /tf odom -> base_link with
wheel-odometry error, camera_info, registered depth) replayed with base_frame
and odom_frame set:

  * every child frame in /tf and /tf_static has exactly one parent throughout;
  * ~odometry arrives for every posed frame (every ~pointmap) whose pose is
    in metres, with a symmetric positive-definite pose covariance: with
    --pose-source model none before the scale is metric (the poses are held
    in model units, as TF is; the diagnostics say so);
  * ~depth and ~camera_info through depth_image_proc's point_cloud_xyz give the
    same points as ~frame_cloud, to float precision (with --expect-unscaled:
    neither is published, they wait for a metric scale);
  * the saved map's floor is horizontal in map (normal within 5 degrees of +z),
    unless --no-floor;
  * --expect-metric: the scale source's estimate is applied (~pointmap says
    metric); --expect-unscaled: it is not (an inconsistent estimate is never
    adopted, the map stays in model units);
  * with --eval, the saved map is scored against the ground truth (long3r_eval,
    metrics.json under OUT/robot_MODE_eval) and, with --max-scale-error > 0,
    its Sim(3) scale must be within that of 1; with --max-ate-m > 0 the saved
    path's ATE must be below it and its Sim(3) scale within --max-scale-error
    of 1 (a path in metres);
  * map -> odom has one history: the nodelet's stamps only grow, as sent;
    map -> base resolves at each posed frame's stamp when its ~odometry
    arrives (inside the latency window), and later to the same transform;
  * with --rival (another node publishes map -> odom from the start), the
    nodelet publishes none, and its diagnostics name the other publisher;
  * with --odom-covariance (pose_source odometry), the covariance of each
    ~odometry is that of the bag's /odom message at its stamp (nearest within
    100 ms), turned into map by the published map -> odom;
  * with --placed-only (pose_source odometry, PnP failing after frame 0),
    every frame is placed by the odometry: ~odometry and ~path hold
    --min-frames poses, one parent per frame in TF, and at most frame 0 has a
    ~pointmap (no other frame's points are known);
  * with --grid, ~grid (subscribed from the start) is the occupancy grid of the
    room (the sequence's scene.json, brought into map by the first ground-truth
    base pose): the base's path free, the wall ahead occupied, and the occupied
    cells on the room's walls and furniture (within 0.5 m, the map's accuracy).
"""
import argparse
import json
import math
import os
import queue
import subprocess
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid, Odometry, Path
from sensor_msgs.msg import PointCloud2
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker

from long3r_ros.msg import Pointmap
from long3r_ros.srv import SaveMap, SaveMesh, SaveTrajectory

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', 'scripts'))
from demo_record import FrameAccounting, bag_images, lookup_transform_wall, wait_for  # noqa: E402

ARGS = None


def cloud_xyz(msg):
    """x, y, z of an organised PointCloud2 as an (H*W, 3) float32 array."""
    offsets = {f.name: f.offset for f in msg.fields}
    raw = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height * msg.width, msg.point_step)
    return np.stack([raw[:, offsets[c]:offsets[c] + 4].copy().view(np.float32)[:, 0]
                     for c in 'xyz'], axis=1)


def read_ply_xyz(path):
    with open(path, 'rb') as f:
        n, fmt = 0, None
        while True:
            line = f.readline().decode().strip()
            if line.startswith('format'):
                fmt = line.split()[1]
            if line.startswith('element vertex'):
                n = int(line.split()[2])
            if line == 'end_header':
                break
        assert fmt == 'binary_little_endian', fmt
        rec = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'),
                        ('r', 'u1'), ('g', 'u1'), ('b', 'u1')])
        return np.frombuffer(f.read(n * rec.itemsize), dtype=rec, count=n)


def floor_normal(points):
    """The floor: RANSAC on the lowest fifth of the map (height in map's z),
    then a least-squares plane through its inliers. Returns the unit normal."""
    rng = np.random.default_rng(1)
    low = points[points[:, 2] <= np.percentile(points[:, 2], 20)]
    best, best_inliers = None, -1
    thr = 0.03  # metres: the map is metric here
    for _ in range(300):
        p = low[rng.choice(len(low), 3, replace=False)]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        if np.linalg.norm(n) < 1e-12:
            continue
        n /= np.linalg.norm(n)
        inliers = np.abs((low - p[0]) @ n) < thr
        if inliers.sum() > best_inliers:
            best, best_inliers = inliers, inliers.sum()
    q = low[best]
    _, _, vt = np.linalg.svd(q - q.mean(axis=0))
    n = vt[2]
    return n if n[2] >= 0 else -n


def transform_tuple(t):
    return (t.translation.x, t.translation.y, t.translation.z,
            t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)


class Recorder:
    def __init__(self):
        self.lock = threading.Lock()
        self.parents, self.publishers, self.diagnostics = {}, {}, []
        self.pointmaps, self.odometry, self.clouds, self.dip = [], [], {}, {}
        rospy.Subscriber('/tf', TFMessage, self._tf, queue_size=1000)
        rospy.Subscriber('/diagnostics', DiagnosticArray, self._diagnostics, queue_size=100)
        rospy.Subscriber('/tf_static', TFMessage, self._tf, queue_size=100)
        rospy.Subscriber('/long3r/pointmap', Pointmap, self._add('pointmaps'), queue_size=100)
        rospy.Subscriber('/long3r/odometry', Odometry, self._add('odometry'), queue_size=100)
        self.pose_covs = []
        rospy.Subscriber('/long3r/pose_with_covariance', PoseWithCovarianceStamped,
                         self._add('pose_covs'), queue_size=100)
        rospy.Subscriber('/long3r/frame_cloud', PointCloud2, self._cloud('clouds'), queue_size=100)
        rospy.Subscriber('/dip_points', PointCloud2, self._cloud('dip'), queue_size=100)
        self.grids = []
        rospy.Subscriber('/long3r/grid', OccupancyGrid, self._add('grids'), queue_size=10)
        self.surfaces, self.meshes = [], []  # surface_enabled: ~surface and ~mesh
        rospy.Subscriber('/long3r/surface', PointCloud2, self._add('surfaces'), queue_size=10)
        rospy.Subscriber('/long3r/mesh', Marker, self._add('meshes'), queue_size=10)
        self.wheel = []  # the bag's odometry messages
        rospy.Subscriber('/odom', Odometry, self._add('wheel'), queue_size=1000)
        self.map_odom_rotations = []  # map -> odom as published, (x, y, z, w)
        self.map_odom_stamps = {}  # publisher -> the stamps of its map -> odom, as they arrived
        # map -> base looked up at each ~odometry's stamp within a second of
        # its arrival, on a thread of its own: a subscriber's callbacks run one
        # after another, so a lookup waiting there would hold back the next
        # ~odometry's recording.
        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(600))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.window_lookups = []  # (stamp, transform or the error's text)
        self.lookups_asked = 0
        self._to_look_up = queue.Queue()
        threading.Thread(target=self._look_up, daemon=True).start()
        self.units = []  # the diagnostics' units, as reported
        rospy.Subscriber('/long3r/odometry', Odometry, self._lookup, queue_size=100)

    def _tf(self, msg):
        caller = msg._connection_header.get('callerid', '?')
        with self.lock:
            for t in msg.transforms:
                if t.header.frame_id == 'map' and t.child_frame_id == ARGS.odom_frame:
                    r = t.transform.rotation
                    self.map_odom_rotations.append((r.x, r.y, r.z, r.w))
                    self.map_odom_stamps.setdefault(caller, []).append(t.header.stamp.to_nsec())
                self.parents.setdefault(t.child_frame_id, set()).add(t.header.frame_id)
                self.publishers.setdefault(t.child_frame_id, set()).add(caller)

    def _diagnostics(self, msg):
        with self.lock:
            for st in msg.status:
                if 'long3r' in st.name:
                    self.diagnostics.append(st.message)
                    self.units.extend(kv.value for kv in st.values if kv.key == 'units')

    def _lookup(self, msg):
        with self.lock:
            self.lookups_asked += 1
        self._to_look_up.put((msg.header.stamp, time.time()))

    def _look_up(self):
        while True:
            stamp, arrived = self._to_look_up.get()
            try:
                t = lookup_transform_wall(self.tf_buffer, 'map', ARGS.base_frame, stamp,
                                          arrived + 1.0 - time.time())
                found = transform_tuple(t.transform)
            except tf2_ros.TransformException as e:
                found = str(e)
            with self.lock:
                self.window_lookups.append((stamp, found))

    def lookups_done(self):
        with self.lock:
            return len(self.window_lookups) == self.lookups_asked

    def _add(self, name):
        def cb(msg):
            with self.lock:
                getattr(self, name).append(msg)
        return cb

    def _cloud(self, name):
        def cb(msg):
            with self.lock:
                getattr(self, name)[msg.header.stamp.to_nsec()] = cloud_xyz(msg)
        return cb

    def get(self, name):
        with self.lock:
            value = getattr(self, name)
            return dict(value) if isinstance(value, dict) else list(value)


def wait_for_every_frame(test, accounting):
    """Until the node has accounted for every image of the bag (--timeout)."""
    frames = bag_images(ARGS.bag)
    done = accounting.wait(frames, ARGS.timeout)
    rospy.loginfo('frame accounting: %s', accounting.describe(frames))
    test.assertTrue(done, 'the node did not account for every frame: ' + accounting.describe(frames))


class RobotCheck(unittest.TestCase):
    def test_robot(self):
        rec = Recorder()
        accounting = FrameAccounting()
        rospy.wait_for_service('/long3r/reset', timeout=120)
        if ARGS.placed_only:
            self.check_placed_only(rec, accounting)
            return
        wait_for_every_frame(self, accounting)
        pms = rec.get('pointmaps')
        self.assertGreaterEqual(len(pms), ARGS.min_frames, 'too few posed frames')

        # The scale source's verdict, as the last ~pointmap states it.
        last = pms[-1]
        rospy.loginfo('last ~pointmap: scale %.4f +- %.4f, metric %s',
                      last.scale, last.scale_stddev, last.metric)
        if ARGS.expect_metric:
            self.assertTrue(last.metric, 'no metric scale was applied')
            self.assertNotEqual(last.scale, 1.0)
        if ARGS.expect_unscaled:
            self.assertFalse(last.metric, 'an inconsistent scale estimate was applied')
            self.assertEqual(last.scale, 1.0)

        # One parent per frame, throughout.
        parents = rec.get('parents')
        rospy.loginfo('TF tree: %s', {c: sorted(p) for c, p in parents.items()})
        for child, ps in parents.items():
            self.assertEqual(len(ps), 1, '%s has parents %s' % (child, sorted(ps)))
        self.assertIn(ARGS.odom_frame, parents)
        self.assertEqual(parents[ARGS.odom_frame], {'map'})
        publishers = rec.get('publishers')
        rospy.loginfo('publishers of %s: %s', ARGS.odom_frame, publishers[ARGS.odom_frame])
        if ARGS.rival:
            self.assertEqual(publishers[ARGS.odom_frame], {'/rival'},
                             'the nodelet published map -> odom beside another publisher')
            named = [m for m in rec.get('diagnostics') if 'also published by /rival' in m]
            self.assertTrue(named, 'the diagnostics do not name the other publisher: %s'
                            % sorted(set(rec.get('diagnostics')))[:5])
        else:
            self.assertEqual(len(publishers[ARGS.odom_frame]), 1)
            self.check_tf_history(rec)

        # ~odometry for every posed frame in metres, with a PD covariance;
        # the model's poses in model units are held.
        held = [p for p in pms if ARGS.pose_source != 'odometry' and not p.metric]
        # The ~odometry of the last frames may still be on its way when their
        # ~pointmaps have been counted: wait for the messages checked, not for
        # quiet.
        wanted = {p.header.stamp.to_nsec() for p in pms if p not in held}

        def missing():
            return wanted - {o.header.stamp.to_nsec() for o in rec.get('odometry')}
        start = time.time()
        wait_for(lambda: not missing(), ARGS.timeout)
        rospy.loginfo('~odometry of %d posed frames in metres after %.1f s more, %d missing',
                      len(wanted), time.time() - start, len(missing()))
        odom = {o.header.stamp.to_nsec(): o for o in rec.get('odometry')}
        rospy.loginfo('%d of %d posed frames before the metric scale', len(held), len(pms))
        for p in held:
            self.assertNotIn(p.header.stamp.to_nsec(), odom,
                             '~odometry in model units at %.3f' % p.header.stamp.to_sec())
        if held:
            # Said in the diagnostics: their units (and their summary, unless
            # something more urgent, the rival, takes it).
            units = set(rec.get('units'))
            self.assertIn('none yet: outputs in metres held until the metric scale is known', units)
            said = [m for m in rec.get('diagnostics') if m.startswith('held until the metric scale is known')]
            if not ARGS.rival:
                self.assertTrue(said, 'the summary does not say the poses are held: %s'
                                % sorted(set(rec.get('diagnostics')))[:5])
            for m in said:
                self.assertIn('TF, ~pose, ~odometry', m)
        for p in pms:
            if p in held:
                continue
            o = odom.get(p.header.stamp.to_nsec())
            self.assertIsNotNone(o, 'no ~odometry for the frame at %.3f' % p.header.stamp.to_sec())
            self.assertEqual(o.header.frame_id, 'map')
            self.assertEqual(o.child_frame_id, ARGS.base_frame)
            c = np.array(o.pose.covariance).reshape(6, 6)
            self.assertTrue(np.allclose(c, c.T, atol=1e-12 * max(1.0, np.abs(c).max())))
            self.assertGreater(np.linalg.eigvalsh(c).min(), 0.0)
        # ~pose_with_covariance: the same pose and covariance, for robot_localization.
        pose_covs = {m.header.stamp.to_nsec(): m for m in rec.get('pose_covs')}
        for stamp, o in odom.items():
            m = pose_covs.get(stamp)
            self.assertIsNotNone(m, 'no ~pose_with_covariance beside ~odometry')
            self.assertEqual(m.header.frame_id, 'map')
            self.assertEqual(m.pose, o.pose)

        if ARGS.odom_covariance:
            self.check_odometry_covariance(rec, odom)
        if ARGS.grid:
            self.check_grid(rec)
        if ARGS.surface:
            self.check_surface(rec)

        # depth_image_proc's cloud of ~depth equals ~frame_cloud; with a scale
        # source, neither goes out before the scale is metric (publish_unscaled).
        clouds, dip = rec.get('clouds'), rec.get('dip')
        if ARGS.expect_unscaled:
            self.assertEqual((len(clouds), len(dip)), (0, 0),
                             '~frame_cloud or ~depth published in model units')
        else:
            self.expect_same_clouds(clouds, dip)

        # The saved map: floor level in map, and metric.
        map_path = os.path.join(ARGS.out, 'robot_%s_map.ply' % ARGS.mode)
        traj_path = os.path.join(ARGS.out, 'robot_%s_trajectory.txt' % ARGS.mode)
        self.assertTrue(rospy.ServiceProxy('/long3r/save_map', SaveMap)(map_path).success)
        self.assertTrue(rospy.ServiceProxy('/long3r/save_trajectory', SaveTrajectory)(traj_path)
                        .success)
        ply = read_ply_xyz(map_path)
        pts = np.stack([ply['x'], ply['y'], ply['z']], axis=1).astype(np.float64)
        n = floor_normal(pts)
        tilt = math.degrees(math.acos(min(1.0, abs(n[2]))))
        rospy.loginfo('floor normal %s: %.2f degrees from +z', n, tilt)
        if not ARGS.no_floor:
            self.assertLess(tilt, 5.0)
        if ARGS.eval:
            out = os.path.join(ARGS.out, 'robot_%s_eval' % ARGS.mode)
            run = subprocess.run([ARGS.eval, '--gt', ARGS.seq, '--gt-traj', ARGS.gt_traj,
                                  '--est-traj', traj_path, '--est-map', map_path, '--icp-scale',
                                  '--no-normals', '--gt-frame-step', '4', '--gt-pixel-step', '4',
                                  '--offset', str(-ARGS.time_offset), '--out', out],
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            rospy.loginfo('long3r_eval:\n%s', run.stdout)
            self.assertEqual(run.returncode, 0, 'long3r_eval failed')
            with open(os.path.join(out, 'metrics.json')) as f:
                metrics = json.load(f)
            scale = metrics['reconstruction']['sim3']['scale']
            rospy.loginfo('map Sim(3) scale against the ground truth: %.4f, Acc mean %.4f m',
                          scale, metrics['reconstruction']['accuracy_mean_m'])
            if ARGS.max_scale_error > 0:
                self.assertLess(abs(scale - 1.0), ARGS.max_scale_error,
                                'the map is not metric: Sim(3) scale %.4f' % scale)
            path = metrics['trajectory']
            rospy.loginfo('path: ATE %.4f m, Sim(3) scale against the ground truth %.4f',
                          path['ate_m']['rmse'], path['sim3']['scale'])
            if ARGS.max_ate_m > 0:
                self.assertLess(path['ate_m']['rmse'], ARGS.max_ate_m)
                self.assertLess(abs(path['sim3']['scale'] - 1.0), ARGS.max_scale_error,
                                'the path is not metric: Sim(3) scale %.4f' % path['sim3']['scale'])

    def check_surface(self, rec):
        """~surface and ~mesh in map, latched, coloured, on the map's points;
        ~save_mesh writes the mesh as a PLY with its triangles."""
        wait_for(lambda: rec.get('surfaces') and rec.get('meshes'), 30.0, poll_s=0.5)
        surfaces, meshes = rec.get('surfaces'), rec.get('meshes')
        self.assertTrue(surfaces, 'no ~surface')
        self.assertTrue(meshes, 'no ~mesh')
        surface, mesh = surfaces[-1], meshes[-1]
        self.assertEqual(surface.header.frame_id, 'map')
        self.assertEqual([f.name for f in surface.fields][:3], ['x', 'y', 'z'])
        self.assertIn('rgb', [f.name for f in surface.fields])
        points = cloud_xyz(surface)
        self.assertGreater(len(points), 1000)
        self.assertTrue(np.isfinite(points).all())
        self.assertEqual(mesh.header.frame_id, 'map')
        self.assertEqual(mesh.type, Marker.TRIANGLE_LIST)
        self.assertGreater(len(mesh.points), 0)
        self.assertEqual(len(mesh.points) % 3, 0)
        self.assertEqual(len(mesh.colors), len(mesh.points))
        # On the map: most surface points have map points within 10 cm (the
        # surface is the views' consensus, the map every view's points).
        map_path = os.path.join(ARGS.out, 'robot_%s_surface_map.ply' % ARGS.mode)
        self.assertTrue(rospy.ServiceProxy('/long3r/save_map', SaveMap)(map_path).success)
        ply = read_ply_xyz(map_path)
        cells = set(map(tuple, np.floor(np.stack([ply['x'], ply['y'], ply['z']], axis=1) / 0.1)
                        .astype(np.int64)))
        sample = points[::max(1, len(points) // 2000)]
        near = sum(any((c[0] + dx, c[1] + dy, c[2] + dz) in cells
                       for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1))
                   for c in np.floor(sample / 0.1).astype(np.int64))
        rospy.loginfo('~surface: %d points, %.1f %% beside the map; ~mesh: %d triangles',
                      len(points), 100.0 * near / len(sample), len(mesh.points) // 3)
        self.assertGreater(near, 0.9 * len(sample))
        mesh_path = os.path.join(ARGS.out, 'robot_%s_mesh.ply' % ARGS.mode)
        res = rospy.ServiceProxy('/long3r/save_mesh', SaveMesh)(mesh_path)
        self.assertTrue(res.success, res.message)
        with open(mesh_path, 'rb') as f:
            header = f.read(400).split(b'end_header')[0].decode()
        faces = [int(line.split()[2]) for line in header.splitlines()
                 if line.startswith('element face')]
        self.assertEqual(len(faces), 1, header)
        self.assertGreater(faces[0], 0)

    def check_tf_history(self, rec):
        """map -> odom goes out with growing stamps only, and map -> base
        resolves inside the latency window to what it resolves to later."""
        for caller, stamps in rec.get('map_odom_stamps').items():
            back = [(a, b) for a, b in zip(stamps, stamps[1:]) if b <= a]
            rospy.loginfo('map -> odom from %s: %d transforms, %d not after the previous one',
                          caller, len(stamps), len(back))
            self.assertFalse(back, 'map -> odom from %s went back in time: %s'
                             % (caller, ['%.3f after %.3f' % (b * 1e-9, a * 1e-9) for a, b in back[:5]]))
        self.assertTrue(wait_for(rec.lookups_done, ARGS.timeout),
                        'map -> %s lookups still pending' % ARGS.base_frame)
        lookups = rec.get('window_lookups')
        failed = [(s.to_sec(), f) for s, f in lookups if isinstance(f, str)]
        self.assertFalse(failed, 'map -> %s not found at posed frames\' stamps: %s'
                         % (ARGS.base_frame, failed[:3]))
        self.assertGreaterEqual(len(lookups), ARGS.min_frames)
        for stamp, found in lookups:
            later = transform_tuple(rec.tf_buffer.lookup_transform('map', ARGS.base_frame, stamp).transform)
            np.testing.assert_allclose(later, found, atol=1e-9,
                                       err_msg='map -> base at %.3f changed' % stamp.to_sec())

    def expect_same_clouds(self, clouds, dip):
        common = sorted(set(clouds) & set(dip))
        self.assertGreaterEqual(len(common), min(5, ARGS.min_frames))
        for stamp in common:
            a, b = clouds[stamp], dip[stamp]
            self.assertEqual(a.shape, b.shape)
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            ok = ~np.isnan(a)
            np.testing.assert_allclose(a[ok], b[ok], rtol=1e-6, atol=1e-7)

    def check_placed_only(self, rec, accounting):
        """PnP fails on every frame after the first: the odometry places them all."""
        paths = []
        rospy.Subscriber('/long3r/path', Path, lambda m: paths.append(m), queue_size=100)
        wait_for_every_frame(self, accounting)
        odom = {o.header.stamp.to_nsec(): o for o in rec.get('odometry')}
        pms = rec.get('pointmaps')
        rospy.loginfo('placed only: %d ~odometry, %d ~pointmap', len(odom), len(pms))
        self.assertGreaterEqual(len(odom), ARGS.min_frames, 'frames whose PnP failed were not placed')
        self.assertLessEqual(len(pms), 1, 'a frame without a PnP pose published points')
        self.assertTrue(paths, 'no ~path')
        self.assertEqual(len(paths[-1].poses), len(odom))
        for child, ps in rec.get('parents').items():
            self.assertEqual(len(ps), 1, '%s has parents %s' % (child, sorted(ps)))
        self.assertEqual(rec.get('parents')[ARGS.odom_frame], {'map'})
        if ARGS.odom_covariance:
            self.check_odometry_covariance(rec, odom)

    def check_odometry_covariance(self, rec, odom):
        """Each ~odometry's covariance is the wheel odometry's at its stamp, in map."""
        wheel = sorted(rec.get('wheel'), key=lambda m: m.header.stamp.to_sec())
        self.assertTrue(wheel, 'the bag has no /odom messages')
        rotations = rec.get('map_odom_rotations')
        self.assertTrue(rotations, 'no map -> odom was published')
        R = quaternion_matrix(rotations[-1])
        J = np.zeros((6, 6))
        J[:3, :3] = J[3:, 3:] = R
        stamps = np.array([m.header.stamp.to_sec() for m in wheel])
        checked = 0
        for o in odom.values():
            t = o.header.stamp.to_sec()
            i = int(np.argmin(np.abs(stamps - t)))
            self.assertLessEqual(abs(stamps[i] - t), 0.1, 'no /odom message near %.3f' % t)
            expected = J @ np.array(wheel[i].pose.covariance).reshape(6, 6) @ J.T
            got = np.array(o.pose.covariance).reshape(6, 6)
            np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max(),
                                       err_msg='~odometry at %.3f' % t)
            checked += 1
        rospy.loginfo('~odometry covariance: the wheel odometry\'s in map for %d frames '
                      '(last position std %.4f m)', checked,
                      math.sqrt(np.array(list(odom.values())[-1].pose.covariance)[0]))
        self.assertGreaterEqual(checked, ARGS.min_frames)

    def check_grid(self, rec):
        time.sleep(2.0)  # the grid of the last map (map_publish_period_s)
        grids = rec.get('grids')
        self.assertTrue(grids, 'no ~grid')
        g = grids[-1]
        self.assertEqual(g.header.frame_id, 'map')
        self.assertAlmostEqual(g.info.resolution, 0.05, places=6)
        cells = np.array(g.data, dtype=np.int8).reshape(g.info.height, g.info.width)
        res, ox, oy = g.info.resolution, g.info.origin.position.x, g.info.origin.position.y
        # map = odom = the base at the first frame: the ground truth in map.
        gt = np.loadtxt(ARGS.gt_traj)
        T0 = np.eye(4)
        T0[:3, :3] = quaternion_matrix(gt[0, 4:8])
        T0[:3, 3] = gt[0, 1:4]
        to_map = np.linalg.inv(T0)
        path = (to_map[:3, :3] @ gt[:, 1:4].T).T + to_map[:3, 3]

        def cell(x, y):
            i, j = int(math.floor((x - ox) / res)), int(math.floor((y - oy) / res))
            return cells[j, i] if 0 <= i < g.info.width and 0 <= j < g.info.height else -1
        # The base from the tenth frame on stands where the first frames' cameras looked.
        on_path = [cell(p[0], p[1]) for p in path[10:]]
        rospy.loginfo('~grid %dx%d: %d occupied, %d free; path cells %s', g.info.width,
                      g.info.height, (cells == 100).sum(), (cells == 0).sum(), on_path)
        self.assertNotIn(100, on_path, 'an occupied cell on the path')
        self.assertGreaterEqual(on_path.count(0), 0.8 * len(on_path), 'the path is not free')

        # Occupied cells: on a wall or a shape of the room, as far as the map is: its
        # points lie within 0.3 m of them for 79 % and 0.5 m for 98 % (the shipped
        # model's per-frame shape at 1-4 m), its occupied cells within 0.5 m for 94 %.
        scene = json.load(open(os.path.join(ARGS.seq, 'scene.json')))
        size = scene['room_size']
        to_world = T0
        jj, ii = np.nonzero(cells == 100)
        xy = np.stack([ox + (ii + 0.5) * res, oy + (jj + 0.5) * res, np.zeros(len(ii))], axis=1)
        w = (to_world[:3, :3] @ xy.T).T + to_world[:3, 3]

        def distance(p):
            d = min(abs(p[0]), abs(p[0] - size[0]), abs(p[1]), abs(p[1] - size[1]))
            for s in scene['shapes']:
                c, h = np.array(s['center'][:2]), np.array(s['half_size'][:2])
                q = np.abs(p[:2] - c) - h
                d = min(d, np.linalg.norm(np.maximum(q, 0.0)) + min(max(q[0], q[1]), 0.0))
            return d
        near = np.array([distance(p) <= 0.5 for p in w])
        far_wall = np.sum(np.abs(w[:, 1] - size[1]) <= 0.5)
        rospy.loginfo('~grid occupied cells near the room: %d of %d; on the far wall: %d',
                      near.sum(), len(near), far_wall)
        self.assertGreater(len(near), 20)
        self.assertGreaterEqual(near.mean(), 0.85, 'occupied cells off the walls and furniture')
        self.assertGreaterEqual(far_wall, 50, 'the wall ahead is not occupied')


def quaternion_matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


if __name__ == '__main__':
    parser = argparse.ArgumentParser()
    parser.add_argument('--mode', default='odometry')
    parser.add_argument('--min-frames', type=int, default=10)
    parser.add_argument('--timeout', type=float, default=400.0)
    parser.add_argument('--out', default='/tmp')
    parser.add_argument('--seq', default='')
    parser.add_argument('--bag', required=True, help='the bag replayed (its images are counted)')
    parser.add_argument('--gt-traj', default='')
    parser.add_argument('--eval', default='', help='long3r_eval to score the map with')
    parser.add_argument('--time-offset', type=float, default=1000.0)
    parser.add_argument('--base-frame', default='base_link')
    parser.add_argument('--odom-frame', default='odom')
    parser.add_argument('--max-scale-error', type=float, default=0.05,
                        help='with --eval; 0: report the scale without a bound')
    parser.add_argument('--no-floor', action='store_true')
    parser.add_argument('--expect-metric', action='store_true')
    parser.add_argument('--expect-unscaled', action='store_true')
    parser.add_argument('--grid', action='store_true')
    parser.add_argument('--surface', action='store_true',
                        help='surface_enabled: check ~surface, ~mesh and ~save_mesh')
    parser.add_argument('--odom-covariance', action='store_true')
    parser.add_argument('--placed-only', action='store_true')
    parser.add_argument('--rival', action='store_true')
    parser.add_argument('--pose-source', default='model', choices=['model', 'keyframes', 'odometry'])
    parser.add_argument('--max-ate-m', type=float, default=0.0,
                        help='with --eval: the saved path\'s ATE bound (0: not checked)')
    ARGS, rest = parser.parse_known_args(rospy.myargv()[1:])
    rospy.init_node('robot_check')
    rostest.rosrun('long3r_ros', 'robot_check', RobotCheck, [sys.argv[0]] + rest)
