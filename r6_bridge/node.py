"""ROS 2 node for the Huacheng R6 controller (docs/bridges/r6.md)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from geometry_msgs.msg import PoseStamped

from bridge_core.ros.node_base import BridgeNode, copy_fields
from bridge_core.ros.node_services import Command
from bridge_core.ros.process import spin_node
from bridge_core.runtime.diagnostics import Level, Report
from bridge_core.runtime.parameters import padded
from bridge_core.runtime.rate_groups import PollGroups
from bridge_core.runtime.units import DEG, MM, RPM_TO_RAD_S, euler_xyz_deg_to_quaternion
from bridge_core.wire.errors import CommandRejected, DeviceException, FrameError
from msg_defs.msg import R6State

from .device import R6Device, R6Snapshot
from .interface import (
    ACTIONS,
    EXTRA_WORLD_AXES,
    PARAMETERS,
    R6_DEFAULTS,
    SERVICES,
    TRIGGER_COMMANDS,
)
from .motions import RunCycleMotion
from .program import PROGRAM, PROGRAM_COMMANDS
from .registers import COMMANDS, MAX_AXES, STOP_COMMANDS
from .upload import POINT_DATA, PointUploadSteps

T = TypeVar("T")

# R6State fields copied as they are from the snapshot (same names, same units).
STATE_FIELDS = (
    "mode",
    "mode_name",
    "alarm_code",
    "moving",
    "homed",
    "global_speed_percent",
    "current_cycle_time_ms",
    "last_cycle_time_ms",
    "machine_id",
    "axis_count",
    "io_board_count",
    "io_board_inputs",
    "io_board_outputs",
)


class R6BridgeNode(BridgeNode[R6Snapshot]):
    """The R6 controller: one node per controller, on its own TCP link."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("r6_bridge", R6_DEFAULTS, **kwargs)
        values = self.declare_specs(PARAMETERS)
        self.extra_world_axes = EXTRA_WORLD_AXES[: int(values["extra_world_axes"])]
        self.gear_ratios = padded(values["gear_ratios"], MAX_AXES, 1.0)
        self.rated_torques = padded(values["rated_torques"], MAX_AXES, 1.0)
        self.device = R6Device(
            self.channel,
            m_boards=bool(values["m_boards"]),
            eu_board=bool(values["eu_board"]),
            slow_period_s=self.slow_poll_period_s,
        )
        self.firmware_version = ""

        self.state_pub = self.create_publisher(R6State, "~/state", 10)
        self.pose_pub = self.create_publisher(PoseStamped, "~/tcp_pose", 10)

        self._create_services()

    # ------------------------------------------------------------ polling
    def on_link_up(self) -> None:
        self.device.invalidate_plan()
        self.device.cycle_time_written_at = None  # decision 23: maybe another controller
        try:
            self.firmware_version = self.device.read_version()
        except (DeviceException, FrameError) as err:
            # A controller without the version rows still gets polled.
            self.firmware_version = f"unavailable ({err})"
        self.get_logger().info(f"R6 firmware {self.firmware_version!r}")

    def poll_groups(self) -> PollGroups:
        return self.device.groups

    def poll_device(self) -> R6Snapshot:
        return self.device.poll()

    def replan(self) -> None:
        self.device.invalidate_plan()

    def publish_snapshot(self, snapshot: R6Snapshot) -> None:
        axes = len(snapshot.axis_positions_deg)  # the controller's axis count, may change
        if len(self.joint_names) != axes:
            self.joint_names = [f"{self.joint_prefix}joint_{a}" for a in range(1, axes + 1)]
        self.publish_joints(
            snapshot.read_time,
            [deg * DEG for deg in snapshot.axis_positions_deg],
            [
                rpm * RPM_TO_RAD_S / self.gear_ratios[a]
                for a, rpm in enumerate(snapshot.axis_speeds_rpm)
            ],
            [t * self.rated_torques[a] for a, t in enumerate(snapshot.axis_torques_rated)],
        )
        # Each message carries the read time of the rows it holds (decision 26).
        state_time = snapshot.state_read_time or snapshot.read_time
        state = copy_fields(self.stamped(R6State(), state_time), snapshot, STATE_FIELDS)
        state.slow_stamp = self.stamp(snapshot.slow_read_time)
        state.world_extra = [snapshot.world[axis] for axis in self.extra_world_axes]
        state.m_board_inputs = list(snapshot.m_board_inputs)
        state.m_board_outputs = list(snapshot.m_board_outputs)
        if snapshot.eu_board_input is not None and snapshot.eu_board_output is not None:
            state.eu_board_inputs = [snapshot.eu_board_input]
            state.eu_board_outputs = [snapshot.eu_board_output]
        self.state_pub.publish(state)

        pose = self.stamped(PoseStamped(), snapshot.world_read_time or snapshot.read_time)
        world = snapshot.world
        pose.pose.position.x = world["x"] * MM
        pose.pose.position.y = world["y"] * MM
        pose.pose.position.z = world["z"] * MM
        q = euler_xyz_deg_to_quaternion(world["u"], world["v"], world["w"])
        (
            pose.pose.orientation.x,
            pose.pose.orientation.y,
            pose.pose.orientation.z,
            pose.pose.orientation.w,
        ) = q
        self.pose_pub.publish(pose)

    def device_report(self) -> Report | None:
        values = [("firmware version", self.firmware_version or "unknown")]
        snapshot = self.last_snapshot
        if snapshot is None:
            return Report(Level.OK, "connected", values)
        values += [
            ("mode", snapshot.mode_name),
            ("alarm code", f"{snapshot.alarm_code} (0x{snapshot.alarm_code:04X})"),
            ("moving", str(snapshot.moving)),
            ("homed", str(snapshot.homed)),
        ]
        if snapshot.alarm_code:
            # The R6 Modbus manual lists no alarm texts; the code is shown as read.
            return Report(
                Level.WARN,
                f"controller alarm {snapshot.alarm_code} "
                f"(0x{snapshot.alarm_code:04X}; the R6 Modbus manual gives no text)",
                values,
            )
        return Report(Level.OK, "connected", values)

    def _boards_in_use(self) -> int | None:
        snapshot = self.last_snapshot
        return None if snapshot is None else snapshot.io_board_count

    # ------------------------------------------------------------ services
    @property
    def _program_started(self) -> tuple[str, Callable[[], object]]:
        """A program a service set running: a halt pauses it (20001, the goals' end too,
        decision 23: the step is kept for the operator's next start), confirmed as
        ``~/pause`` is (decision 29: "not confirmed" in the log otherwise)."""
        return PROGRAM, lambda: self.device.halt("pause")

    # One table: the handler of each row of interface.SERVICES / ACTIONS (the log text and
    # the device call); splitting it would scatter the node's interface.
    def _create_services(self) -> None:
        d = self.device

        def command(command: str) -> Command[str]:
            # Done only when the controller shows it (decision 29): the reply says what
            # was written and read back.
            return Command(
                _constant(command),
                _constant_call(_command(d, command)),
                stop=command in STOP_COMMANDS,
                starts=(lambda _r: self._program_started) if command in PROGRAM_COMMANDS else None,
                stops_axes=(lambda _r: (PROGRAM,)) if command in STOP_COMMANDS else None,
                fill=_said,
            )

        self.command_services.create(
            SERVICES,
            {
                "~/{command}": command,
                "~/clear_alarm_and_next": Command(
                    lambda r: f"clear_alarm_and_next (skip_failed_step {r.skip_failed_step})",
                    lambda r: d.run_program(
                        "clear_alarm_and_next", skip_failed_step=bool(r.skip_failed_step)
                    ),
                    starts=lambda _r: self._program_started,
                    fill=_said,
                ),
                "~/set_global_speed": Command(
                    lambda r: f"set_global_speed {r.value} %",
                    lambda r: d.set_global_speed_read_back(r.value),
                    fill=_said,
                ),
                "~/set_output": Command(
                    lambda r: (
                        f"set_output board {r.board} point {r.index} {'on' if r.state else 'off'}"
                    ),
                    lambda r: d.set_output(r.board, r.index, r.state, self._boards_in_use()),
                ),
                "~/set_board_outputs": Command(
                    lambda r: (
                        f"set_board_outputs board {r.board} = 0x{r.bits:08X} mask 0x{r.mask:08X}"
                    ),
                    lambda r: d.write_board_outputs(r.board, r.bits, r.mask, self._boards_in_use()),
                    fill=_said,
                ),
                "~/set_counter": Command(
                    lambda r: f"set_counter {r.id} = {r.value}",
                    lambda r: d.set_counter(r.id, r.value),
                    fill=_said,
                ),
                "~/list_counters": Command(
                    lambda r: "list_counters",
                    lambda r: d.read_counter_ids(),
                    writes=False,
                    fill=lambda response, ids: setattr(response, "ids", ids),
                ),
                "~/read_counter": Command(
                    lambda r: f"read_counter {r.id}",
                    lambda r: d.read_counter(r.id),  # writes the id to 2179: refused if read_only
                    fill=_fill_counter,
                ),
                "~/read_parameter": Command(
                    lambda r: f"read_parameter {r.index}",
                    lambda r: d.read_parameter(r.index),
                    writes=False,
                    fill=lambda response, value: setattr(response, "value", value),
                ),
                "~/write_parameter": Command(
                    lambda r: f"write_parameter {r.index} = {r.value}",
                    lambda r: d.write_parameter(r.index, r.value),
                    fill=_said,
                ),
                "~/read_data_source": Command(
                    lambda r: f"read_data_source {r.source_id}",
                    lambda r: self._unless_uploading(  # writes 30000: refused if read_only
                        lambda: d.read_data_source_length(r.source_id)
                    ),
                    fill=lambda response, points: setattr(response, "points", points),
                ),
                "~/upload_points": Command(
                    lambda r: f"upload_points to source {r.data_source_id}",
                    lambda r: self._unless_uploading(
                        lambda: d.upload_points(
                            r.data_source_id,
                            r.values_per_point,
                            r.axis_mask,
                            [int(v) for v in r.values],
                        )
                    ),
                    fill=lambda response, frames: setattr(response, "frames_sent", frames),
                ),
            },
            {"command": TRIGGER_COMMANDS},
        )
        # The upload as an action too (docs/actions.md): progress, cancel, a result when done.
        self.actions.create(
            ACTIONS,
            {
                "~/upload_points": lambda goal: PointUploadSteps(
                    d,
                    goal.data_source_id,
                    goal.values_per_point,
                    goal.axis_mask,
                    [int(v) for v in goal.values],
                ),
                "~/run_cycle": lambda goal: RunCycleMotion(
                    d, self.last_snapshot, single_cycle=bool(goal.single_cycle)
                ),
            },
        )

    def _unless_uploading(self, action: Callable[[], T]) -> T:
        """The point-data rows (30000-30006) between two frames of an upload goal would
        send its next frames to another source: refused while one runs."""
        if (goal := self.actions.occupied(POINT_DATA)) is not None:
            raise CommandRejected(f"the {goal} goal is using the point-data rows")
        return action()


def _command(device: R6Device, name: str) -> Callable[[], str]:
    """A command service's action: the ones that set the program running are checked
    first (decision 23: nothing written unless the controller is in auto mode, homed and,
    for start and single cycle, without an alarm); the stops go out as they are. Starts,
    single cycles and stops are done only when read back (decision 29)."""
    if name in PROGRAM_COMMANDS:
        return lambda: device.run_program(name)
    if name in STOP_COMMANDS:
        return lambda: device.halt(name)

    def command() -> str:
        device.command(name)
        return f"wrote {COMMANDS[name]} = 1 ({name})"

    return command


def _constant(text: str) -> Callable[[Any], str]:
    return lambda _request: text


def _constant_call(action: Callable[[], str]) -> Callable[[Any], str]:
    return lambda _request: action()


def _said(response: Any, text: str) -> None:
    """A command's own account of what it read back, after "done"."""
    response.message += f" ({text})"


def _fill_counter(response: Any, values: tuple[int, int, int]) -> None:
    """ReadCounter's reply from (id, target, current) as read."""
    _, response.target, response.current = values


def main(args: Sequence[str] | None = None) -> int:
    return spin_node(R6BridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
