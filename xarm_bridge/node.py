"""ROS 2 node for the UFactory xArm controller (DESIGN §3, xarm_bridge)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Any

from geometry_msgs.msg import PoseStamped
from std_srvs.srv import SetBool, Trigger

from bridge_core.checks import board_zero_index
from bridge_core.diagnostics import Level, Report
from bridge_core.node_base import BridgeNode, DeviceDefaults, copy_fields, spin_node
from bridge_core.units import DEG, MM, euler_xyz_deg_to_quaternion
from msg_defs.msg import XArmState
from msg_defs.srv import RunOfflineTask, SetChannelValue, SetInteger, SetOutput

from .device import XArmDevice, XArmSnapshot, error_text, mode_name, state_name, warning_text
from .registers import JOINTS, WORLD


def _pose6(values: dict[str, float]) -> list[float]:
    """x y z (mm) roll pitch yaw (deg) -> m and rad."""
    return [values[a] * (MM if k < 3 else DEG) for k, a in enumerate(WORLD)]


# XArmState fields copied as they are from the snapshot (same names, same units).
STATE_FIELDS = (
    "mode",
    "state",
    "error_code",
    "warning_code",
    "brakes",
    "enabled",
    "reduced_mode",
    "fence_mode",
    "paused",
    "stopped",
    "motion_modes",
    "counter",
    "digital_inputs",
    "digital_outputs",
    "tool_digital_inputs",
    "tool_digital_outputs",
    "analog_inputs",
    "tool_analog_inputs",
    "analog_outputs",
)


XARM_DEFAULTS = DeviceDefaults("UFactory xArm", "tcp", poll_rate_hz=50.0)


class XArmBridgeNode(BridgeNode[XArmSnapshot]):
    """The xArm controller: one node per arm, on its own TCP link."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("xarm_bridge", XARM_DEFAULTS, **kwargs)
        self.device = XArmDevice(self.channel)
        self.joint_names = [f"{self.joint_prefix}joint{j}" for j in range(1, JOINTS + 1)]
        self.state_pub = self.create_publisher(XArmState, "~/state", 10)
        self.pose_pub = self.create_publisher(PoseStamped, "~/tcp_pose", 10)
        self._create_services()

    # ------------------------------------------------------------ polling
    def poll_device(self) -> XArmSnapshot:
        return self.device.poll()

    def publish_snapshot(self, s: XArmSnapshot) -> None:
        self.publish_joints(
            s.read_time,
            [a * DEG for a in s.joint_angles_deg],
            [v * DEG for v in s.joint_speeds_deg_s],
        )
        pose = self.stamped(PoseStamped(), s.read_time)
        p = s.tcp_pose
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (
            p["x"] * MM,
            p["y"] * MM,
            p["z"] * MM,
        )
        o = pose.pose.orientation
        o.x, o.y, o.z, o.w = euler_xyz_deg_to_quaternion(p["roll"], p["pitch"], p["yaw"])
        self.pose_pub.publish(pose)

        m = copy_fields(self.stamped(XArmState(), s.read_time), s, STATE_FIELDS)
        m.state_name = state_name(s.state)
        m.error_text = error_text(s.error_code)
        m.warning_text = warning_text(s.warning_code)
        m.joint_temperatures = list(s.joint_temperatures_c)
        m.tcp_speed = s.tcp_speed_mm_s * MM
        m.tcp_load_mass = s.tcp_load_mass_kg
        m.tcp_load_center = [c * MM for c in s.tcp_load_center_mm]
        m.tcp_offset = _pose6(s.tcp_offset)
        m.base_offset = _pose6(s.base_offset)
        self.state_pub.publish(m)

    def device_report(self) -> Report | None:
        s = self.last_snapshot
        if s is None:
            return None
        values = [
            ("mode", f"{s.mode} ({mode_name(s.mode)})"),
            ("state", f"{s.state} ({state_name(s.state)})"),
            ("error code", f"{s.error_code} {error_text(s.error_code)}".strip()),
            ("warning code", f"{s.warning_code} {warning_text(s.warning_code)}".strip()),
        ]
        if s.error_code:
            return Report(
                Level.ERROR, f"controller error {s.error_code}: {error_text(s.error_code)}", values
            )
        if s.warning_code:
            return Report(
                Level.WARN,
                f"controller warning {s.warning_code}: {warning_text(s.warning_code)}",
                values,
            )
        return Report(Level.OK, "connected", values)

    # ------------------------------------------------------------ services
    def _create_services(self) -> None:
        d = self.device

        def state_after(result: tuple[int, int]) -> str:
            mode, state = result
            return f"; mode {mode} ({mode_name(mode)}), state {state} ({state_name(state)})"

        def fill_state(response: Any, result: tuple[int, int]) -> None:
            response.message += state_after(result)

        for name, action, stops in (
            ("pause", d.pause, True),
            ("stop", d.stop, True),
            ("resume", d.resume, False),
        ):
            self.command_service(
                Trigger, f"~/{name}", _named(name), _call(action), stop=stops, fill=fill_state
            )
        self.command_service(
            SetInteger, "~/set_mode", lambda r: f"set_mode {r.value}", lambda r: d.set_mode(r.value)
        )
        self.command_service(
            SetInteger,
            "~/set_state",
            lambda r: f"set_state {r.value}",
            lambda r: d.set_state(r.value),
            fill=fill_state,
        )
        self.command_service(
            SetOutput,
            "~/set_digital_output",
            lambda r: f"set_digital_output {r.index} {'on' if r.state else 'off'}",
            lambda r: d.set_digital_output(_board_zero(r.board, r.index), r.state),
        )
        self.command_service(
            SetOutput,
            "~/set_tool_digital_output",
            lambda r: f"set_tool_digital_output {r.index} {'on' if r.state else 'off'}",
            lambda r: d.set_tool_digital_output(_board_zero(r.board, r.index), r.state),
        )
        self.command_service(
            SetChannelValue,
            "~/set_analog_output",
            lambda r: f"set_analog_output {r.channel} = {r.value} V",
            lambda r: d.set_analog_output(r.channel, r.value),
        )
        self.command_service(
            SetBool,
            "~/set_reduced_mode",
            lambda r: f"set_reduced_mode {r.data}",
            lambda r: d.set_reduced_mode(r.data),
        )
        self.command_service(
            SetBool,
            "~/set_fence_mode",
            lambda r: f"set_fence_mode {r.data}",
            lambda r: d.set_fence_mode(r.data),
        )
        self.command_service(
            RunOfflineTask,
            "~/run_offline_task",
            lambda r: f"run_offline_task {list(r.projects)}",
            lambda r: d.run_offline_task([int(p) for p in r.projects]),
        )


def _named(name: str) -> Callable[[Any], str]:
    return lambda _request: name


def _call(action: Callable[[], tuple[int, int]]) -> Callable[[Any], tuple[int, int]]:
    return lambda _request: action()


def _board_zero(board: int, index: int) -> int:
    return board_zero_index("xArm controller", board, index)


def main(args: Sequence[str] | None = None) -> int:
    return spin_node(XArmBridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
