"""The stepper nodes' ROS interface as data (no rclpy): ``stepper_bridge.node`` and
``stepper_bridge.bus`` declare these parameters; ``bridge_core.runtime.interface`` lists the nodes;
tests/core/ros/test_interface.py checks the topics, services and actions against running nodes."""

from __future__ import annotations

from bridge_core.runtime.interface import Action, Service, Topic, bridge_node, bus_node
from bridge_core.runtime.joint_commands import MAX_JUMP_SPEC
from bridge_core.runtime.parameters import DeviceDefaults, ParameterSpec
from bridge_core.runtime.stream_guard import COMMAND_TIMEOUT_RANGE_S

from .device import DEFAULT_CONFIG_REFRESH_S, DESTRUCTIVE_COMMANDS, SYSTEM_COMMANDS
from .interpolation import PAIR_READING_CHOICES, PAIR_READING_UNSET
from .jog import DEFAULT_JOG_TIMEOUT_S
from .registers import DEFAULT_BAUDRATE, MOTOR_ACTIONS, MOTORS, REPLY_DELAY_S
from .units import DEFAULT_UNITS_PER_METER

# A jog speed change is one FC 06 of ~52 ms at 9600 baud with the manual's 35 ms reply
# delay (plus a direction coil when it reverses): 5 a second per motor leave the polls
# most of the line.
JOG_WRITE_RATE_HZ = 5.0
JOG_RATE_RANGE_HZ = (0.5, 100.0)  # command_rate_hz
# Actions' "reached" band (live parameter goal_tolerance): one step of the coordinate
# registers (x100 of the user's unit, 40108+); an open-loop stepper ends on its target.
GOAL_TOLERANCE_UNITS = 0.01

STEPPER_DEFAULTS = DeviceDefaults(
    "stepper controller",
    "rtu",
    poll_rate_hz=3.0,  # a poll takes ~0.22 s of wire at 9600 baud (stepper decision 21)
    baudrate=DEFAULT_BAUDRATE,
    # No baud rate makes a reply come sooner than 35 ms; the floor at the configured baud
    # rate is checked at start (check_reply_timeout).
    timeout_min_s=REPLY_DELAY_S,
    # A stop coil's reply is 8 bytes, no sooner than 35 ms after the request: the least
    # timeout the manual's rule allows is plenty, and keeps a stop over a line that comes
    # back within 0.3 s of it (bench/stop_after_outage.py). Scaled with the baud rate at
    # start (StepperBridgeNode); this is its value at the default 9600.
    stop_timeout_s=0.15,
)

PARAMETERS = (
    ParameterSpec(
        "joint_types",
        ["prismatic"] * MOTORS,
        "per motor: prismatic (m) or revolute (rad)",
    ),
    ParameterSpec(
        "units_per_meter",
        [DEFAULT_UNITS_PER_METER] * MOTORS,
        "per prismatic motor: controller units per metre (1000: mm)",
        item_positive=True,
    ),
    ParameterSpec(
        "units_per_revolution",
        [0.0] * MOTORS,
        "per revolute motor: controller units per joint revolution "
        "(0: the lead read from the controller, i.e. no reduction)",
    ),
    ParameterSpec(
        "command_timeout_s",
        DEFAULT_JOG_TIMEOUT_S,
        "jog and joint_commands deadman: stop a motor after this silence",
        *COMMAND_TIMEOUT_RANGE_S,
        live=True,
    ),
    ParameterSpec(
        "command_rate_hz",
        JOG_WRITE_RATE_HZ,
        "jog and joint_commands: most values written per second per motor (a 0 at once)",
        *JOG_RATE_RANGE_HZ,
        live=True,
    ),
    MAX_JUMP_SPEC,
    ParameterSpec(
        "goal_tolerance",
        GOAL_TOLERANCE_UNITS,
        "actions: a motion reached its target when each coordinate is within "
        "this many controller units of it",
        0.0,
        1e6,
        live=True,
    ),
    ParameterSpec(
        "interpolation_pair_reading",
        PAIR_READING_UNSET,
        "which motors interpolation pairs 2 and 3 drive: the manual's type rows "
        "(2 = motors 1+3, 3 = 2+3) or point rows (2 = 2+3, 3 = 1+3); unset "
        "refuses pairs 2 and 3 until the hardware check in docs/decisions/stepper.md",
        choices=PAIR_READING_CHOICES,
    ),
    ParameterSpec(
        "zero_after_home",
        False,
        "home actions: after the home input is reached, send the zero coordinates "
        "coil (00044, every motor's coordinate) and check the homed motors read 0",
    ),
    ParameterSpec(
        "config_refresh_s",
        DEFAULT_CONFIG_REFRESH_S,
        "re-read the motor parameters this often",
        0.5,
        3600.0,
    ),
)

