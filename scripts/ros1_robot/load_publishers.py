#!/usr/bin/python3
"""A rospy node publishing many std_msgs/Float64 topics, for load benchmarks.

    load_publishers.py --name /load0 --topics 25 --rate 100 [--prefix /load0/t] [--wave]

One loop publishes every topic once per period, so the process keeps ``topics * rate``
messages per second as long as it has the CPU for it. Every message carries 1.0, or with
``--wave`` one slow sine of the wall clock plus a little noise, so the topics of every process
measure one motion (what relation benchmarks need).
"""

import argparse
import math
import random
import time

import rospy
from std_msgs.msg import Float64


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--name", required=True)
    parser.add_argument("--topics", type=int, default=25)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--prefix", default=None)
    parser.add_argument("--wave", action="store_true")
    args, _ = parser.parse_known_args()
    rospy.init_node(args.name.strip("/"), anonymous=False)
    prefix = args.prefix or f"{args.name}/t"
    pubs = [rospy.Publisher(f"{prefix}{i}", Float64, queue_size=10) for i in range(args.topics)]
    msg = Float64(1.0)
    period = 1.0 / args.rate
    next_t = time.monotonic()
    while not rospy.is_shutdown():
        for p in pubs:
            if args.wave:
                msg.data = math.sin(0.5 * time.time()) + random.gauss(0.0, 0.01)
            p.publish(msg)
        next_t += period
        delay = next_t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            next_t = time.monotonic()


if __name__ == "__main__":
    main()
