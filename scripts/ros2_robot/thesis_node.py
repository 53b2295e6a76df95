#!/usr/bin/env python3
"""One node of the thesis robot (section 6.2.1) as a real rclpy node, or a helper node.

    thesis_node.py camera|audio|signal [--rate HZ] [--reliability reliable|best_effort]
    thesis_node.py listener --topic /signal [--reliability reliable|best_effort]
    thesis_node.py load --topics 100 --rate 100

Runs under a Python with the ``ros-rclpy`` wheels (the project's venv). Each publisher
re-reads its parameters ``rate`` (Hz), and for the signal ``offset`` and ``scale``, every
cycle, so the fault injector changes them at run time with a plain ROS 2
``set_parameters`` call. The same graph as the ROS 1 robot (``scripts/ros1_robot``):

- camera: ``/usb_cam`` publishes ``/usb_cam/image_raw`` (sensor_msgs/Image 640x480 rgb8) at 15 Hz
- audio: ``/audio_capture`` publishes ``/audio`` (std_msgs/UInt8MultiArray, 480 bytes) at 33.3 Hz
- signal: ``/Signal_generator`` subscribes to both and publishes ``/signal``
  (std_msgs/Float64, offset + scale * (15 +- 0.5 uniform)) at 15 Hz
- listener: ``/listener`` subscribes to ``--topic`` (std_msgs/Float64) and prints a line
  per message (tests use it to make an incompatible-QoS pair)
- load: ``--name`` (default ``load_publishers``) publishes Float64 on ``/NAME/t0`` ... at
  ``--rate`` each; with ``--report FILE`` it writes how many rounds it published and over
  how many seconds, ten times a second
"""

from __future__ import annotations

import argparse
import contextlib
import os
import random
import threading
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from std_msgs.msg import Float64, UInt8MultiArray

ROLES = {
    "camera": ("usb_cam", 15.0),
    "audio": ("audio_capture", 33.333),
    "signal": ("Signal_generator", 15.0),
    "listener": ("listener", 0.0),
    "load": ("load_publishers", 100.0),
}


def _qos(reliability: str, depth: int = 10) -> QoSProfile:
    policy = (ReliabilityPolicy.BEST_EFFORT if reliability == "best_effort"
              else ReliabilityPolicy.RELIABLE)
    return QoSProfile(depth=depth, reliability=policy)


class Paced:
    """Calls ``tick`` at the node's ``rate`` parameter, re-read every cycle (0 = paused).

    Callbacks (subscriptions, parameter services) run in a spinning thread of their own,
    so a node receiving a lot still answers ``set_parameters`` at once.
    """

    def __init__(self, node: Node, tick, rate: float) -> None:
        self.node = node
        self.tick = tick
        node.declare_parameter("rate", rate)
        self.next_t = time.monotonic()

    def run(self) -> None:
        threading.Thread(target=_spin, args=(self.node,), daemon=True).start()
        while rclpy.ok():
            hz = float(self.node.get_parameter("rate").value)
            if hz > 0:
                self.tick()
                self.next_t += 1.0 / hz
            else:
                self.next_t += 0.1
            delay = self.next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                self.next_t = time.monotonic()


def _spin(node: Node) -> None:
    with contextlib.suppress(ExternalShutdownException, RuntimeError):
        rclpy.spin(node)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("role", choices=sorted(ROLES))
    parser.add_argument("--rate", type=float, default=None, help="publishing rate in Hz")
    parser.add_argument("--reliability", choices=("reliable", "best_effort"),
                        default="reliable")
    parser.add_argument("--topic", default="/signal")
    parser.add_argument("--topics", type=int, default=100)
    parser.add_argument("--name", default=None)
    parser.add_argument("--report", default=None)
    args, _ = parser.parse_known_args()
    name, default_rate = ROLES[args.role]
    name = args.name or name
    rate = default_rate if args.rate is None else args.rate
    rclpy.init()
    node = Node(name)
    qos = _qos(args.reliability)
    if args.role == "camera":
        pub = node.create_publisher(Image, "/usb_cam/image_raw", qos)
        msg = Image(height=480, width=640, encoding="rgb8", is_bigendian=0, step=640 * 3)
        msg.data = bytes(640 * 480 * 3)
        msg.header.frame_id = "usb_cam"

        def camera() -> None:
            msg.header.stamp = node.get_clock().now().to_msg()
            pub.publish(msg)

        Paced(node, camera, rate).run()
    elif args.role == "audio":
        pub = node.create_publisher(UInt8MultiArray, "/audio", qos)
        chunk = UInt8MultiArray()
        chunk.data = bytes(480)
        Paced(node, lambda: pub.publish(chunk), rate).run()
    elif args.role == "signal":
        node.declare_parameter("offset", 0.0)
        node.declare_parameter("scale", 1.0)
        node.create_subscription(Image, "/usb_cam/image_raw", lambda m: None, 1)
        node.create_subscription(UInt8MultiArray, "/audio", lambda m: None, 5)
        pub = node.create_publisher(Float64, "/signal", qos)

        def signal() -> None:
            base = 15.0 + random.uniform(-0.5, 0.5)
            offset = float(node.get_parameter("offset").value)
            scale = float(node.get_parameter("scale").value)
            pub.publish(Float64(data=offset + scale * base))

        Paced(node, signal, rate).run()
    elif args.role == "listener":
        node.create_subscription(Float64, args.topic,
                                 lambda m: print(f"heard {m.data}", flush=True), qos)
        rclpy.spin(node)
    else:
        pubs = [node.create_publisher(Float64, f"/{name}/t{i}", qos)
                for i in range(args.topics)]
        count = [0]
        began = time.monotonic()
        reported = [began]

        def load() -> None:
            count[0] += 1
            for p in pubs:
                p.publish(Float64(data=float(count[0])))
            now = time.monotonic()
            if args.report and now - reported[0] >= 0.1:
                reported[0] = now
                with open(args.report + ".tmp", "w") as f:
                    f.write(f"{count[0]} {now - began:.3f}\n")
                os.replace(args.report + ".tmp", args.report)

        Paced(node, load, rate).run()


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
        main()
