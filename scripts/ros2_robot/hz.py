#!/usr/bin/env python3
"""What ``ros2 topic hz TOPIC`` does, as a plain rclpy script (no ``ros2`` CLI wheel exists).

    hz.py /usb_cam/image_raw [--type sensor_msgs/msg/Image] [--window 10000]

Subscribes without deserializing (``raw=True``, as ``ros2 topic hz`` does), keeps the
arrival times of the last ``--window`` messages and prints the average rate, min, max and
standard deviation of the period once a second: the baseline the black box's overhead is
compared with in ``benchmarks/ros2_overhead.py``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import itertools
import statistics
import time
from collections import deque

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("topic")
    parser.add_argument("--type", default="sensor_msgs/msg/Image")
    parser.add_argument("--window", type=int, default=10000)
    args = parser.parse_args()
    pkg, _, name = args.type.split("/")
    msg_type = getattr(importlib.import_module(f"{pkg}.msg"), name)
    rclpy.init()
    node = Node("hz")
    times: deque[float] = deque(maxlen=args.window)
    node.create_subscription(msg_type, args.topic, lambda _: times.append(time.monotonic()),
                             10, raw=True)

    def report() -> None:
        if len(times) < 2:
            print("no new messages", flush=True)
            return
        ts = list(times)
        periods = [b - a for a, b in itertools.pairwise(ts)]
        mean = statistics.fmean(periods)
        print(f"average rate: {1 / mean:.3f}\n\tmin: {min(periods):.3f}s max: "
              f"{max(periods):.3f}s std dev: {statistics.pstdev(periods):.5f}s window: "
              f"{len(ts)}", flush=True)

    node.create_timer(1.0, report)
    rclpy.spin(node)


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
        main()
