#!/usr/bin/python3
"""Demo helper node: waits until the replay is over (no new pose for a while,
after the flush of the last frame), saves the map through ~save_map, writes the
estimated trajectory (TUM format) from ~path, then exits (ending roslaunch)."""
import os
import sys
import time

import rospy
from nav_msgs.msg import Path
from long3r_ros.msg import Pointmap
from long3r_ros.srv import SaveMap


def main():
    rospy.init_node('long3r_demo_record')
    out_dir = rospy.get_param('~out_dir')
    quiet_s = rospy.get_param('~quiet_s', 6.0)
    timeout_s = rospy.get_param('~timeout_s', 1800.0)
    os.makedirs(out_dir, exist_ok=True)
    state = {'path': None, 'frames': 0, 'last': time.time()}

    def on_path(msg):
        state['path'] = msg

    def on_pointmap(_):
        state['frames'] += 1
        state['last'] = time.time()

    rospy.Subscriber('/long3r/path', Path, on_path, queue_size=10)
    rospy.Subscriber('/long3r/pointmap', Pointmap, on_pointmap, queue_size=100)
    start = time.time()
    while not rospy.is_shutdown():
        time.sleep(0.5)  # wall time: the bag's clock stops at its end
        if state['frames'] > 0 and time.time() - state['last'] > quiet_s:
            break
        if time.time() - start > timeout_s:
            rospy.logerr('demo: nothing finished within %.0f s', timeout_s)
            sys.exit(1)
    rospy.wait_for_service('/long3r/save_map', timeout=10)
    res = rospy.ServiceProxy('/long3r/save_map', SaveMap)(os.path.join(out_dir, 'map.ply'))
    rospy.loginfo('save_map: %s', res.message)
    traj = os.path.join(out_dir, 'trajectory.txt')
    poses = state['path'].poses if state['path'] else []
    with open(traj + '.tmp', 'w') as f:
        f.write('# timestamp tx ty tz qx qy qz qw (T_W_C, world = camera 0)\n')
        for p in poses:
            q, t = p.pose.orientation, p.pose.position
            f.write('%.6f %.6f %.6f %.6f %.6f %.6f %.6f %.6f\n' % (
                p.header.stamp.to_sec(), t.x, t.y, t.z, q.x, q.y, q.z, q.w))
    os.replace(traj + '.tmp', traj)
    rospy.loginfo('demo: %d frames published, %d poses written to %s', state['frames'],
                  len(poses), traj)
    sys.exit(0 if res.success else 1)


if __name__ == '__main__':
    main()
