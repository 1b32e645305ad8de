"""The MOTEC nodes' ROS interface as data (no rclpy): ``motec_bridge.bus`` (the bus node) and
``motec_bridge.node`` (each drive node) declare these parameters; ``bridge_core.runtime.interface``
lists the nodes; tests/core/ros/test_interface.py checks the topics, services and actions
against running nodes."""

from __future__ import annotations

from bridge_core.runtime.interface import Action, Service, Topic, bridge_node, bus_node
from bridge_core.runtime.joint_commands import MAX_JUMP_SPEC
from bridge_core.runtime.parameters import DeviceDefaults, ParameterSpec
from bridge_core.runtime.stream_guard import COMMAND_TIMEOUT_RANGE_S
from bridge_core.wire.serial_timing import longest_hold_s

from .device import DEFAULT_CONFIG_REFRESH_S, DEFAULT_MAX_SPEED_RPM
from .lifeguard import lifeguard_bound_text, lifeguard_min_ms
from .motions import MOVE_TIME_MARGIN
from .registers import (
    DEFAULT_BAUDRATE,
    INTERFACE_RS485,
    MAX_DRIVES,
    OUTPUT1_COIL_CHOICES,
    OUTPUT1_COIL_DEFAULT,
)
from .units import SPEED_LIMIT_RPM

# A speed write is one FC 06 of ~2-3 ms at 115200 baud: 20 a second per drive cost a few
# percent of the bus that every drive's polls share.
VELOCITY_WRITE_RATE_HZ = 20.0
VELOCITY_RATE_RANGE_HZ = (0.5, 1000.0)  # command_rate_hz
# ~/move_to's "reached" band (live parameter): the simulator lands on the target; a real
# drive's position loop settles within a few counts of it (10 counts = 0.36 deg of a
# 10000-count motor turn).
GOAL_TOLERANCE_COUNTS = 10
GOAL_TOLERANCE_COUNTS_MAX = 1_000_000
STOP_TIMEOUT_S = 0.05
# ~/move_to without a timeout_s: limited to the move's time at its speed limit x this
# (plus the ramps' allowance, decision 17); 0 (set explicitly) = no default limit.
MOVE_TIME_MARGIN_MAX = 100.0
# position_max_velocity's bound (rad/s): a parameter range, not the drive's; the drive's
# limit is max_speed_rpm, checked when the value is written.
POSITION_MAX_VELOCITY_LIMIT = 1e6

MOTEC_DEFAULTS = DeviceDefaults(
    "MOTEC β servo drive",
    "rtu",
    poll_rate_hz=10.0,  # per drive; a poll is 2 reads (the slow group's 2 more now and then)
    baudrate=DEFAULT_BAUDRATE,
    timeout_s=0.1,  # a reply is a few ms at 115200: a dead drive costs little bus time
    # A stop or lifeguard feed sent while the drive is marked down: one try this long (a
    # reply is a few ms), so a dead line costs the other drives little per feed period.
    stop_timeout_s=STOP_TIMEOUT_S,
)


def lifeguard_text(drives_on_bus: int, hold_s: float) -> str:
    """``lifeguard_ms``'s description: its floor depends on the bus (drives, timing)."""
    return (
        f"drive watchdog 0x112/0x114: armed on connect and fed by the bridge; at "
        f"least {lifeguard_min_ms(drives_on_bus, hold_s)} ms on this bus = "
        f"{lifeguard_bound_text(drives_on_bus, hold_s)}. "
        f"0 at start: leave the drive's own setting; set to 0 at run time: disarm"
    )


DRIVE_PARAMETERS = (
    ParameterSpec("counts_per_rev", 10000.0, "encoder counts per motor revolution", 1.0, 1e9),
    ParameterSpec("gear_ratio", 1.0, "motor revolutions per joint revolution", 1e-6, 1e6),
    ParameterSpec(
        "command_timeout_s",
        0.5,
        "cmd_velocity and joint_commands deadman: stop the drive after this silence",
        *COMMAND_TIMEOUT_RANGE_S,
        live=True,
    ),
    ParameterSpec(
        "command_rate_hz",
        VELOCITY_WRITE_RATE_HZ,
        "cmd_velocity and joint_commands: most values written per second (a 0 at once)",
        *VELOCITY_RATE_RANGE_HZ,
        live=True,
    ),
    MAX_JUMP_SPEC,
    ParameterSpec(
        "position_max_velocity",
        0.0,
        "joint_commands position targets: the speed limit (rad/s of the joint) written to "
        "0xAE with a stream's first target; 0 keeps the drive's own 0xAE",
        0.0,
        POSITION_MAX_VELOCITY_LIMIT,
        live=True,
    ),
    ParameterSpec(
        "lifeguard_ms",
        0,
        "drive watchdog 0x112/0x114 (ms), armed on connect and fed by the bridge; if not 0, "
        "at least 1.5 x (0.1 s + drives x the line's longest transaction): `ros2 param "
        "describe` gives this bus's figure. 0 at start: leave the drive's own setting; set "
        "to 0 at run time: disarm",
        0,
        65535,
        live=True,
        text_of=lifeguard_text,
    ),
    ParameterSpec(
        "max_speed_rpm",
        DEFAULT_MAX_SPEED_RPM,
        "largest |speed| a command may ask (rpm)",
        1,
        SPEED_LIMIT_RPM,
    ),
    ParameterSpec(
        "config_refresh_s",
        DEFAULT_CONFIG_REFRESH_S,
        "re-read 0x6D, 0x112, 0x114 this often",
        0.5,
        3600.0,
    ),
    ParameterSpec(
        "output1_coil",
        OUTPUT1_COIL_DEFAULT,
        "coil (and output-word bit) of OUTPUT1: 0 as the FC 01 example (07 = three "
        "outputs on), 1 as the FC 05 example (OUTPUT2 at 0x0002)",
        min(OUTPUT1_COIL_CHOICES),
        max(OUTPUT1_COIL_CHOICES),
    ),
    ParameterSpec(
        "goal_tolerance_counts",
        GOAL_TOLERANCE_COUNTS,
        "~/move_to: reached when the drive stands within this many counts of its target",
        0,
        GOAL_TOLERANCE_COUNTS_MAX,
        live=True,
    ),
    ParameterSpec(
        "read_io_tables",
        False,
        "every poll also reads 0x79, FC 01 (outputs) and FC 02 (inputs): 3 more reads",
    ),
    ParameterSpec(
        "allow_unlisted_parameters",
        False,
        "~/write_parameter may write Pr.N the manual does not name (FC 06, one "
        "word; the drive checks the value and answers exception 03)",
    ),
    ParameterSpec(
        "move_time_margin",
        MOVE_TIME_MARGIN,
        "~/move_to without timeout_s: stopped after the move's time at its speed "
        "limit x this + a ramp allowance; 0 = no default limit",
        0.0,
        MOVE_TIME_MARGIN_MAX,
        live=True,
    ),
)
BUS_PARAMETERS = (
    ParameterSpec("read_only", False, "refuse ~/disable_all and ~/start_all", live=True),
    ParameterSpec(
        "interface",
        INTERFACE_RS485,
        "the line: rs485 (31 drives, §1.1.2) or rs232 (8 drives, §1.1.1)",
        choices=tuple(MAX_DRIVES),
    ),
)


