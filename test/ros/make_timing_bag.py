#!/usr/bin/python3
"""Rewrites the times of a generated bag (tum_to_bag.py, --robot too) to test
the node against pauses and slow cameras:

  --pause-after K --pause-s S   a gap of S seconds after frame K (record time
                                 and stamps alike: `rosbag play` waits too)
  --period P                     one frame every P seconds (a slow camera)
"""
import argparse
import collections

import rosbag
import rospy


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument('src')
    p.add_argument('dst')
    p.add_argument('--pause-after', type=int, default=-1)
    p.add_argument('--pause-s', type=float, default=0.0)
    p.add_argument('--period', type=float, default=0.0)
    args = p.parse_args()

    messages = list(rosbag.Bag(args.src).read_messages())
    stamps = sorted({m.header.stamp.to_sec() for topic, m, _ in messages
                     if topic == '/camera/image_raw'})
    t0 = stamps[0]
    new_time = {}
    for k, s in enumerate(stamps):
        t = t0 + (k * args.period if args.period > 0 else s - t0)
        if 0 <= args.pause_after < k:
            t += args.pause_s
        new_time[s] = t

    def retime(t):
        if args.period > 0:  # every message goes with the frame nearest in time
            return rospy.Time.from_sec(new_time[min(new_time, key=lambda s: abs(s - t))])
        # A pause shifts everything after frame K (odometry at its own rate too).
        late = 0 <= args.pause_after < len(stamps) and t > stamps[args.pause_after] + 1e-6
        return rospy.Time.from_sec(t + (args.pause_s if late else 0.0))

    counts = collections.Counter()
    with rosbag.Bag(args.dst, 'w') as bag:
        for topic, msg, t in messages:
            if topic in ('/tf', '/tf_static'):
                for tr in msg.transforms:
                    tr.header.stamp = retime(tr.header.stamp.to_sec())
                when = msg.transforms[0].header.stamp
            else:
                msg.header.stamp = retime(msg.header.stamp.to_sec())
                when = msg.header.stamp
            bag.write(topic, msg, when)
            counts[topic] += 1
    print('wrote %s: %s' % (args.dst, dict(counts)))


if __name__ == '__main__':
    main()
