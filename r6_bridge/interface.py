"""The R6 node's ROS interface as data (no rclpy): ``r6_bridge.node`` declares these
parameters; ``bridge_core.runtime.interface`` lists the node; tests/test_interface.py checks the
topics, services and actions against a running node."""

from __future__ import annotations

from bridge_core.runtime.interface import Action, Service, Topic, bridge_node
from bridge_core.runtime.parameters import DeviceDefaults, ParameterSpec

from .registers import COMMANDS, MAX_AXES

R6_DEFAULTS = DeviceDefaults("Huacheng R6", "tcp", poll_rate_hz=50.0)
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
        "the controller offers M board values: poll and switch them (decision 21)",
    ),
    ParameterSpec(
        "eu_board",
        False,
        "an EU board is fitted: poll and switch its IO (decision 21)",
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
    Service("~/{command}", "std_srvs/srv/Trigger", "a controller command (coil write)"),
    Service("~/clear_alarm_and_next", "msg_defs/srv/ClearAlarmAndNext"),
    Service("~/set_global_speed", "msg_defs/srv/SetValue"),
    Service("~/set_output", "msg_defs/srv/SetOutput"),
    Service("~/set_board_outputs", "msg_defs/srv/SetOutputBoard"),
    Service("~/set_counter", "msg_defs/srv/SetCounter"),
    Service("~/list_counters", "msg_defs/srv/ListCounters"),
    Service("~/read_counter", "msg_defs/srv/ReadCounter"),
    Service("~/read_parameter", "msg_defs/srv/ReadParameter"),
    Service("~/write_parameter", "msg_defs/srv/WriteParameter"),
    Service("~/read_data_source", "msg_defs/srv/ReadDataSource"),
    Service("~/upload_points", "msg_defs/srv/UploadPoints"),
)
ACTIONS = (
    Action("~/upload_points", "msg_defs/action/PointUpload"),
    Action("~/run_cycle", "msg_defs/action/RunCycle"),
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