TOPICS = (
    Topic("~/state", "msg_defs/msg/StepperState", True, "every poll"),
    Topic("~/motor_{motor}/jog", "std_msgs/msg/Float64", False, "motor rpm; 0 stops"),
    Topic(
        "~/joint_commands",
        "sensor_msgs/msg/JointState",
        False,
        "position (m / rad) or velocity (m/s / rad/s) per motor, by joint_states' names",
    ),
)
SERVICES = (
    Service("~/motor_{motor}/{motor_action}", "std_srvs/srv/Trigger", "the motor's coil"),
    Service(
        "~/motor_{motor}/move_by",
        "msg_defs/srv/MoveBy",
        "single run by a signed distance (m / rad): direction, run distance, single-run coil",
    ),
    Service(
        "~/motor_{motor}/configure",
        "msg_defs/srv/ConfigureMotor",
        "write the motor's step angle, microstep, start / accel Hz, speed and lead",
    ),
    Service(
        "~/motor_{motor}/set_speed",
        "msg_defs/srv/SetInteger",
        "the motor's speed in rpm (0-65535): single run, forward / reverse, homing",
    ),
    Service(
        "~/motor_{motor}/set_direction",
        "msg_defs/srv/SetInteger",
        "single-run direction: 0 positive, 1 negative",
    ),
    Service(
        "~/motor_{motor}/set_run_distance",
        "msg_defs/srv/SetValue",
        "single-run distance in m / rad, a magnitude (the sign is set_direction's)",
    ),
    Service(
        "~/motor_{motor}/set_round_trips",
        "msg_defs/srv/SetInteger",
        "the motor's round trips in system mode 1 (0-65535, 0 = endless)",
    ),
    Service(
        "~/motor_{motor}/set_limit_inputs",
        "msg_defs/srv/SetLimitInputs",
        "which inputs (1-13, 0 = none) are the motor's positive limit, negative limit and home",
    ),
    Service("~/{system_command}", "std_srvs/srv/Trigger", "an all-motor or system coil"),
    Service(
        "~/{destructive_command}",
        "msg_defs/srv/ConfirmedCommand",
        "restore factory settings or clear all parameters; only with confirm = the service's name",
    ),
    Service(
        "~/set_output",
        "msg_defs/srv/SetOutput",
        "switch one output (board 0, index 1-12) on or off",
    ),
    Service(
        "~/set_all_outputs",
        "std_srvs/srv/SetBool",
        "switch every output on (true) or off (false)",
    ),
    Service(
        "~/set_homing_order",
        "msg_defs/srv/SetHomingOrder",
        "the motors ~/home_all homes, in order (up to 5 distinct; the other slots 0)",
    ),
    Service(
        "~/set_system_mode",
        "msg_defs/srv/SetInteger",
        "the controller's system mode: 0 normal, 1-5 input-driven modes",
    ),
    Service(
        "~/line_move",
        "msg_defs/srv/LineMove",
        "line interpolation of a motor pair to absolute points (m / rad); refused while one runs",
    ),
    Service(
        "~/arc_move",
        "msg_defs/srv/ArcMove",
        "arc interpolation of a motor pair through absolute points; refused while one runs",
    ),
    Service(
        "~/stop_interpolation",
        "std_srvs/srv/Trigger",
        "stop a line or arc (both interpolation stop coils and its motors' stop coils)",
    ),
)
ACTIONS = (
    Action(
        "~/motor_{motor}/move_by",
        "msg_defs/action/StepperMoveBy",
        "single run as a goal; REACHED when the motor stands within goal_tolerance of target",
    ),
    Action(
        "~/motor_{motor}/home",
        "msg_defs/action/StepperRun",
        "home the motor; REACHED when it stands with its home input on",
    ),
    Action(
        "~/home_all",
        "msg_defs/action/StepperRun",
        "home the motors of the homing order; REACHED when each stands with its home input on",
    ),
    Action(
        "~/return_to_zero",
        "msg_defs/action/StepperRun",
        "every motor back to coordinate 0; REACHED when all stand within goal_tolerance of 0",
    ),
    Action(
        "~/line_move",
        "msg_defs/action/LineMotion",
        "line interpolation as a goal; REACHED when both motors of the pair stand at end",
    ),
    Action(
        "~/arc_move",
        "msg_defs/action/ArcMotion",
        "arc interpolation as a goal; REACHED when both motors of the pair stand at end",
    ),
)
EXPANSION = {
    "motor": tuple(range(1, MOTORS + 1)),
    "motor_action": MOTOR_ACTIONS,
    "system_command": SYSTEM_COMMANDS,
    "destructive_command": DESTRUCTIVE_COMMANDS,
}
# stepper_bus: the default unit_ids (bridge_core.runtime.parameters.UNIT_IDS_SPEC).
BUS_EXPANSION = {**EXPANSION, "unit_id": (1,)}

NODES = (
    bridge_node(
        "stepper_bridge",
        "stepper_bridge",
        "stepper_bridge",
        "one stepper controller on its own serial line",
        STEPPER_DEFAULTS,
        PARAMETERS,
        topics=TOPICS,
        services=SERVICES,
        actions=ACTIONS,
        expansion=EXPANSION,
    ),
    bus_node(
        "stepper_bridge",
        "stepper_bus",
        "stepper_bus",
        "the RS-485 line several controllers share: opens it, one node per unit id",
        STEPPER_DEFAULTS,
    ),
    bridge_node(
        "stepper_bridge",
        "stepper_bus",
        "stepper_{unit_id}",
        "one controller on the bus of stepper_bus",
        STEPPER_DEFAULTS,
        PARAMETERS,
        owns_link=False,
        topics=TOPICS,
        services=SERVICES,
        actions=ACTIONS,
        expansion=BUS_EXPANSION,
    ),
)
