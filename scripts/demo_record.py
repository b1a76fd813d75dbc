#!/usr/bin/python3
"""Demo helper node: waits until the replay is over (no new pose for a while,
after the last frame was published), saves the map through ~save_map and the
trajectory (TUM format) through ~save_trajectory, then exits (ending
roslaunch)."""
import os
import sys
import time

import rospy
from long3r_ros.msg import Pointmap
from long3r_ros.srv import SaveMap, SaveTrajectory


def main():
    rospy.init_node('long3r_demo_record')
    out_dir = rospy.get_param('~out_dir')
    quiet_s = rospy.get_param('~quiet_s', 6.0)
    timeout_s = rospy.get_param('~timeout_s', 1800.0)
    os.makedirs(out_dir, exist_ok=True)
    state = {'frames': 0, 'last': time.time()}

    def on_pointmap(_):
        state['frames'] += 1
        state['last'] = time.time()

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
    traj = rospy.ServiceProxy('/long3r/save_trajectory', SaveTrajectory)(
        os.path.join(out_dir, 'trajectory.txt'))
    rospy.loginfo('save_trajectory: %s', traj.message)
    rospy.loginfo('demo: %d frames published', state['frames'])
    sys.exit(0 if res.success and traj.success else 1)


if __name__ == '__main__':
    main()
