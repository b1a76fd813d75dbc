#!/usr/bin/python3
"""Demo helper node: waits until the node has accounted for every frame of
the replay (~frames; FrameAccounting), saves the map through ~save_map and
the trajectory (TUM format) through ~save_trajectory, writes summary.json
(frames answered, with points (~pointmap) and with a pose (~pose), the
first frame in metres, the scale),
then exits (ending roslaunch). With ~frames 0 it waits for quiet instead:
no result for ~quiet_s after the first.

FrameAccounting is also what the rostests wait with: never for quiet, for
the frames they count.
"""
import json
import os
import sys
import threading
import time

import rospy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from long3r_ros.msg import Pointmap
from long3r_ros.srv import SaveMap, SaveTrajectory
from sensor_msgs.msg import CameraInfo

# The node's totals (node_status.cpp): every image it receives ends in one.
RECEIVED = 'frames received (total)'
PROCESSED = 'frames processed (total)'
NOT_PROCESSED = ('frames failed (total)', 'frames dropped: bad input (total)',
                 'frames dropped: queue full or cleared (total)', 'frames dropped: paused (total)')


# Where our bags carry their images (tum_to_bag.py; the compressed transport).
IMAGE_TOPICS = ('/camera/image_raw', '/camera/image_raw/compressed')


def bag_images(path, topics=IMAGE_TOPICS):
    """The images in a bag: what FrameAccounting.wait() is given to count."""
    import rosbag
    with rosbag.Bag(path) as bag:
        return sum(bag.get_message_count(t) for t in topics)


class FrameAccounting:
    """What the node has done with the images it was sent, from its
    /diagnostics totals, and the results that reached us: each processed
    frame's ~camera_info goes out with its result, posed or not. complete(n)
    holds once n images are accounted for (processed, failed or dropped), as
    many as the node received (none is pending: the last one goes out after
    flush_after_s), and every processed frame's ~camera_info has arrived, as of a diagnostics
    report that came a full report after the one that first said so (the
    node's other topics of those frames went out before either)."""

    def __init__(self, node='/long3r'):
        self._lock = threading.Lock()
        self.results = 0      # ~camera_info messages received
        self.processed = 0    # the node's totals, as last reported
        self.received = 0
        self.accounted = 0
        self._reports = 0     # diagnostics reports with the node's totals
        self._complete_at = None  # the report at which complete() first held
        self._subs = [
            rospy.Subscriber(node + '/camera_info', CameraInfo, self._on_result, queue_size=1000),
            rospy.Subscriber('/diagnostics', DiagnosticArray, self._on_diagnostics, queue_size=100)]

    def _on_result(self, _):
        with self._lock:
            self.results += 1

    def _on_diagnostics(self, msg):
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            if PROCESSED not in values:
                continue
            with self._lock:
                self.processed = int(values[PROCESSED])
                self.received = int(values.get(RECEIVED, 0))
                self.accounted = self.processed + sum(int(values.get(k, 0)) for k in NOT_PROCESSED)
                self._reports += 1

    def complete(self, frames):
        with self._lock:
            if (self.accounted < frames or self.accounted < self.received or
                    self.results < self.processed):
                self._complete_at = None
                return False
            if self._complete_at is None:
                self._complete_at = self._reports
            return self._reports > self._complete_at

    def wait(self, frames, timeout_s):
        """True once complete(frames); False after timeout_s (wall time)."""
        deadline = time.time() + timeout_s
        while time.time() < deadline and not rospy.is_shutdown():
            if self.complete(frames):
                return True
            time.sleep(0.2)
        return False

    def describe(self, frames):
        with self._lock:
            return ('%d of %d frames accounted for (%d received), %d results of %d processed '
                    'received' % (self.accounted, frames, self.received, self.results, self.processed))


def wait_for(pred, timeout_s, poll_s=0.05):
    """pred() once it holds, else its value after timeout_s. Wall time: a
    replayed bag's clock stops when the bag ends."""
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        if pred():
            return True
        time.sleep(poll_s)
    return pred()


def lookup_transform_wall(buffer, target, source, stamp, timeout_s):
    """tf2_ros.Buffer.lookup_transform with a timeout in wall time: tf2's own
    waits in ROS time, which stands still once a replayed bag's /clock has
    ended, so a transform not there yet would be waited for forever."""
    wait_for(lambda: buffer.can_transform(target, source, stamp), timeout_s, poll_s=0.01)
    return buffer.lookup_transform(target, source, stamp)  # raises if still not there


def write_json(path, value):
    tmp = path + '.tmp'
    with open(tmp, 'w') as f:
        json.dump(value, f, indent=1)
    os.replace(tmp, path)


def main():
    rospy.init_node('long3r_demo_record')
    out_dir = rospy.get_param('~out_dir')
    frames = int(rospy.get_param('~frames', 0))
    quiet_s = rospy.get_param('~quiet_s', 6.0)
    timeout_s = rospy.get_param('~timeout_s', 1800.0)
    os.makedirs(out_dir, exist_ok=True)
    lock = threading.Lock()
    state = {'posed': 0, 'poses': 0, 'first_metric': None, 'scale': None, 'scale_stddev': None}

    def on_pose(_):
        with lock:
            state['poses'] += 1

    def on_pointmap(p):
        with lock:
            if p.metric and state['first_metric'] is None:
                state['first_metric'] = state['posed']
            state['posed'] += 1
            state['scale'], state['scale_stddev'] = p.scale, p.scale_stddev

    rospy.Subscriber('/long3r/pointmap', Pointmap, on_pointmap, queue_size=1000)
    rospy.Subscriber('/long3r/pose', PoseStamped, on_pose, queue_size=1000)
    accounting = FrameAccounting()
    if frames > 0:
        if not accounting.wait(frames, timeout_s):
            rospy.logerr('demo: within %.0f s, %s', timeout_s, accounting.describe(frames))
            sys.exit(1)
    else:
        start, seen, last = time.time(), -1, time.time()
        while not rospy.is_shutdown():
            time.sleep(0.5)  # wall time: the bag's clock stops at its end
            if accounting.results != seen:
                seen, last = accounting.results, time.time()
            if seen > 0 and time.time() - last > quiet_s:
                break
            if time.time() - start > timeout_s:
                rospy.logerr('demo: nothing finished within %.0f s', timeout_s)
                sys.exit(1)
    rospy.wait_for_service('/long3r/save_map', timeout=10)
    res = rospy.ServiceProxy('/long3r/save_map', SaveMap)(os.path.join(out_dir, 'map.ply'))
    rospy.loginfo('save_map: %s', res.message)
    traj = rospy.ServiceProxy('/long3r/save_trajectory', SaveTrajectory)(
        os.path.join(out_dir, 'trajectory.txt'))
    rospy.loginfo('save_trajectory: %s', traj.message)
    with lock:
        summary = {'results': accounting.results, 'posed': state['posed'], 'poses': state['poses'],
                   'first_metric_frame': state['first_metric'], 'scale': state['scale'],
                   'scale_stddev': state['scale_stddev']}
    write_json(os.path.join(out_dir, 'summary.json'), summary)
    rospy.loginfo('demo: %d frames answered, %d posed', summary['results'], summary['posed'])
    sys.exit(0 if res.success and traj.success else 1)


if __name__ == '__main__':
    main()
