#!/usr/bin/env python3
"""A differential-drive robot of correlated sensors on real ROS 2 (rclpy), issue 22.

    diffdrive_robot.py --domain 42 [--seed 0]            # start all nodes, print pids
    diffdrive_robot.py node ROLE --epoch T --seed S       # one node (what the above runs)

Five nodes measure one motion (``scripts/robots/diffdrive_motion.py``, shared with the ROS 1
robot ``scripts/ros1_robot/diffdrive_robot.py``):

- ``/teleop``: ``/cmd_vel`` (geometry_msgs/Twist: ``linear.x`` = v, ``angular.z`` = w), 20 Hz
- ``/base_driver``: ``/joint_states`` (sensor_msgs/JointState, left and right wheel
  ``velocity[0..1]`` = (v -+ 0.2 w) / 0.1 rad/s), 50 Hz
- ``/odometry``: ``/odom/twist`` (geometry_msgs/TwistStamped from the wheels), 20 Hz
- ``/imu_driver``: ``/imu/data`` (sensor_msgs/Imu ``angular_velocity.z`` = w), 100 Hz;
  parameter ``yaw_offset`` (rad/s, default 0) is added to what it reports: set it with
  :class:`robot.ParameterClient` to inject an IMU offset that stays inside the normal range
- ``/battery_monitor``: ``/battery_state`` (sensor_msgs/BatteryState ``voltage``, ``current``), 2 Hz

``--fault-seed S --fault-start T --fault-duration D``: every node applies the value faults
(stuck, drift, offset, scale, noise) that the seeded schedule of
``scripts/robots/diffdrive_faults.py`` puts on its own fields from motion second ``T`` on;
kill and stall are the harness's (``benchmarks/learned_campaign_real.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import random
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "robots"))  # the motion model both robots share

from diffdrive_faults import FaultPlan  # noqa: E402
from diffdrive_motion import DiffdriveMotion  # noqa: E402


def _launcher() -> ModuleType:
    """The thesis robot's launcher beside this file, by path: another ``robot`` module (the
    ROS 1 one) may already be imported under that name in the same process."""
    name = "ros2_thesis_robot"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, HERE / "robot.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


ros2_env = _launcher().ros2_env

ROLES = {"/teleop": ("teleop", 20.0), "/base_driver": ("base_driver", 50.0),
         "/odometry": ("odometry", 20.0), "/imu_driver": ("imu_driver", 100.0),
         "/battery_monitor": ("battery_monitor", 2.0)}
"""Node name -> (role argument, rate in Hz)."""

TOPICS = {"/cmd_vel": "/teleop", "/joint_states": "/base_driver", "/odom/twist": "/odometry",
          "/imu/data": "/imu_driver", "/battery_state": "/battery_monitor"}
"""Topic -> publishing node."""

SIGNALS = (("/cmd_vel", "linear.x"), ("/cmd_vel", "angular.z"),
           ("/joint_states", "velocity[0]"), ("/joint_states", "velocity[1]"),
           ("/odom/twist", "twist.linear.x"), ("/odom/twist", "twist.angular.z"),
           ("/imu/data", "angular_velocity.z"), ("/battery_state", "voltage"),
           ("/battery_state", "current"))
"""The numeric fields that measure the shared motion."""


def run_node(role: str, epoch: float, seed: int,
             faults: tuple[int, float, float] = (0, 0.0, 0.0)) -> None:
    """One node, publishing the shared motion plus its own sensor noise until interrupted."""
    import rclpy
    from geometry_msgs.msg import Twist, TwistStamped
    from rclpy.node import Node
    from sensor_msgs.msg import BatteryState, Imu, JointState

    name = next(n for n, (r, _) in ROLES.items() if r == role)
    rate = ROLES[name][1]
    motion = DiffdriveMotion(seed)
    noise = random.Random(f"{seed}:{role}")
    topic = next(tp for tp, node in TOPICS.items() if node == name)
    plan = FaultPlan(topic, *faults)  # the seeded schedule's faults on my topic
    rclpy.init()
    node = Node(name.strip("/"))
    node.declare_parameter("yaw_offset", 0.0)
    stamp = node.get_clock
    if role == "teleop":
        pub = node.create_publisher(Twist, "/cmd_vel", 10)

        def tick(t: float) -> None:
            msg = Twist()
            msg.linear.x = plan.apply("linear.x", t,
                                      motion.v(t) + noise.gauss(0, 0.01))
            msg.angular.z = plan.apply("angular.z", t,
                                       motion.w(t) + noise.gauss(0, 0.01))
            pub.publish(msg)
    elif role == "base_driver":
        node.create_subscription(Twist, "/cmd_vel", lambda m: None, 10)
        pub = node.create_publisher(JointState, "/joint_states", 10)

        def tick(t: float) -> None:
            v, w = motion.v(t - 0.02), motion.w(t - 0.02)
            msg = JointState()
            msg.header.stamp = stamp().now().to_msg()
            msg.name = ["left_wheel", "right_wheel"]
            left = (v - 0.2 * w) / 0.1 + noise.gauss(0, 0.1)
            right = (v + 0.2 * w) / 0.1 + noise.gauss(0, 0.1)
            msg.velocity = [plan.apply("velocity[0]", t, left),
                            plan.apply("velocity[1]", t, right)]
            pub.publish(msg)
    elif role == "odometry":
        node.create_subscription(JointState, "/joint_states", lambda m: None, 10)
        pub = node.create_publisher(TwistStamped, "/odom/twist", 10)

        def tick(t: float) -> None:
            msg = TwistStamped()
            msg.header.stamp = stamp().now().to_msg()
            msg.twist.linear.x = plan.apply("twist.linear.x", t,
                                            motion.v(t - 0.03) + noise.gauss(0, 0.015))
            msg.twist.angular.z = plan.apply("twist.angular.z", t,
                                             motion.w(t - 0.03) + noise.gauss(0, 0.02))
            pub.publish(msg)
    elif role == "imu_driver":
        pub = node.create_publisher(Imu, "/imu/data", 10)

        def tick(t: float) -> None:
            msg = Imu()
            msg.header.stamp = stamp().now().to_msg()
            offset = float(node.get_parameter("yaw_offset").value)
            msg.angular_velocity.z = plan.apply("angular_velocity.z", t,
                                                  motion.w(t) + offset + noise.gauss(0, 0.02))
            msg.linear_acceleration.z = 9.81 + noise.gauss(0, 0.05)
            pub.publish(msg)
    else:
        pub = node.create_publisher(BatteryState, "/battery_state", 10)

        def tick(t: float) -> None:
            msg = BatteryState()
            msg.header.stamp = stamp().now().to_msg()
            msg.voltage = plan.apply("voltage", t,
                                     motion.voltage(t) + noise.gauss(0, 0.02))
            msg.current = plan.apply("current", t,
                                     motion.current(t) + noise.gauss(0, 0.05))
            pub.publish(msg)

    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor()
    executor.add_node(node)
    next_t = time.time()
    while rclpy.ok():
        tick(time.time() - epoch)
        next_t += 1.0 / rate
        # Serve parameter requests while waiting for the next sample.
        while (delay := next_t - time.time()) > 0:
            executor.spin_once(timeout_sec=delay)
        if -delay > 2.0 / rate:  # descheduled: skip the missed cycles, as ROS timers do
            next_t = time.time()


@dataclass
class DiffdriveRobot2:
    """The five nodes as rclpy processes on ROS 2 domain ``domain_id``, one shared motion."""

    domain_id: int
    seed: int = 0
    log_dir: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="ros2-dd-")))
    python: str = sys.executable
    epoch: float = field(default_factory=time.time)
    faults: tuple[int, float, float] = (0, 0.0, 0.0)
    """(seed, start, duration) of the fault schedule every node applies to its own values
    (``scripts/robots/diffdrive_faults.py``; motion seconds); duration 0: none."""
    transports: str | None = None
    """Fast DDS's built-in transports for the nodes (``FASTDDS_BUILTIN_TRANSPORTS``, e.g.
    ``UDPv4``); ``None``: its default, shared memory between the nodes plus UDP. A campaign
    that SIGKILLs nodes needs ``UDPv4``: with shared memory, a node killed and started again
    left three other nodes silent for two minutes (seen once in 900 s; Fast DDS issue 5469),
    faults the campaign's ground truth does not have."""
    nodes: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    def start(self) -> DiffdriveRobot2:
        for name in ROLES:
            self.start_node(name)
        return self

    def start_node(self, name: str) -> subprocess.Popen[bytes]:
        """Start node ``name`` of :data:`ROLES` (again, after a kill)."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        role = ROLES[name][0]
        seed, start, duration = self.faults
        env = ros2_env(self.domain_id)
        if self.transports is not None:
            env["FASTDDS_BUILTIN_TRANSPORTS"] = self.transports
        with (self.log_dir / f"{role}.log").open("ab") as log:
            self.nodes[name] = subprocess.Popen(
                [self.python, str(Path(__file__).resolve()), "node", role, "--epoch",
                 repr(self.epoch), "--seed", str(self.seed), "--fault-seed", str(seed),
                 "--fault-start", repr(start), "--fault-duration", repr(duration)],
                env=env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        return self.nodes[name]

    def pids(self) -> dict[str, int]:
        return {n: p.pid for n, p in self.nodes.items() if p.poll() is None}

    def stop(self) -> None:
        for proc in self.nodes.values():
            if proc.poll() is None:
                proc.send_signal(2)  # SIGINT
        for proc in self.nodes.values():
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
        self.nodes.clear()

    def __enter__(self) -> DiffdriveRobot2:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", nargs="?", default="robot", choices=("robot", "node"))
    parser.add_argument("role", nargs="?", default="")
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--epoch", type=float, default=None)
    parser.add_argument("--fault-seed", type=int, default=0, help="the fault schedule's seed")
    parser.add_argument("--fault-start", type=float, default=0.0,
                        help="motion second the fault schedule starts at")
    parser.add_argument("--fault-duration", type=float, default=0.0,
                        help="seconds of faults (0: none)")
    args = parser.parse_args()
    faults = (args.fault_seed, args.fault_start, args.fault_duration)
    if args.what == "node":
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
            run_node(args.role, args.epoch if args.epoch is not None else time.time(),
                     args.seed, faults)
        return
    robot = DiffdriveRobot2(args.domain, args.seed, faults=faults).start()
    print(json.dumps(robot.pids()), flush=True)
    try:
        while all(p.poll() is None for p in robot.nodes.values()):
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        robot.stop()


if __name__ == "__main__":
    main()
