#!/usr/bin/env python3
"""A differential-drive robot of correlated sensors on real ROS 1 (rospy), issue 22.

    diffdrive_robot.py --port 11411 [--seed 0]                  # roscore + all nodes, pids
    diffdrive_robot.py node ROLE --epoch T --seed S              # one node (what the above runs)

The ROS 1 twin of ``scripts/ros2_robot/diffdrive_robot.py``: the same five nodes, topics,
rates, fields and noise, all measuring one motion (``scripts/robots/diffdrive_motion.py``,
no ROS import, shared by both robots), so a configuration learned on one middleware reads
the same signals as on the other:

- ``/teleop``: ``/cmd_vel`` (geometry_msgs/Twist: ``linear.x`` = v, ``angular.z`` = w), 20 Hz
- ``/base_driver``: subscribes ``/cmd_vel``; ``/joint_states`` (sensor_msgs/JointState, left
  and right wheel ``velocity[0..1]`` = (v -+ 0.2 w) / 0.1 rad/s), 50 Hz
- ``/odometry``: subscribes ``/joint_states``; ``/odom/twist`` (geometry_msgs/TwistStamped
  from the wheels), 20 Hz
- ``/imu_driver``: ``/imu/data`` (sensor_msgs/Imu ``angular_velocity.z`` = w), 100 Hz; the
  private parameter ``~yaw_offset`` (rad/s, default 0) is added to what it reports. The node
  reads it through rospy's parameter cache every cycle, so one ``setParam`` on the master
  (:meth:`DiffdriveRobot1.set_yaw_offset`) injects an IMU offset at run time.
- ``--fault-seed S --fault-start T --fault-duration D``: every node applies the value faults
  (stuck, drift, offset, scale, noise) that the seeded schedule of
  ``scripts/robots/diffdrive_faults.py`` puts on its own fields from motion second ``T``
  on; kill and stall are the harness's (``benchmarks/learned_campaign_real.py``).
- ``/battery_monitor``: ``/battery_state`` (sensor_msgs/BatteryState ``voltage``,
  ``current``), 2 Hz

The launcher part needs only the standard library (tests import it from any Python 3); the
nodes run under Debian's ``/usr/bin/python3``, where rospy lives, each with the master,
loopback environment and process handling of :class:`robot.ThesisRobot`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "robots"))  # the motion model both robots share
sys.path.insert(0, str(HERE))

from diffdrive_faults import FaultPlan  # noqa: E402
from diffdrive_motion import DiffdriveMotion  # noqa: E402
from robot import ROS_PYTHON, ThesisRobot, free_port  # noqa: E402

ROLES = {"/teleop": ("teleop", 20.0), "/base_driver": ("base_driver", 50.0),
         "/odometry": ("odometry", 20.0), "/imu_driver": ("imu_driver", 100.0),
         "/battery_monitor": ("battery_monitor", 2.0)}
"""Node name -> (role argument, rate in Hz); the same as the ROS 2 robot's."""

TOPICS = {"/cmd_vel": "/teleop", "/joint_states": "/base_driver", "/odom/twist": "/odometry",
          "/imu/data": "/imu_driver", "/battery_state": "/battery_monitor"}
"""Topic -> publishing node."""

SUBSCRIPTIONS = {"/base_driver": "/cmd_vel", "/odometry": "/joint_states"}
"""Node -> the topic it subscribes to (the chain command -> wheels -> odometry)."""

SIGNALS = (("/cmd_vel", "linear.x"), ("/cmd_vel", "angular.z"),
           ("/joint_states", "velocity[0]"), ("/joint_states", "velocity[1]"),
           ("/odom/twist", "twist.linear.x"), ("/odom/twist", "twist.angular.z"),
           ("/imu/data", "angular_velocity.z"), ("/battery_state", "voltage"),
           ("/battery_state", "current"))
"""The numeric fields that measure the shared motion."""

YAW_OFFSET_PARAM = "/imu_driver/yaw_offset"

__all__ = ["ROLES", "SIGNALS", "TOPICS", "DiffdriveRobot1", "free_port", "run_node"]


