#!/usr/bin/python3
"""rosbag play, started once TOPIC (or one of its image_transport topics,
TOPIC/compressed, ...) has a subscriber: the bag begins when the node is
ready to take it, however long its start takes (Long3rNodelet subscribes
to its images last, after loading its model), rather than after a
fixed delay that a loaded machine can outlast (the first frames, or the whole
bag, would then go unseen).
  play_when_subscribed.py TOPIC [--timeout-s S] -- ROSBAG_PLAY_ARGUMENTS...
"""
import os
import sys
import time

import rosgraph
import rospy


def subscribed(master, topic):
    """TOPIC, or one of its image_transport topics (TOPIC/compressed, ...), has a subscriber."""
    _, subscribers, _ = master.getSystemState()
    return any((t == topic or t.startswith(topic + '/')) and nodes for t, nodes in subscribers)


def main():
    argv = rospy.myargv(argv=sys.argv)[1:]  # without roslaunch's __name:= and __log:=
    if '--' not in argv or argv.index('--') < 1:
        sys.exit(__doc__)
    ours, play = argv[:argv.index('--')], argv[argv.index('--') + 1:]
    topic, timeout_s = ours[0], 600.0
    if len(ours) == 3 and ours[1] == '--timeout-s':
        timeout_s = float(ours[2])
    elif len(ours) != 1:
        sys.exit(__doc__)
    master = rosgraph.Master('/play_when_subscribed')
    deadline = time.time() + timeout_s
    while not subscribed(master, topic):
        if time.time() > deadline:
            sys.exit('play_when_subscribed: nobody subscribed to %s within %.0f s' % (topic, timeout_s))
        time.sleep(0.2)
    os.execvp('rosbag', ['rosbag', 'play'] + play)


if __name__ == '__main__':
    main()
