"""ROS 2 node for the UFactory xArm controller (docs/bridges/xarm.md)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from geometry_msgs.msg import PoseStamped

from bridge_core.ros.node_base import BridgeNode, copy_fields
from bridge_core.ros.node_services import Command, trigger
from bridge_core.ros.process import spin_node
from bridge_core.runtime.checks import board_zero_index, listed
from bridge_core.runtime.diagnostics import Level, Report
from bridge_core.runtime.rate_groups import PollGroups
from bridge_core.runtime.units import (
    DEG,
    MM,
    euler_xyz_deg_to_quaternion,
    quaternion_angle_deg,
    rotation_vector_deg_to_quaternion,
)
from bridge_core.wire.errors import ConfigurationError, NotConfirmed
from msg_defs.msg import XArmState

from .device import XArmDevice, XArmSnapshot
from .interface import PARAMETERS, SERVICES, XARM_DEFAULTS
from .registers import (
    ORIENTATION_MISMATCH_DEG,
    SET_STATE_START,
    USER_COILS,
    WORLD,
    error_text,
    mode_name,
    state_name,
    warning_text,
)

T = TypeVar("T")


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


# The axis of what the services set moving (the node's motion ledger).
ARM = "arm"


class XArmBridgeNode(BridgeNode[XArmSnapshot]):
    """The xArm controller: one node per arm, on its own TCP link."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("xarm_bridge", XARM_DEFAULTS, **kwargs)
        values = self.declare_specs(PARAMETERS)
        first, count = int(values["user_coil_first"]), int(values["user_coil_count"])
        if first + count > USER_COILS.stop:
            raise ConfigurationError(
                f"user_coil_first {first} + user_coil_count {count} runs past coil "
                f"{USER_COILS.stop - 1}, the last user coil"
            )
        self.joint_count = int(values["joint_count"])
        self.user_coil_first = first
        self.device = XArmDevice(
            self.channel,
            self.joint_count,
            range(first, first + count),
            slow_period_s=self.slow_poll_period_s,
        )
        self.joint_names = [f"{self.joint_prefix}joint{j}" for j in range(1, self.joint_count + 1)]
        self.state_pub = self.create_publisher(XArmState, "~/state", 10)
        self.pose_pub = self.create_publisher(PoseStamped, "~/tcp_pose", 10)
        self._create_services()

    # ------------------------------------------------------------ polling
    def poll_groups(self) -> PollGroups:
        return self.device.groups

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
        m.slow_stamp = self.stamp(s.slow_read_time)
        m.state_name = state_name(s.state)
        m.error_text = error_text(s.error_code)
        m.warning_text = warning_text(s.warning_code)
        m.joint_temperatures = list(s.joint_temperatures_c)
        m.tcp_speed = s.tcp_speed_mm_s * MM
        m.tcp_load_mass = s.tcp_load_mass_kg
        m.tcp_load_center = [c * MM for c in s.tcp_load_center_mm]
        m.tcp_offset = _pose6(s.tcp_offset)
        m.base_offset = _pose6(s.base_offset)
        m.tcp_rotation_vector = [a * DEG for a in s.tcp_rotation_vector_deg]
        m.user_coil_first = self.user_coil_first
        m.user_coils = list(s.user_coils)
        self.state_pub.publish(m)

    def device_report(self) -> Report | None:
        s = self.last_snapshot
        if s is None:
            return None
        mismatch = orientation_mismatch_deg(s)
        values = [
            ("mode", f"{s.mode} ({mode_name(s.mode)})"),
            ("state", f"{s.state} ({state_name(s.state)})"),
            ("error code", f"{s.error_code} {error_text(s.error_code)}".strip()),
            ("warning code", f"{s.warning_code} {warning_text(s.warning_code)}".strip()),
            ("joints", str(self.joint_count)),
            ("roll/pitch/yaw vs rx/ry/rz (deg)", f"{mismatch:.2f}"),
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
        if mismatch > ORIENTATION_MISMATCH_DEG:
            return Report(
                Level.WARN,
                f"tcp orientation: roll/pitch/yaw and rx/ry/rz differ by {mismatch:.1f} deg: "
                "~/tcp_pose's Euler convention may not be the controller's (or I70-72 "
                "are not filled by this firmware)",
                values,
            )
        return Report(Level.OK, "connected", values)

    # ------------------------------------------------------------ services
    # One table: the handler of each row of interface.SERVICES (the log text and the device
    # call); splitting it would scatter the node's interface.
    def _create_services(self) -> None:
        d = self.device

        def halt(what: str, action: Callable[[], str]) -> Command[str]:
            # Stop and pause: C145 / C144 and H33 at once, answered from H33 read back
            # (decisions 6, 19).
            return trigger(what, action, stop=True, fill=_written, stops_axes=(ARM,))

        # What sets the arm moving: a halt (deactivate, exit, read_only) stops it (C145
        # and H33 = 4); a stop the arm does not show is logged "sent, not confirmed".
        arm_started = (ARM, _halt_stop(d.stop))
        self.command_services.create(
            SERVICES,
            {
                "~/pause": halt("pause", d.pause),
                "~/stop": halt("stop", d.stop),
                "~/resume": trigger("resume", d.resume, fill=_written, starts=arm_started),
                "~/set_mode": Command(
                    lambda r: f"set_mode {r.value}",
                    lambda r: d.set_mode(r.value),
                    fill=lambda response, _: setattr(
                        response, "message", response.message + " (in force after set_state 0)"
                    ),
                ),
                "~/set_state": Command(
                    lambda r: f"set_state {r.value}",
                    lambda r: d.command_state(r.value),
                    fill=_written,
                    starts=lambda r: arm_started if r.value == SET_STATE_START else None,
                ),
                "~/set_digital_output": Command(
                    lambda r: f"set_digital_output {r.index} {'on' if r.state else 'off'}",
                    lambda r: d.set_digital_output(_board_zero(r.board, r.index), r.state),
                ),
                "~/set_digital_outputs": Command(
                    lambda r: f"set_digital_outputs {_pairs(r)}",
                    lambda r: d.set_digital_outputs(list(r.indexes), list(r.states)),
                    fill=_written,
                ),
                "~/set_user_coils": Command(
                    lambda r: f"set_user_coils {_pairs(r)}",
                    lambda r: d.set_user_coils(list(r.indexes), list(r.states)),
                    fill=_written,
                ),
                "~/set_joint_enable": Command(
                    lambda r: (
                        "set_joint_enable "
                        f"{'all joints' if r.joint == 0 else f'joint {r.joint}'} "
                        f"{'enable' if r.enable else 'disable'}"
                    ),
                    lambda r: d.set_joint_enable(r.joint, r.enable),
                    fill=_written,
                    stop=lambda r: not r.enable,  # disabling ends motion: tried at once
                    stops_axes=lambda r: (ARM,) if not r.enable and r.joint == 0 else (),
                ),
                "~/set_tool_digital_output": Command(
                    lambda r: f"set_tool_digital_output {r.index} {'on' if r.state else 'off'}",
                    lambda r: d.set_tool_digital_output(_board_zero(r.board, r.index), r.state),
                ),
                "~/set_analog_output": Command(
                    lambda r: f"set_analog_output {r.channel} = {r.value} V",
                    lambda r: d.set_analog_output(r.channel, r.value),
                ),
                # Off only with confirm (decision 17); read back either way.
                "~/set_reduced_mode": Command(
                    lambda r: f"set_reduced_mode {r.data}",
                    lambda r: d.set_reduced_mode(r.data, r.confirm),
                    fill=_written,
                ),
                "~/set_fence_mode": Command(
                    lambda r: f"set_fence_mode {r.data}",
                    lambda r: d.set_fence_mode(r.data, r.confirm),
                    fill=_written,
                ),
                "~/run_offline_task": Command(
                    lambda r: f"run_offline_task {listed(r.projects, 'projects', bracketed=True)}",
                    lambda r: d.run_offline_task([int(p) for p in r.projects]),
                    fill=_written,
                    starts=lambda _r: arm_started,
                ),
            },
        )


def orientation_mismatch_deg(s: XArmSnapshot) -> float:
    """The angle between the orientation of roll/pitch/yaw and of rx/ry/rz (deg)."""
    p = s.tcp_pose
    return quaternion_angle_deg(
        euler_xyz_deg_to_quaternion(p["roll"], p["pitch"], p["yaw"]),
        rotation_vector_deg_to_quaternion(*s.tcp_rotation_vector_deg),
    )


def _pairs(request: Any) -> str:
    """``indexes``/``states`` of a SetOutputs request as "2 on, 9 off" (as given), or
    their count when that would be long (``listed``)."""
    states = ["on" if state else "off" for state in request.states]
    pairs = [
        f"{index} {states[k] if k < len(states) else '?'}"
        for k, index in enumerate(request.indexes)
    ]
    return listed(pairs, "outputs")


def _halt_stop(stop: Callable[[], str]) -> Callable[[], str]:
    """A halt's stop of what the services started: NotConfirmed says "sent, not
    confirmed" in the halt's log line (and the stop is tried again, ``MotionLedger``)."""

    def halt_stop() -> str:
        try:
            return stop()
        except NotConfirmed as err:
            raise NotConfirmed(f"sent, not confirmed: {err}") from None

    return halt_stop


def _written(response: Any, written: str) -> None:
    response.message += f" ({written})"


def _board_zero(board: int, index: int) -> int:
    return board_zero_index("xArm controller", board, index)


def main(args: Sequence[str] | None = None) -> int:
    return spin_node(XArmBridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
