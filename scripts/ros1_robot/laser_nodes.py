#!/usr/bin/python3
"""A laser driver and a node using it, as real rospy nodes: a part of a robot that no
hand-written thesis observer covers, for `blackbox learn` on real ROS 1.

    laser_nodes.py laser|monitor

- laser: ``/laser_driver`` publishes ``/scan`` (sensor_msgs/LaserScan, 90 ranges of
  2.0 +- 0.02 m, stamped) at ``~rate`` Hz (default 10); every range gets ``~offset``
  added, read through the parameter cache each cycle, so a test makes the driver publish
  wrong values at the right rate with one ``setParam``.
- monitor: ``/obstacle_monitor`` subscribes ``/scan`` and publishes the nearest range as
  ``/min_distance`` (std_msgs/Float64) for every scan.

Runs under Debian's ``/usr/bin/python3`` (where rospy lives); started by tests with the
loopback environment of ``robot.ros_env``.
"""

import argparse
import contextlib
import random
import time

import rospy
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Float64

BEAMS = 90


def _param(name, default):
    try:
        return float(rospy.get_param_cached(name, default))
    except (KeyError, TypeError, ValueError):
        return default


def laser():
    rospy.init_node("laser_driver", anonymous=False)
    rospy.set_param("~rate", 10.0)
    rospy.set_param("~offset", 0.0)
    pub = rospy.Publisher("/scan", LaserScan, queue_size=5)
    msg = LaserScan(angle_min=-0.785, angle_max=0.785, angle_increment=1.57 / BEAMS,
                    range_min=0.05, range_max=10.0)
    msg.header.frame_id = "laser"
    next_t = time.monotonic()
    while not rospy.is_shutdown():
        offset = _param("~offset", 0.0)
        msg.header.stamp = rospy.Time.now()
        msg.ranges = [2.0 + random.uniform(-0.02, 0.02) + offset for _ in range(BEAMS)]
        pub.publish(msg)
        next_t += 1.0 / max(0.1, _param("~rate", 10.0))
        delay = next_t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            next_t = time.monotonic()


def monitor():
    rospy.init_node("obstacle_monitor", anonymous=False)
    pub = rospy.Publisher("/min_distance", Float64, queue_size=5)
    rospy.Subscriber("/scan", LaserScan, lambda m: pub.publish(Float64(min(m.ranges))),
                     queue_size=5)
    rospy.spin()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("role", choices=["laser", "monitor"])
    args, _ = parser.parse_known_args()
    laser() if args.role == "laser" else monitor()


if __name__ == "__main__":
    with contextlib.suppress(rospy.ROSInterruptException):
        main()