def run_node(role: str, epoch: float, seed: int,
             faults: tuple[int, float, float] = (0, 0.0, 0.0)) -> None:
    """One rospy node, publishing the shared motion plus its own sensor noise until shut down.

    Same noise and delays as the ROS 2 nodes (``scripts/ros2_robot/diffdrive_robot.py``)."""
    import rospy
    from geometry_msgs.msg import Twist, TwistStamped
    from sensor_msgs.msg import BatteryState, Imu, JointState

    name = next(n for n, (r, _) in ROLES.items() if r == role)
    rate = ROLES[name][1]
    motion = DiffdriveMotion(seed)
    noise = random.Random(f"{seed}:{role}")
    topic = next(tp for tp, node in TOPICS.items() if node == name)
    plan = FaultPlan(topic, *faults)  # the seeded schedule's faults on my topic
    rospy.init_node(name.strip("/"), anonymous=False)
    if name in SUBSCRIPTIONS:
        kind = Twist if SUBSCRIPTIONS[name] == "/cmd_vel" else JointState
        rospy.Subscriber(SUBSCRIPTIONS[name], kind, lambda m: None, queue_size=10)
    if role == "teleop":
        pub = rospy.Publisher("/cmd_vel", Twist, queue_size=10)

        def make(t):
            msg = Twist()
            msg.linear.x = plan.apply("linear.x", t,
                                      motion.v(t) + noise.gauss(0, 0.01))
            msg.angular.z = plan.apply("angular.z", t,
                                       motion.w(t) + noise.gauss(0, 0.01))
            return msg
    elif role == "base_driver":
        pub = rospy.Publisher("/joint_states", JointState, queue_size=10)

        def make(t):
            v, w = motion.v(t - 0.02), motion.w(t - 0.02)
            msg = JointState()
            msg.header.stamp = rospy.Time.now()
            msg.name = ["left_wheel", "right_wheel"]
            left = (v - 0.2 * w) / 0.1 + noise.gauss(0, 0.1)
            right = (v + 0.2 * w) / 0.1 + noise.gauss(0, 0.1)
            msg.velocity = [plan.apply("velocity[0]", t, left),
                            plan.apply("velocity[1]", t, right)]
            return msg
    elif role == "odometry":
        pub = rospy.Publisher("/odom/twist", TwistStamped, queue_size=10)

        def make(t):
            msg = TwistStamped()
            msg.header.stamp = rospy.Time.now()
            msg.twist.linear.x = plan.apply("twist.linear.x", t,
                                            motion.v(t - 0.03) + noise.gauss(0, 0.015))
            msg.twist.angular.z = plan.apply("twist.angular.z", t,
                                             motion.w(t - 0.03) + noise.gauss(0, 0.02))
            return msg
    elif role == "imu_driver":
        rospy.set_param("~yaw_offset", 0.0)
        pub = rospy.Publisher("/imu/data", Imu, queue_size=10)

        def make(t):
            msg = Imu()
            msg.header.stamp = rospy.Time.now()
            try:
                offset = float(rospy.get_param_cached("~yaw_offset", 0.0))
            except (KeyError, TypeError, ValueError):
                offset = 0.0
            msg.angular_velocity.z = plan.apply("angular_velocity.z", t,
                                                  motion.w(t) + offset + noise.gauss(0, 0.02))
            msg.linear_acceleration.z = 9.81 + noise.gauss(0, 0.05)
            return msg
    else:
        pub = rospy.Publisher("/battery_state", BatteryState, queue_size=10)

        def make(t):
            msg = BatteryState()
            msg.header.stamp = rospy.Time.now()
            msg.voltage = plan.apply("voltage", t,
                                     motion.voltage(t) + noise.gauss(0, 0.02))
            msg.current = plan.apply("current", t,
                                     motion.current(t) + noise.gauss(0, 0.05))
            return msg

    next_t = time.time()
    while not rospy.is_shutdown():
        pub.publish(make(time.time() - epoch))
        next_t += 1.0 / rate
        delay = next_t - time.time()
        if delay > 0:
            time.sleep(delay)
        elif -delay > 2.0 / rate:  # descheduled: skip the missed cycles, as rospy.Rate does
            next_t = time.time()


@dataclass
class DiffdriveRobot1(ThesisRobot):
    """roscore on ``port`` plus the five nodes as rospy processes, one shared motion.

    ``epoch`` (wall-clock seconds) is the motion's time zero, given to every node."""

    seed: int = 0
    epoch: float = field(default_factory=time.time)
    faults: tuple[int, float, float] = (0, 0.0, 0.0)
    """(seed, start, duration) of the fault schedule every node applies to its own values
    (``scripts/robots/diffdrive_faults.py``; motion seconds); duration 0: none."""

    def start(self, timeout: float = 30.0) -> DiffdriveRobot1:
        self.start_master(timeout)
        for name in ROLES:
            self.start_node(name)
        self.wait_registered(list(ROLES), timeout)
        return self

    def start_node(self, name: str, rate: float | None = None) -> subprocess.Popen[bytes]:
        """Start node ``name`` of :data:`ROLES` (``rate`` is not used: rates are fixed)."""
        seed, start, duration = self.faults
        cmd = [ROS_PYTHON, str(Path(__file__).resolve()), "node", ROLES[name][0],
               "--epoch", repr(self.epoch), "--seed", str(self.seed), "--fault-seed",
               str(seed), "--fault-start", repr(start), "--fault-duration", repr(duration)]
        fd = self._log(name)
        proc = subprocess.Popen(cmd, env=self.env, stdout=fd, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        os.close(fd)
        self.nodes[name] = proc
        return proc

    def set_yaw_offset(self, value: float) -> None:
        """Make the IMU driver add ``value`` rad/s to the yaw rate it reports, from now on."""
        self.set_param(YAW_OFFSET_PARAM, float(value))

    def __enter__(self) -> DiffdriveRobot1:
        return self


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", nargs="?", default="robot", choices=("robot", "node"))
    parser.add_argument("role", nargs="?", default="")
    parser.add_argument("--port", type=int, default=11311, help="ROS master port")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--epoch", type=float, default=None)
    parser.add_argument("--log-dir", type=Path, help="node logs (default: a temporary ROS_HOME)")
    parser.add_argument("--fault-seed", type=int, default=0, help="the fault schedule's seed")
    parser.add_argument("--fault-start", type=float, default=0.0,
                        help="motion second the fault schedule starts at")
    parser.add_argument("--fault-duration", type=float, default=0.0,
                        help="seconds of faults (0: none)")
    args = parser.parse_args(argv)
    faults = (args.fault_seed, args.fault_start, args.fault_duration)
    if args.what == "node":
        import rospy

        with contextlib.suppress(rospy.ROSInterruptException):
            run_node(args.role, args.epoch if args.epoch is not None else time.time(),
                     args.seed, faults)
        return 0
    robot = DiffdriveRobot1(args.port, log_dir=args.log_dir, seed=args.seed, faults=faults)
    stop = {"now": False}

    def on_signal(signum: int, frame: object) -> None:
        stop["now"] = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        robot.start()
        print(json.dumps(robot.pids(), sort_keys=True), flush=True)
        print(f"diffdrive robot up on {robot.master_uri}; set {YAW_OFFSET_PARAM} to inject "
              "an IMU offset; Ctrl-C stops it", file=sys.stderr)
        while not stop["now"]:
            time.sleep(0.2)
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    finally:
        robot.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
