#!/usr/bin/python3
"""Publishes map -> odom (the identity) on /tf at 10 Hz of wall time (also
while a replay's clock stands still), as amcl or a second SLAM node would: the
node under test must give way (robot_check.py --rival)."""
import time

import rospy
from geometry_msgs.msg import TransformStamped
from tf2_msgs.msg import TFMessage


def main():
    rospy.init_node('rival')
    pub = rospy.Publisher('/tf', TFMessage, queue_size=10)
    while not rospy.is_shutdown():
        t = TransformStamped()
        t.header.stamp = rospy.Time.now()
        t.header.frame_id = 'map'
        t.child_frame_id = 'odom'
        t.transform.rotation.w = 1.0
        pub.publish(TFMessage(transforms=[t]))
        time.sleep(0.1)


if __name__ == '__main__':
    main()
