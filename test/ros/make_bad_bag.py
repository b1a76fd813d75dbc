#!/usr/bin/python3
"""Writes a bag of hostile input from a normal one (arrival order, stamps):

  good t0, good t0+0.1, unsupported encoding t0+0.2 (skipped), one stray frame
  of twice the size t0+0.3 (dropped), good t0+0.4, half-size frames from
  t0+0.5 on (the first size_change_frames - 1 = 2 dropped, the third starts a
  new stream), then half-size frames back in time at t0-5 (a looped bag: a
  new stream).

The node must survive all of it, keep publishing, and publish exactly the
frames replay_check.py --mode bad expects."""
import copy
import sys

import rosbag
import rospy


def resized(msg, factor_num, factor_den):
    """Nearest-neighbour resize of an rgb8 image by factor_num / factor_den."""
    out = copy.deepcopy(msg)
    w, h = msg.width, msg.height
    out.width, out.height = w * factor_num // factor_den, h * factor_num // factor_den
    out.step = out.width * 3
    rows = []
    for r in range(out.height):
        src = msg.data[(r * factor_den // factor_num) * msg.step:][:msg.step]
        rows.append(b''.join(bytes(src[(c * factor_den // factor_num) * 3:][:3])
                             for c in range(out.width)))
    out.data = b''.join(rows)
    return out


def main(src, dst):
    images = [m for _, m, _ in rosbag.Bag(src).read_messages(topics=['/camera/image_raw'])]
    assert len(images) >= 8, 'need at least 8 frames'
    t0 = images[0].header.stamp.to_sec()

    def stamped(msg, t):
        msg = copy.deepcopy(msg)
        msg.header.stamp = rospy.Time.from_sec(t)
        return msg

    bad = copy.deepcopy(images[2])
    bad.encoding = '32FC1'  # 4 bytes per pixel: a consistent image that is not colour
    bad.step = bad.width * 4
    bad.data = bytes(bad.height * bad.step)
    half = [resized(images[k], 1, 2) for k in (5, 6, 7, 0, 1, 2)]
    out = [
        stamped(images[0], t0),
        stamped(images[1], t0 + 0.1),
        stamped(bad, t0 + 0.2),
        stamped(resized(images[3], 2, 1), t0 + 0.3),
        stamped(images[4], t0 + 0.4),
        stamped(half[0], t0 + 0.5),
        stamped(half[1], t0 + 0.6),
        stamped(half[2], t0 + 0.7),
        stamped(half[3], t0 + 0.8),
        stamped(half[4], t0 - 5.0),
        stamped(half[5], t0 - 4.9),
    ]
    with rosbag.Bag(dst, 'w') as bag:
        for k, msg in enumerate(out):
            # Record in arrival order so `rosbag play` sends them in this order.
            bag.write('/camera/image_raw', msg, rospy.Time.from_sec(t0 + 0.1 * k))


if __name__ == '__main__':
    main(sys.argv[1], sys.argv[2])
