#!/usr/bin/python3
"""The launch files keep the user's config file: what `roslaunch --dump-params`
says each one sets.

Every argument of long3r.launch that names a node parameter is empty by
default ("as the config file says"): with `config:=` a file that sets each of
them to a value of its own, every launch file the package ships hands the node
the file's values; an argument given on the command line overrides its
parameter only. replay.launch and the example launch files take every
argument long3r.launch takes, and the examples remap the camera's topics
(checked through roslaunch's own loader). Needs the package on
ROS_PACKAGE_PATH (ctest runs it in the workspace's environment); no master.
"""
import os
import subprocess
import sys
import tempfile
import unittest
import xml.etree.ElementTree as ET

import yaml

import roslaunch.config

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LAUNCH = os.path.join(ROOT, 'launch')
NODE = '/long3r/'

# long3r.launch's arguments that set a node parameter of the same name, and a
# value for each that differs from the node's default (config/default.yaml).
PARAM_ARGS = {
    'model_path': '/models/user.safetensors',
    'session_path': '/sessions/user.long3r',
    'device': 'cuda:1',
    'precision': 'bfloat16',
    'queue_size': 17,
    'image_transport': 'compressed',
    'map_frame': 'user_map',
    'odom_frame': 'user_odom',
    'base_frame': 'user_base',
    'camera_frame': 'user_camera',
    'scale_source': 'fixed',
    'pose_source': 'odometry',
}
# Arguments each launch file needs, and the parameters it sets on purpose.
REQUIRED = {
    'long3r.launch': [],
    'replay.launch': ['bag:=/tmp/x.bag'],
    'demo.launch': ['bag:=/tmp/x.bag', 'out_dir:=/tmp/out'],
    'realsense.launch': [],
    'usb_camera.launch': [],
}
FIXED = {'demo.launch': {'queue_size': 1000}}


def launch_args(name):
    root = ET.parse(os.path.join(LAUNCH, name)).getroot()
    return {a.get('name') for a in root.findall('arg')}


def dump_params(name, *args):
    out = subprocess.run(['roslaunch', '--dump-params', os.path.join(LAUNCH, name)] + list(args),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True,
                         timeout=120)
    if out.returncode != 0:
        raise AssertionError('roslaunch --dump-params %s %s failed:\n%s' % (name, ' '.join(args), out.stderr))
    return yaml.safe_load(out.stdout)


def node_remaps(name, *args):
    config = roslaunch.config.load_config_default([(os.path.join(LAUNCH, name), list(args))], None)
    nodes = [n for n in config.nodes if n.name == 'long3r']
    assert len(nodes) == 1, [n.name for n in config.nodes]
    return dict(nodes[0].remap_args)


class LaunchParams(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory(prefix='long3r_launch_')
        cls.config = os.path.join(cls.tmp.name, 'user.yaml')
        with open(cls.config, 'w') as f:
            yaml.safe_dump(PARAM_ARGS, f)
        with open(os.path.join(ROOT, 'config', 'default.yaml')) as f:
            cls.defaults = yaml.safe_load(f)

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def test_user_values_differ_from_the_defaults(self):
        for name, value in PARAM_ARGS.items():
            self.assertIn(name, self.defaults, name)
            self.assertNotEqual(self.defaults[name], value, name)

    def test_every_launch_file_takes_every_argument(self):
        base = launch_args('long3r.launch')
        self.assertTrue(set(PARAM_ARGS) <= base, set(PARAM_ARGS) - base)
        for name in REQUIRED:
            self.assertTrue(base <= launch_args(name) or name == 'demo.launch',
                            '%s lacks %s' % (name, sorted(base - launch_args(name))))

    def test_the_config_file_is_kept(self):
        for name, required in REQUIRED.items():
            params = dump_params(name, 'config:=' + self.config, *required)
            for param, value in PARAM_ARGS.items():
                expected = FIXED.get(name, {}).get(param, value)
                self.assertEqual(params.get(NODE + param), expected, '%s: %s' % (name, param))

    def test_the_defaults_are_the_config_files(self):
        # Nothing given: the node's parameters are exactly the default config's.
        params = dump_params('long3r.launch')
        for param, value in self.defaults.items():
            self.assertEqual(params.get(NODE + param), value, param)
        self.assertEqual({k for k in params if k.startswith(NODE)},
                         {NODE + k for k in self.defaults})
        # The RealSense example: its own config (the depth scale), the node's
        # defaults otherwise.
        params = dump_params('realsense.launch')
        self.assertEqual({k: v for k, v in params.items() if k.startswith(NODE)},
                         {NODE + 'scale_source': 'depth'})

    def test_a_given_argument_overrides_only_its_parameter(self):
        given = {'queue_size': 3, 'map_frame': 'given_map', 'device': 'cpu', 'pose_source': 'model'}
        for name, required in REQUIRED.items():
            if name == 'demo.launch':
                continue  # takes the frame and source arguments only
            params = dump_params(name, 'config:=' + self.config, *required,
                                 *['%s:=%s' % kv for kv in given.items()])
            for param, value in PARAM_ARGS.items():
                self.assertEqual(params.get(NODE + param), given.get(param, value), '%s: %s' % (name, param))

    def test_rviz_fixed_frame_follows_the_units(self):
        # The node's map_frame defaults to map_model_units with scale_source
        # none (config/default.yaml), else map; rviz is started on it.
        def fixed_frame(name, *args):
            config = roslaunch.config.load_config_default(
                [(os.path.join(LAUNCH, name), ['rviz:=true'] + list(args))], None)
            rviz = [n for n in config.nodes if n.name == 'rviz']
            self.assertEqual(len(rviz), 1, name)
            words = rviz[0].args.split()
            return words[words.index('-f') + 1]
        self.assertEqual(fixed_frame('long3r.launch'), 'map_model_units')
        self.assertEqual(fixed_frame('long3r.launch', 'scale_source:=depth'), 'map')
        self.assertEqual(fixed_frame('long3r.launch', 'map_frame:=world'), 'world')
        self.assertEqual(fixed_frame('usb_camera.launch'), 'map_model_units')
        self.assertEqual(fixed_frame('replay.launch', 'bag:=/tmp/x.bag'), 'map_model_units')
        self.assertEqual(fixed_frame('realsense.launch'), 'map')
        self.assertEqual(fixed_frame('realsense.launch', 'scale_source:=none'), 'map_model_units')

    def test_topics_are_remapped(self):
        self.assertEqual(node_remaps('long3r.launch'), {
            'image': '/camera/image_raw', 'camera_info': '/camera/camera_info',
            'depth': '/camera/depth_registered/image_raw', 'odom': '/odom'})
        rs = node_remaps('realsense.launch')
        self.assertEqual(rs['image'], '/camera/color/image_raw')
        self.assertEqual(rs['camera_info'], '/camera/color/camera_info')
        self.assertEqual(rs['depth'], '/camera/aligned_depth_to_color/image_raw')
        self.assertEqual(node_remaps('realsense.launch', 'camera:=front')['image'], '/front/color/image_raw')
        usb = node_remaps('usb_camera.launch')
        self.assertEqual((usb['image'], usb['camera_info']), ('/usb_cam/image_raw', '/usb_cam/camera_info'))
        replay = node_remaps('replay.launch', 'bag:=/tmp/x.bag', 'image:=/front/image_raw')
        self.assertEqual(replay['image'], '/front/image_raw')


if __name__ == '__main__':
    unittest.main(argv=[sys.argv[0]] + sys.argv[1:])
