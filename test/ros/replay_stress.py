#!/usr/bin/python3
"""Replays a robot-like bag (simulated time, /tf_static, wheel odometry on
/tf, registered depth) through demo.launch again and again, each time from a
cold start (a new master, a new nodelet manager, the model loaded anew), and
checks that every frame of the bag got a pose each time: the start-up (the
clock, the first TF, the model's load against the bag's start) must never
leave a replay without poses. The robot's settings: pose_source odometry,
scale_source depth, as the README's robot recipe.
  replay_stress.py --bag B --frames N [--runs R] [--model M] [--work DIR]
CI runs it three times (ros_replay_stress); by hand, --runs 20.
"""
import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'support'))
from cli_test import free_port  # noqa: E402


def replay(args, run):
    out = os.path.join(args.work, 'run_%02d' % run)
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    port = free_port('localhost')
    env = dict(os.environ, ROS_MASTER_URI='http://localhost:%d' % port)
    env.pop('ROS_IP', None)
    cmd = ['roslaunch', '-p', str(port), 'long3r_ros', 'demo.launch', 'bag:=' + args.bag,
           'out_dir:=' + out, 'frames:=%d' % args.frames, 'odom_frame:=odom', 'base_frame:=base_link',
           'pose_source:=odometry', 'scale_source:=depth', 'depth:=' + args.depth_topic]
    if args.model:
        cmd.append('model_path:=' + args.model)
    start = time.time()
    with open(os.path.join(out, 'roslaunch.log'), 'w') as log:
        # Its own process group: a replay that overruns ends with all its
        # nodes (roslaunch first, as Ctrl-C would; then the whole group).
        launch = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                                  start_new_session=True)
        try:
            rc = launch.wait(timeout=args.timeout_s)
        except subprocess.TimeoutExpired:
            launch.send_signal(signal.SIGINT)
            try:
                launch.wait(timeout=30)
            except subprocess.TimeoutExpired:
                pass
            os.killpg(launch.pid, signal.SIGKILL)
            launch.wait()
            rc = 'timed out after %.0f s' % args.timeout_s
    seconds = time.time() - start
    try:
        with open(os.path.join(out, 'summary.json')) as f:
            summary = json.load(f)
    except OSError:
        summary = {}
    return rc, summary, seconds, out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--bag', required=True)
    ap.add_argument('--frames', type=int, required=True, help='images in the bag')
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--model', default='', help='default: the package\'s shipped model')
    ap.add_argument('--depth-topic', default='/camera/depth/image_raw')
    ap.add_argument('--work', default='/tmp/long3r_replay_stress')
    ap.add_argument('--timeout-s', type=float, default=900.0, help='per replay')
    args = ap.parse_args()
    args.bag = os.path.abspath(args.bag)  # roslaunch runs its nodes in ROS_HOME
    failed = []
    for run in range(args.runs):
        rc, s, seconds, out = replay(args, run)
        ok = rc == 0 and s.get('results') == args.frames and s.get('poses') == args.frames
        print('replay %d of %d: %s in %.0f s: %s of %d frames answered, %s posed (%s)'
              % (run + 1, args.runs, 'ok' if ok else 'FAILED (roslaunch: %s)' % rc, seconds,
                 s.get('results'), args.frames,
                 s.get('poses'), out), flush=True)
        if not ok:
            failed.append(run + 1)
    print('%d of %d replays posed every frame' % (args.runs - len(failed), args.runs))
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
