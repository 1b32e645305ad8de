"""The R6 node's ROS interface as data (no rclpy): ``r6_bridge.node`` declares these
parameters; ``bridge_core.runtime.interface`` lists the node;
tests/core/ros/test_interface.py checks the topics, services and actions against a running node."""

from __future__ import annotations

from bridge_core.runtime.interface import Action, Service, Topic, bridge_node
from bridge_core.runtime.parameters import DeviceDefaults, ParameterSpec

from .registers import COMMANDS, MAX_AXES

R6_DEFAULTS = DeviceDefaults("Huacheng R6", "tcp", poll_rate_hz=50.0, pose_topic="~/tcp_pose")
# World axes past X-W (§3.1.9 rows 2344-2347), read every poll; published when configured.
EXTRA_WORLD_AXES = ("m7", "m8")

PARAMETERS = (
    ParameterSpec(
        "gear_ratios",
        [1.0] * MAX_AXES,
        "motor rpm per joint rpm, per axis",
        item_positive=True,
    ),
    ParameterSpec(
        "rated_torques",
        [1.0] * MAX_AXES,
        "rated torque (N m) per axis; effort = fraction x this",
        item_positive=True,
    ),
    ParameterSpec(
        "m_boards",
        False,
        "the controller offers M board values: poll and switch them (R6 decision 21)",
    ),
    ParameterSpec(
        "eu_board",
        False,
        "an EU board is fitted: poll and switch its IO (R6 decision 21)",
    ),
    ParameterSpec(
        "extra_world_axes",
        0,
        "world M7/M8 values published in ~/state world_extra (0-2)",
        low=0,
        high=len(EXTRA_WORLD_AXES),
    ),
)

# The Trigger services, one per command of the map (clear_alarm_and_next has its own type).
TRIGGER_COMMANDS = tuple(name for name in COMMANDS if name != "clear_alarm_and_next")

TOPICS = (
    Topic("~/state", "msg_defs/msg/R6State", True, "every poll"),
    Topic("~/tcp_pose", "geometry_msgs/msg/PoseStamped", True, "the tool pose (world X-W)"),
)
SERVICES = (
    Service(
        "~/{command}",
        "std_srvs/srv/Trigger",
        "a controller command: 1 to its register 20000-20006; starts and clears check mode, "
        "homing, alarm",
    ),
    Service(
        "~/clear_alarm_and_next",
        "msg_defs/srv/ClearAlarmAndNext",
        "clear the alarm and skip the step that raised it (20005); only with skip_failed_step true",
    ),
    Service(
        "~/set_global_speed",
        "msg_defs/srv/SetValue",
        "the global speed, value in percent 0-100 (0.1 % steps)",
    ),
    Service(
        "~/set_output",
        "msg_defs/srv/SetOutput",
        "switch one output (index 0-31) of an IO board in use (0-4), an M board (5-7) or the EU "
        "board (8)",
    ),
    Service(
        "~/set_board_outputs",
        "msg_defs/srv/SetOutputBoard",
        "set the outputs in mask of one IO board (0-4) at once; a partial mask reads the "
        "board first",
    ),
    Service(
        "~/set_counter",
        "msg_defs/srv/SetCounter",
        "set a listed counter's current value; success when it reads back as written",
    ),
    Service("~/list_counters", "msg_defs/srv/ListCounters", "the ids of the controller's counters"),
    Service(
        "~/read_counter",
        "msg_defs/srv/ReadCounter",
        "a counter's target and current value (selecting it is a write: refused if read_only)",
    ),
    Service(
        "~/read_parameter",
        "msg_defs/srv/ReadParameter",
        "one int32 entry of the parameter table (index 0-999, not 915)",
    ),
    Service(
        "~/write_parameter",
        "msg_defs/srv/WriteParameter",
        "write one parameter (index 0-964, not 915); success when it reads back as written",
    ),
    Service(
        "~/read_data_source",
        "msg_defs/srv/ReadDataSource",
        "how many points a data source holds (selecting it is a write: refused if read_only)",
    ),
    Service(
        "~/upload_points",
        "msg_defs/srv/UploadPoints",
        "replace a data source's points with raw values, in one call; answers frames_sent",
    ),
)
ACTIONS = (
    Action(
        "~/upload_points",
        "msg_defs/action/PointUpload",
        "the same upload frame by frame, with progress; an upload that does not finish "
        "clears the source",
    ),
    Action(
        "~/run_cycle",
        "msg_defs/action/RunCycle",
        "run the program: one cycle (REACHED when it ran and ended) or until stopped",
    ),
)

NODES = (
    bridge_node(
        "r6_bridge",
        "r6_bridge",
        "r6_bridge",
        "one Huacheng R6 controller on its own Modbus TCP link",
        R6_DEFAULTS,
        PARAMETERS,
        topics=TOPICS,
        services=SERVICES,
        actions=ACTIONS,
        expansion={"command": TRIGGER_COMMANDS},
    ),
)
