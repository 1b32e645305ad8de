"""CPU floor for the bridge nodes: a bare rclpy process that only publishes.

A timer at ``--rate`` Hz publishes what ``r6_bridge`` publishes per poll cycle (a
6-joint JointState, an R6State and a PoseStamped), with no Modbus traffic. The bench
(``bench/r6_bench.py``) reads this process's CPU from /proc to get "floor A".

    python bench/floor_rclpy_publisher.py [--rate 100] [--executor single|multi|events]
        [--ros-args ...]

Run it with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a ROS_DOMAIN_ID of its own
(the bench sets both).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import JointState

from msg_defs.msg import R6State

JOINTS = 6


class FloorPublisher(Node):
    def __init__(self, rate_hz: float) -> None:
        super().__init__("floor_rclpy_publisher")
        # Same topic names and depths as the bridge (joint_states depth 10, ~/... depth 10).
        self.joint_pub = self.create_publisher(JointState, "joint_states", 10)
        self.state_pub = self.create_publisher(R6State, "~/state", 10)
        self.pose_pub = self.create_publisher(PoseStamped, "~/tcp_pose", 10)
        self.names = [f"joint_{a}" for a in range(1, JOINTS + 1)]
        self.cycles = 0
        self.timer = self.create_timer(1.0 / rate_hz, self._tick)

    def _tick(self) -> None:
        now = time.time()
        stamp = Time(nanoseconds=int(now * 1e9)).to_msg()
        k = self.cycles
        self.cycles += 1

        joints = JointState()
        joints.header.stamp = stamp
        joints.name = list(self.names)
        joints.position = [math.sin(k * 1e-3 + a) for a in range(JOINTS)]
        joints.velocity = [0.1 * a for a in range(JOINTS)]
        joints.effort = [0.2 * a for a in range(JOINTS)]
        self.joint_pub.publish(joints)

        state = R6State()
        state.header.stamp = stamp
        state.header.frame_id = "base_link"
        state.mode = 2
        state.mode_name = "auto"
        state.global_speed_percent = 50.0
        state.machine_id = 1
        state.axis_count = JOINTS
        state.io_board_count = 1
        state.io_board_inputs = [k & 0xFFFF]
        state.io_board_outputs = [0]
        self.state_pub.publish(state)

        pose = PoseStamped()
        pose.header.stamp = stamp
        pose.header.frame_id = "base_link"
        pose.pose.position.x = 0.4
        pose.pose.position.y = 0.1
        pose.pose.position.z = 0.3
        pose.pose.orientation.w = 1.0
        self.pose_pub.publish(pose)


def make_executor(kind: str):  # type: ignore[no-untyped-def]
    if kind == "single":
        return SingleThreadedExecutor()
    if kind == "multi":
        # What the bridges use (bridge_core.node_base.spin_node).
        return MultiThreadedExecutor(num_threads=3)
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    raise ValueError(kind)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    ros_args = argv[argv.index("--ros-args") :] if "--ros-args" in argv else []
    own = argv[: len(argv) - len(ros_args)]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--executor", choices=("single", "multi", "events"), default="single")
    args = parser.parse_args(own)
    rclpy.init(args=[sys.argv[0], *ros_args])
    node = FloorPublisher(args.rate)
    executor = make_executor(args.executor)
    executor.add_node(node)
    print(f"floor publisher at {args.rate} Hz ({args.executor} executor)", flush=True)
    try:
        if args.executor == "events":
            # The experimental EventsExecutor's spin() does not return on SIGINT here.
            while rclpy.ok():
                executor.spin_once(timeout_sec=0.2)
        else:
            executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
