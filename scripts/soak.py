#!/usr/bin/python3
"""Soak benchmark of the running node: streams N frames of a generated
sequence (a ping-pong walk through it, so the video never jumps) to
/camera/image_raw with camera_info at a fixed rate and wall-clock stamps,
and every --every frames prints the node's resident memory (VmRSS of the
process hosting the nodelet) and the latency of the results (result received
minus image stamp) over the last block. Started by scripts/soak.sh."""
import argparse
import glob
import os
import sys
import threading
import time
import xmlrpc.client

import numpy as np
import rosgraph
import rospy
from sensor_msgs.msg import CameraInfo, Image

import tum_to_bag  # the project's PNG and calibration readers (scripts/)


def rss_mib(pid):
    with open('/proc/%d/status' % pid) as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    return float('nan')


def node_pid(name):
    api = rosgraph.Master('/soak').lookupNode(name)
    code, _, pid = xmlrpc.client.ServerProxy(api).getPid('/soak')
    if code != 1:
        raise RuntimeError('cannot get the pid of ' + name)
    return pid


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument('--sequence', required=True, help='a long3r_synth folder')
    p.add_argument('--frames', type=int, default=10000)
    p.add_argument('--rate', type=float, default=8.0, help='frames per second sent')
    p.add_argument('--every', type=int, default=500)
    p.add_argument('--node', default='/long3r_manager', help='the process hosting the nodelet')
    args = p.parse_args(rospy.myargv()[1:])
    rospy.init_node('soak', disable_signals=True)

    frames = [tum_to_bag.read_png(f)
              for f in sorted(glob.glob(os.path.join(args.sequence, 'rgb', '*.png')))]
    fx, fy, cx, cy = tum_to_bag.read_calibration(os.path.join(args.sequence, 'calibration.txt')).K
    order = list(range(len(frames))) + list(range(len(frames) - 2, 0, -1))
    h, w = frames[0].shape[:2]

    lock = threading.Lock()
    latencies = []
    results = [0]

    def on_result(msg):
        with lock:
            latencies.append((rospy.Time.now() - msg.header.stamp).to_sec())
            results[0] += 1

    rospy.Subscriber('/long3r/camera_info', CameraInfo, on_result, queue_size=100)
    image_pub = rospy.Publisher('/camera/image_raw', Image, queue_size=5)
    info_pub = rospy.Publisher('/camera/camera_info', CameraInfo, queue_size=5)
    rospy.wait_for_service('/long3r/reset', timeout=120)
    pid = node_pid(args.node)
    while image_pub.get_num_connections() == 0:
        time.sleep(0.1)

    print('frames sent, results, RSS MiB, latency mean / max s (over the last %d results), '
          'wall s' % args.every)
    print('%6d %7d %8.1f %s %7.1f' % (0, 0, rss_mib(pid), '    -     /    -   ', 0.0))
    sys.stdout.flush()
    start = time.time()
    for k in range(1, args.frames + 1):
        stamp = rospy.Time.now()
        img = Image()
        img.header.stamp = stamp
        img.header.frame_id = 'camera'
        img.height, img.width, img.encoding, img.step = h, w, 'rgb8', 3 * w
        img.data = frames[order[k % len(order)]].tobytes()
        info = CameraInfo()
        info.header = img.header
        info.width, info.height, info.distortion_model = w, h, 'plumb_bob'
        info.D = [0.0] * 5
        info.K = [fx, 0, cx, 0, fy, cy, 0, 0, 1]
        info.R = [1, 0, 0, 0, 1, 0, 0, 0, 1]
        info.P = [fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0]
        info_pub.publish(info)
        image_pub.publish(img)
        if k % args.every == 0:
            with lock:
                block = latencies[-args.every:]
                n = results[0]
            lat = '%6.3f / %6.3f' % (np.mean(block), np.max(block)) if block else '  -  '
            print('%6d %7d %8.1f %s %7.1f' % (k, n, rss_mib(pid), lat, time.time() - start))
            sys.stdout.flush()
        next_t = start + k / args.rate
        time.sleep(max(0.0, next_t - time.time()))
    rospy.signal_shutdown('done')


if __name__ == '__main__':
    main()
