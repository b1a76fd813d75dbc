#!/usr/bin/python3
"""rosbag play, started once every TOPIC (or one of its image_transport
topics, TOPIC/compressed, ...) has a subscriber: the bag begins when the node
is ready to take it, however long its start takes (Long3rNodelet subscribes
to its images last, after loading its model), rather than after a fixed delay
that a loaded machine can outlast (the first frames, or the whole bag, would
then go unseen). TOPIC@NODE waits for NODE itself among TOPIC's subscribers:
a checker or recorder that counts the node's results must be listening before
the first of them goes out, or it waits for ones it never saw.
  play_when_subscribed.py TOPIC[@NODE]... [--timeout-s S] -- ROSBAG_PLAY_ARGUMENTS...
"""
import os
import sys
import time

import rosgraph
import rospy


def subscribed(state, wanted):
    """WANTED's topic (or one of its image_transport topics) has a subscriber,
    WANTED's node among them where it names one."""
    topic, _, node = wanted.partition('@')
    _, subscribers, _ = state
    return any((t == topic or t.startswith(topic + '/')) and nodes and (not node or node in nodes)
               for t, nodes in subscribers)


def main():
    argv = rospy.myargv(argv=sys.argv)[1:]  # without roslaunch's __name:= and __log:=
    if '--' not in argv or argv.index('--') < 1:
        sys.exit(__doc__)
    ours, play = argv[:argv.index('--')], argv[argv.index('--') + 1:]
    timeout_s = 600.0
    if '--timeout-s' in ours:
        i = ours.index('--timeout-s')
        if i + 1 >= len(ours):
            sys.exit(__doc__)
        timeout_s = float(ours[i + 1])
        del ours[i:i + 2]
    if not ours:
        sys.exit(__doc__)
    master = rosgraph.Master('/play_when_subscribed')
    deadline = time.time() + timeout_s
    while True:
        state = master.getSystemState()
        missing = [w for w in ours if not subscribed(state, w)]
        if not missing:
            break
        if time.time() > deadline:
            sys.exit('play_when_subscribed: within %.0f s, no subscriber to %s' % (timeout_s, ', '.join(missing)))
        time.sleep(0.2)
    os.execvp('rosbag', ['rosbag', 'play'] + play)


if __name__ == '__main__':
    main()
