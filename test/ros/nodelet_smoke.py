#!/usr/bin/python3
"""Smoke test: the Long3rNodelet loads in a manager, subscribes, and unloads cleanly."""
import sys
import time
import unittest

import rospy
import rostest
from nodelet.srv import NodeletList, NodeletUnload


class NodeletSmoke(unittest.TestCase):
    def test_load_and_unload(self):
        rospy.wait_for_service('/manager/list', timeout=30)
        list_srv = rospy.ServiceProxy('/manager/list', NodeletList)
        deadline = time.time() + 30
        while time.time() < deadline and '/long3r' not in list_srv().nodelets:
            time.sleep(0.2)
        self.assertIn('/long3r', list_srv().nodelets)

        # The nodelet subscribes to its input image topic.
        deadline = time.time() + 10
        subscribed = False
        while time.time() < deadline and not subscribed:
            master = rospy.get_master()
            _, _, state = master.getSystemState()
            subscribers = dict((t, n) for t, n in state[1])
            subscribed = '/image' in subscribers and '/manager' in subscribers['/image']
            time.sleep(0.2)
        self.assertTrue(subscribed, 'the manager does not subscribe to /image')

        unload = rospy.ServiceProxy('/manager/unload_nodelet', NodeletUnload)
        start = time.time()
        self.assertTrue(unload('/long3r').success)
        self.assertLess(time.time() - start, 5.0, 'unloading took too long (worker not joined?)')
        self.assertNotIn('/long3r', list_srv().nodelets)


if __name__ == '__main__':
    rospy.init_node('nodelet_smoke')
    rostest.rosrun('long3r_ros', 'nodelet_smoke', NodeletSmoke, sys.argv)
