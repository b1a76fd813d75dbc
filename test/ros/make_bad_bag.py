#!/usr/bin/python3
"""Writes a bag of hostile input from a normal one: two good frames, a frame
with an unsupported encoding, two frames of another size, then two frames whose
time goes backwards (a looped bag). The node must survive all of it and keep
publishing."""
import sys

import rosbag
import rospy


def main(src, dst):
    images = [m for _, m, _ in rosbag.Bag(src).read_messages(topics=['/camera/image_raw'])]
    assert len(images) >= 4, 'need at least 4 frames'
    out = []
    t0 = images[0].header.stamp.to_sec()

    def stamped(msg, t):
        msg.header.stamp = rospy.Time.from_sec(t)
        return msg

    out.append(stamped(images[0], t0))
    out.append(stamped(images[1], t0 + 0.1))
    bad = images[2]
    bad.encoding = '32FC1'  # 4 bytes per pixel: a consistent but unsupported image
    bad.step = bad.width * 4
    bad.data = bytes(bad.height * bad.step)
    out.append(stamped(bad, t0 + 0.2))
    for i, src_msg in enumerate(images[3:5]):  # half size: every other row and column
        w, h = src_msg.width, src_msg.height
        rows = [src_msg.data[r * src_msg.step:(r + 1) * src_msg.step] for r in range(0, h, 2)]
        src_msg.data = b''.join(bytes(row[c * 3:c * 3 + 3]) for row in rows for c in range(0, w, 2))
        src_msg.width, src_msg.height = (w + 1) // 2, (h + 1) // 2
        src_msg.step = src_msg.width * 3
        out.append(stamped(src_msg, t0 + 0.3 + 0.1 * i))
    for i, msg in enumerate(images[5:7]):  # back in time
        out.append(stamped(msg, t0 - 5.0 + 0.1 * i))
    with rosbag.Bag(dst, 'w') as bag:
        for k, msg in enumerate(out):
            # Record in arrival order so `rosbag play` sends them in this order.
            bag.write('/camera/image_raw', msg, rospy.Time.from_sec(t0 + 0.1 * k))


if __name__ == '__main__':
    main(sys.argv[1], sys.argv[2])
