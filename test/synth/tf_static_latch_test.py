#!/usr/bin/env python3
"""A robot bag's /tf_static reaches a tf2 listener that starts after rosbag play
has published it, as with a real recording (rosbag play latches a connection
recorded as latched). The same bag with the latching header removed must not
reach it: that is what the header is for. Runs its own rosmaster on a free port
(registered in synth.cmake where rospy and tf2_ros import)."""

import argparse
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import rosbag

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_test import fail, free_port, fresh_dir, load_script, run  # noqa: E402

LISTENER = r"""
import sys, rospy, tf2_ros
rospy.init_node("late_listener", anonymous=True, disable_signals=True)
buf = tf2_ros.Buffer()
tf2_ros.TransformListener(buf)
try:
    t = buf.lookup_transform("base_link", "camera_color_optical_frame", rospy.Time(0), rospy.Duration(float(sys.argv[1])))
except Exception as e:
    print("LOOKUP FAILED", type(e).__name__, e)
    sys.exit(3)
tr, q = t.transform.translation, t.transform.rotation
print("RESULT", tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w)
"""


def start(cmd, env, log):
    return subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def stop(proc):
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def late_lookup(bag, env, work, name, timeout):
    """Plays `bag` (kept alive past its end), waits until it has been played,
    then asks a fresh listener; returns the listener's output and exit code."""
    with open(os.path.join(work, name + "_play.log"), "w") as log:
        play = start(["rosbag", "play", "--keep-alive", "--quiet", bag], env, log)
        try:
            time.sleep(4.0)  # start-up plus the 0.2 s bag, with margin: /tf_static is long published
            if play.poll() is not None:
                fail("rosbag play exited early (%s)" % play.returncode)
            rc, out = run([sys.executable, "-c", LISTENER, str(timeout)], env=env, timeout=timeout + 30)
        finally:
            stop(play)
    return out, rc


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--synth", required=True)
    ap.add_argument("--script", required=True)
    ap.add_argument("--workdir", required=True)
    args = ap.parse_args()
    t2b = load_script(args.script, "tum_to_bag")

    work = fresh_dir(os.path.abspath(args.workdir))
    seq, bag = os.path.join(work, "seq"), os.path.join(work, "robot.bag")
    run([args.synth, "--out", seq, "--frames", "6", "--width", "32", "--height", "24", "--seed", "2",
         "--trajectory", "robot", "--quiet"], check=True)
    run([sys.executable, args.script, seq, bag, "--robot", "--time-offset", "1000"], check=True)
    # The control: every message as it is, the connection header rosbag's default.
    unlatched = os.path.join(work, "unlatched.bag")
    with rosbag.Bag(bag) as src, rosbag.Bag(unlatched, "w") as dst:
        for topic, msg, t in src.read_messages():
            dst.write(topic, msg, t)
    mount = t2b.read_pose_file(os.path.join(seq, "camera_mount.txt"))

    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI="http://127.0.0.1:%d" % port, ROS_HOSTNAME="127.0.0.1",
               ROS_HOME=os.path.join(work, "ros_home"), ROS_LOG_DIR=os.path.join(work, "ros_log"))
    env.pop("ROS_IP", None)
    with open(os.path.join(work, "master.log"), "w") as log:
        master = start(["rosmaster", "--core", "-p", str(port)], env, log)
        try:
            deadline = time.time() + 30
            while True:
                try:
                    socket.create_connection(("127.0.0.1", port), 1).close()
                    break
                except OSError:
                    if time.time() > deadline or master.poll() is not None:
                        fail("rosmaster did not start")
                    time.sleep(0.2)
            out, rc = late_lookup(bag, env, work, "latched", 10.0)
            if rc != 0 or "RESULT" not in out:
                fail("late listener did not get the latched /tf_static:\n" + out)
            v = [float(x) for x in out.split("RESULT", 1)[1].split()[:7]]
            got = t2b.pose_matrix(v[:3], v[3:])
            if not np.allclose(got, mount, atol=1e-9):
                fail("base_link -> optical frame from tf2 %s != camera_mount.txt %s" % (got, mount))
            out, rc = late_lookup(unlatched, env, work, "unlatched", 3.0)
            if rc == 0:
                fail("the control without latching was resolved too, so the test shows nothing:\n" + out)
        finally:
            stop(master)
    print("2 passed, 0 failed")


if __name__ == "__main__":
    main()
