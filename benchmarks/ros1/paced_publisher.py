#!/usr/bin/python3
"""A rospy node publishing std_msgs/Float64 topics at an exact long-run rate, for benchmarks.

    paced_publisher.py --name /pace0 --topics 10 --rate 100 [--prefix /pace0/t]

Unlike a sleep-per-period loop it never gives up lost time: each wake-up publishes every
message due since the start (``int(elapsed * rate)``), so the true rate over a second is
the nominal one as long as the CPU suffices, and what was really sent is known. Once a
second it prints ``<wall time> <messages sent per topic>`` on stdout, which the benchmark
reads to get the true rate over its own window.
"""

import argparse
import sys
import time

import rospy
from std_msgs.msg import Float64


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--name", required=True)
    parser.add_argument("--topics", type=int, default=1)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--prefix", default=None)
    parser.add_argument("--tick", type=float, default=0.001, help="seconds between wake-ups")
    args, _ = parser.parse_known_args()
    rospy.init_node(args.name.strip("/"), anonymous=False)
    prefix = args.prefix or f"{args.name}/t"
    pubs = [rospy.Publisher(f"{prefix}{i}", Float64, queue_size=1000)
            for i in range(args.topics)]
    msg = Float64(1.0)
    t0 = time.monotonic()
    wall0 = time.time()
    sent = 0
    next_report = 1.0
    while not rospy.is_shutdown():
        elapsed = time.monotonic() - t0
        due = int(elapsed * args.rate)
        while sent < due:
            for p in pubs:
                p.publish(msg)
            sent += 1
        if elapsed >= next_report:
            next_report += 1.0
            sys.stdout.write(f"{wall0 + elapsed:.6f} {sent}\n")
            sys.stdout.flush()
        time.sleep(args.tick)


if __name__ == "__main__":
    main()
