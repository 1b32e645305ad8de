"""The xArm node's ROS interface as data (no rclpy): ``xarm_bridge.node`` declares these
parameters; ``bridge_core.runtime.interface`` lists the node; tests/test_interface.py checks the
topics and services against a running node."""

from __future__ import annotations

from bridge_core.runtime.interface import Service, Topic, bridge_node
from bridge_core.runtime.parameters import DeviceDefaults, ParameterSpec

from .registers import JOINT_COUNTS, JOINTS, USER_COILS

XARM_DEFAULTS = DeviceDefaults("UFactory xArm", "tcp", poll_rate_hz=50.0)

PARAMETERS = (
    ParameterSpec(
        "joint_count",
        JOINTS,
        "joints of the arm: 5 (xArm 5), 6 (xArm 6, Lite 6) or 7 (xArm 7)",
        JOINT_COUNTS.start,
        JOINT_COUNTS.stop - 1,
    ),
    ParameterSpec(
        "user_coil_first",
        USER_COILS.start,
        "first user coil (C256-511) read into ~/state and writable",
        USER_COILS.start,
        USER_COILS.stop - 1,
    ),
    ParameterSpec(
        "user_coil_count",
        0,
        "user coils read from user_coil_first on (0: none; any other adds one "
        "FC 01 request to every poll)",
        0,
        len(USER_COILS),
    ),
)

TOPICS = (
    Topic("~/state", "msg_defs/msg/XArmState", True, "every poll"),
    Topic("~/tcp_pose", "geometry_msgs/msg/PoseStamped", True, "the tool pose"),
)
SERVICES = (
    Service("~/pause", "std_srvs/srv/Trigger"),
    Service("~/stop", "std_srvs/srv/Trigger"),
    Service("~/resume", "std_srvs/srv/Trigger"),
    Service("~/set_mode", "msg_defs/srv/SetInteger"),
    Service("~/set_state", "msg_defs/srv/SetInteger"),
    Service("~/set_digital_output", "msg_defs/srv/SetOutput"),
    Service("~/set_digital_outputs", "msg_defs/srv/SetOutputs"),
    Service("~/set_user_coils", "msg_defs/srv/SetOutputs"),
    Service("~/set_joint_enable", "msg_defs/srv/SetJointEnable"),
    Service("~/set_tool_digital_output", "msg_defs/srv/SetOutput"),
    Service("~/set_analog_output", "msg_defs/srv/SetChannelValue"),
    Service("~/set_reduced_mode", "msg_defs/srv/SetSafetyMode"),
    Service("~/set_fence_mode", "msg_defs/srv/SetSafetyMode"),
    Service("~/run_offline_task", "msg_defs/srv/RunOfflineTask"),
)

NODES = (
    bridge_node(
        "xarm_bridge",
        "xarm_bridge",
        "xarm_bridge",
        "one UFactory xArm controller on its own Modbus TCP link",
        XARM_DEFAULTS,
        PARAMETERS,
        topics=TOPICS,
        services=SERVICES,
    ),
)