def drive_parameters(drives_on_bus: int, hold_s: float) -> tuple[ParameterSpec, ...]:
    """What a drive node declares on a bus of ``drives_on_bus`` drives whose longest
    transaction holds the line ``hold_s`` (``SerialSettings.longest_hold_s``)."""
    return tuple(
        spec.described(drives_on_bus=drives_on_bus, hold_s=hold_s) for spec in DRIVE_PARAMETERS
    )


DRIVE_TOPICS = (
    Topic("~/state", "msg_defs/msg/MotecState", True, "every poll"),
    Topic("~/cmd_velocity", "std_msgs/msg/Float64", False, "rad/s of the joint; 0 stops"),
)
DRIVE_SERVICES = (
    Service(
        "~/enable",
        "std_srvs/srv/SetBool",
        "enable (true) or release (false) the motor (0x28); a release is sent as a stop",
    ),
    Service(
        "~/set_control_mode",
        "msg_defs/srv/SetControlMode",
        "network mode, then 1 velocity or 2 position control; refused while the motor turns",
    ),
    Service(
        "~/move",
        "msg_defs/srv/PositionMove",
        "point-to-point move by / to a joint angle (rad); refused unless position control, enabled",
    ),
    Service(
        "~/stop",
        "std_srvs/srv/Trigger",
        "velocity: 0xAE = 0; position: 0x29 = 0, released if it runs on; other modes: release",
    ),
    Service(
        "~/save_to_flash",
        "std_srvs/srv/Trigger",
        "save the drive's parameters to flash (0x35 = 1): they survive a restart",
    ),
    Service(
        "~/set_output",
        "msg_defs/srv/SetOutput",
        "switch one output (board 0, index 1-3) on or off",
    ),
    Service(
        "~/set_analog_max_speed",
        "msg_defs/srv/SetValue",
        "max speed of analog mode (0x6D), taken as rpm, 0-65535",
    ),
    Service(
        "~/read_parameter",
        "msg_defs/srv/ReadParameter",
        "read Pr.N (register N): a named 32-bit one whole, any other as one word",
    ),
    Service(
        "~/write_parameter",
        "msg_defs/srv/WriteParameter",
        "write Pr.N within the manual's range; read-only and service-owned ones are refused",
    ),
)
DRIVE_ACTIONS = (
    Action(
        "~/move_to",
        "msg_defs/action/MoveTo",
        "~/move as a goal; REACHED when the drive stands within goal_tolerance_counts of target",
    ),
)
BUS_TOPICS = (
    Topic(
        "~/joint_commands",
        "sensor_msgs/msg/JointState",
        False,
        "position (rad) or velocity (rad/s) per drive, by joint_states' names",
    ),
)
BUS_SERVICES = (
    Service("~/disable_all", "std_srvs/srv/Trigger", "broadcast 0x28 = 0"),
    Service("~/start_all", "std_srvs/srv/Trigger", "broadcast 0x29 = 1"),
)
# The default bus: unit_ids [1] at the defaults' baud rate and timeout.
DEFAULT_HOLD_S = longest_hold_s(DEFAULT_BAUDRATE, MOTEC_DEFAULTS.timeout_s)

NODES = (
    bus_node(
        "motec_bridge",
        "motec_bridge",
        "motec_bridge",
        "the drives' serial bus: opens it, one drive node per unit id",
        MOTEC_DEFAULTS,
        BUS_PARAMETERS,
        topics=BUS_TOPICS,
        services=BUS_SERVICES,
    ),
    bridge_node(
        "motec_bridge",
        "motec_bridge",
        "motec_{unit_id}",
        "one MOTEC β drive on the bus of motec_bridge",
        MOTEC_DEFAULTS,
        drive_parameters(1, DEFAULT_HOLD_S),
        owns_link=False,
        topics=DRIVE_TOPICS,
        services=DRIVE_SERVICES,
        actions=DRIVE_ACTIONS,
        expansion={"unit_id": (1,)},
    ),
)
