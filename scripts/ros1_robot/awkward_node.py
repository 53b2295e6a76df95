#!/usr/bin/python3
"""A rospy node that is healthy but awkward to watch, for the black box's bad-input tests.

    awkward_node.py burst [--topic /burst] [--count 100] [--every 1.0]
    awkward_node.py slow_api [--topic /slow] [--rate 10] [--delay 1.5]
    awkward_node.py steady [--topic /flaky] [--rate 10]

- ``burst``: sends ``--count`` messages at once every ``--every`` seconds (a sensor driver
  that flushes a buffer), std_msgs/UInt32 counting up.
- ``slow_api``: publishes at ``--rate`` Hz while every call of its slave XML-RPC API
  (``getPid``, ``getBusStats``, ``requestTopic``, ...) answers only after ``--delay``
  seconds (a node whose XML-RPC thread is starved or blocked).
- ``steady``: publishes at ``--rate`` Hz; the test restarts it every few seconds (a
  publisher that keeps crashing and being respawned).

The node name is ``/<role>_node`` unless ``__name:=`` says otherwise. Runs under Debian's
``/usr/bin/python3`` (where rospy lives).
"""

import argparse
import functools
import sys
import time

import rospy
import rospy.impl.masterslave
from std_msgs.msg import UInt32

SLAVE_API = ("getPid", "getBusStats", "getBusInfo", "getMasterUri", "getSubscriptions",
             "getPublications", "requestTopic", "paramUpdate", "publisherUpdate")


def _slowed(method, delay):
    @functools.wraps(method)
    def slow(*args, **kwargs):
        time.sleep(delay)
        return method(*args, **kwargs)
    return slow


def main(argv):
    p = argparse.ArgumentParser()
    p.add_argument("role", choices=("burst", "slow_api", "steady"))
    p.add_argument("--topic")
    p.add_argument("--count", type=int, default=100)
    p.add_argument("--every", type=float, default=1.0)
    p.add_argument("--rate", type=float, default=10.0)
    p.add_argument("--delay", type=float, default=1.5)
    args = p.parse_args(rospy.myargv(argv)[1:])
    topic = args.topic or {"burst": "/burst", "slow_api": "/slow", "steady": "/flaky"}[args.role]
    if args.role == "slow_api":
        handler = rospy.impl.masterslave.ROSHandler
        for name in SLAVE_API:
            setattr(handler, name, _slowed(getattr(handler, name), args.delay))
    rospy.init_node(f"{args.role}_node", disable_signals=False)
    pub = rospy.Publisher(topic, UInt32, queue_size=max(args.count * 2, 10))
    n = 0
    if args.role == "burst":
        next_t = time.monotonic()
        while not rospy.is_shutdown():
            for _ in range(args.count):
                pub.publish(UInt32(n % 2**32))
                n += 1
            next_t += args.every
            time.sleep(max(0.0, next_t - time.monotonic()))
        return 0
    period = 1.0 / args.rate
    next_t = time.monotonic()
    while not rospy.is_shutdown():
        pub.publish(UInt32(n % 2**32))
        n += 1
        next_t += period
        time.sleep(max(0.0, next_t - time.monotonic()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
