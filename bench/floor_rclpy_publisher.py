"""CPU floor for the bridge nodes: a bare rclpy process that only publishes.

A timer at ``--rate`` Hz publishes what the bridge publishes per poll cycle, with no
Modbus traffic: ``--device r6`` a 6-joint JointState, an R6State and a PoseStamped;
``--device xarm`` a 7-joint JointState (position, velocity), an XArmState with the
array sizes the xArm bridge fills and a PoseStamped; ``--device modbus`` a 7-joint
JointState and a DeviceValues of the xArm description's readable registers (no pose:
modbus_bridge publishes none). The bench
(``bench/bridge_bench.py``'s cpu phase, bench/cpu_phase.py) reads this process's CPU from
/proc to get "floor A".

    python bench/floor_rclpy_publisher.py [--device r6|xarm|modbus] [--rate 100]
        [--executor single|multi|events] [--ros-args ...]

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
from rclpy.utilities import ok, try_shutdown
from sensor_msgs.msg import JointState

from msg_defs.msg import DeviceValues, R6State, XArmState

JOINTS = {"r6": 6, "xarm": 7, "modbus": 7}


def r6_state(k: int) -> R6State:
    state = R6State()
    state.mode = 2
    state.mode_name = "auto"
    state.global_speed_percent = 50.0
    state.machine_id = 1
    state.axis_count = JOINTS["r6"]
    state.io_board_count = 1
    state.io_board_inputs = [k & 0xFFFF]
    state.io_board_outputs = [0]
    return state


def xarm_state(k: int) -> XArmState:
    joints = JOINTS["xarm"]
    state = XArmState()
    state.mode, state.state, state.state_name = 0, 2, "sleeping"
    state.error_code, state.error_text = 0, ""
    state.warning_code, state.warning_text = 0, ""
    state.brakes = [True] * joints
    state.enabled = [True] * joints
    state.reduced_mode = state.fence_mode = state.paused = state.stopped = False
    state.motion_modes = [m == 0 for m in range(14)]
    state.joint_temperatures = [30.0 + j for j in range(1, joints + 1)]
    state.tcp_speed = 0.0
    state.counter = k & 0xFFFFFFFF
    state.digital_inputs = [bool(k >> b & 1) for b in range(16)]
    state.digital_outputs = [False] * 16
    state.tool_digital_inputs = [False, True]
    state.tool_digital_outputs = [False, False]
    state.analog_inputs = [1.25, 0.0]
    state.tool_analog_inputs = [0.0, 3.3]
    state.analog_outputs = [1.25, 0.0]
    state.tcp_load_mass = 0.5
    state.tcp_load_center = [0.0, 0.0, 0.03]
    state.tcp_offset = [0.0, 0.0, 0.06, 0.0, 0.0, 0.0]
    state.base_offset = [0.0] * 6
    return state


def modbus_state(k: int) -> DeviceValues:
    """What modbus_bridge publishes for config/devices/xarm.yaml: every readable register."""
    from pathlib import Path

    from modbus_bridge.description import load

    global _MODBUS_UNITS
    if _MODBUS_UNITS is None:
        path = Path(__file__).resolve().parents[1] / "config" / "devices" / "xarm.yaml"
        device = load(path).device
        _MODBUS_UNITS = [(n, device.register_map[n].unit) for n in device.state_names]
    state = DeviceValues()
    state.names = [name for name, _ in _MODBUS_UNITS]
    state.values = [float((k + i) % 7) for i in range(len(_MODBUS_UNITS))]
    state.units = [unit for _, unit in _MODBUS_UNITS]
    state.texts = [""] * len(_MODBUS_UNITS)
    return state


_MODBUS_UNITS: list[tuple[str, str]] | None = None
STATES = {"r6": r6_state, "xarm": xarm_state, "modbus": modbus_state}
STATE_TYPES = {"r6": R6State, "xarm": XArmState, "modbus": DeviceValues}


class FloorPublisher(Node):
    def __init__(self, rate_hz: float, device: str = "r6") -> None:
        super().__init__("floor_rclpy_publisher")
        # Same topic names and depths as the bridge (joint_states depth 10, ~/... depth 10).
        self.joint_pub = self.create_publisher(JointState, "joint_states", 10)
        self.state_pub = self.create_publisher(STATE_TYPES[device], "~/state", 10)
        self.pose_pub = self.create_publisher(PoseStamped, "~/tcp_pose", 10)
        self.joints = JOINTS[device]
        # The bridges' joint names: R6 "joint_<n>", xArm "joint<n>".
        sep = "_" if device == "r6" else ""
        self.names = [f"joint{sep}{a}" for a in range(1, self.joints + 1)]
        self.effort = device == "r6"  # the xArm bridge publishes no effort
        self.make_state = STATES[device]
        self.pose = device != "modbus"  # modbus_bridge publishes no pose
        self.cycles = 0
        self.timer = self.create_timer(1.0 / rate_hz, self._tick)

    def _tick(self) -> None:
        now = time.time()
        stamp = Time(nanoseconds=int(now * 1e9)).to_msg()
        k = self.cycles
        self.cycles += 1
        n = self.joints

        joints = JointState()
        joints.header.stamp = stamp
        joints.name = list(self.names)
        joints.position = [math.sin(k * 1e-3 + a) for a in range(n)]
        joints.velocity = [0.1 * a for a in range(n)]
        if self.effort:
            joints.effort = [0.2 * a for a in range(n)]
        self.joint_pub.publish(joints)

        state = self.make_state(k)
        state.header.stamp = stamp
        state.header.frame_id = "base_link"
        self.state_pub.publish(state)

        if not self.pose:
            return
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
        # What the bridges use (bridge_core.ros.process.spin_node).
        return MultiThreadedExecutor(num_threads=3)
    if kind == "events":
        from rclpy.experimental.events_executor import EventsExecutor

        return EventsExecutor()
    raise ValueError(kind)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    ros_args = argv[argv.index("--ros-args") :] if "--ros-args" in argv else []
    own = argv[: len(argv) - len(ros_args)]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=sorted(JOINTS), default="r6")
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--executor", choices=("single", "multi", "events"), default="single")
    args = parser.parse_args(own)
    rclpy.init(args=[sys.argv[0], *ros_args])
    node: Node = FloorPublisher(args.rate, args.device)
    executor = make_executor(args.executor)
    executor.add_node(node)
    print(f"floor publisher at {args.rate} Hz ({args.executor} executor)", flush=True)
    try:
        if args.executor == "events":
            # The experimental EventsExecutor's spin() does not return on SIGINT here.
            while ok():
                executor.spin_once(timeout_sec=0.2)
        else:
            executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        try_shutdown()


if __name__ == "__main__":
    main()
