#!/usr/bin/python3
"""A nodelet that cannot start ends `roslaunch long3r_ros long3r.launch`, and
the last line the nodelet wrote names the file and the reason.

Each case launches long3r.launch on its own master port with a bad
model_path (missing, a directory, a FIFO, a truncated or corrupt file) or an
invalid parameter, and checks that roslaunch ends by itself (the nodelet is
required) well before the timeout, and what it printed.
"""
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'support'))
from cli_test import free_port  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MODEL = os.path.join(ROOT, 'models', 'default.safetensors')
TIMEOUT_S = 120


def launch(*args):
    port = free_port('localhost')
    env = dict(os.environ, ROS_MASTER_URI='http://localhost:%d' % port)
    env.pop('ROS_IP', None)
    proc = subprocess.run(['roslaunch', '-p', str(port), 'long3r_ros', 'long3r.launch'] + list(args),
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
                          timeout=TIMEOUT_S, universal_newlines=True)
    return proc.stdout


class StartupFaults(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix='long3r_startup_')

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def expect_fault(self, reason, *args, path=None):
        out = launch(*args)
        self.assertIn('REQUIRED process', out, 'the launch did not end on the fault:\n' + out[-3000:])
        before = out.split('REQUIRED process')[0].splitlines()
        # The nodelet's last word, before the loader's generic "Failed to load
        # nodelet" and roslaunch's banner: what failed, naming the file.
        fatal = [l for l in before if 'FATAL' in l]
        self.assertTrue(fatal, 'no FATAL line:\n' + out[-3000:])
        self.assertIn('Failed to load nodelet', fatal[-1])
        ours = [l for l in fatal if 'Failed to load nodelet' not in l]
        self.assertEqual(len(ours), 1, ours)
        for text in ([path] if path else []) + [reason]:
            self.assertIn(text, ours[0])

    def model_file(self, name, data):
        path = os.path.join(self.tmp, name)
        with open(path, 'wb') as f:
            f.write(data)
        return path

    def test_missing_file(self):
        path = os.path.join(self.tmp, 'absent.safetensors')
        self.expect_fault('cannot open', 'model_path:=' + path, path=path)

    def test_directory(self):
        path = os.path.join(self.tmp, 'a_directory.safetensors')
        os.mkdir(path)
        self.expect_fault('is a directory', 'model_path:=' + path, path=path)

    def test_fifo(self):
        path = os.path.join(self.tmp, 'fifo.safetensors')
        os.mkfifo(path)
        self.expect_fault('not a regular file', 'model_path:=' + path, path=path)

    def test_truncated(self):
        with open(MODEL, 'rb') as f:
            data = f.read()
        path = self.model_file('truncated.safetensors', data[:len(data) // 2])
        self.expect_fault('truncated.safetensors', 'model_path:=' + path, path=path)

    def test_corrupt_header(self):
        path = self.model_file('corrupt.safetensors', b'\xff' * 64)
        self.expect_fault('header length', 'model_path:=' + path, path=path)

    def test_session_that_cannot_continue(self):
        # A truncated session file, and a model checkpoint given as a session.
        with open(MODEL, 'rb') as f:
            data = f.read()
        path = self.model_file('truncated.l3s', data[:100])
        self.expect_fault('cannot continue the session', 'session_path:=' + path, path=path)
        self.expect_fault('not a long3r session file', 'session_path:=' + MODEL, path=MODEL)

    def test_invalid_parameter(self):
        self.expect_fault('queue_size must be in [1, 1000]', 'queue_size:=0')


if __name__ == '__main__':
    unittest.main()
