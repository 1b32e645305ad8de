"""The xArm node's ROS interface as data (no rclpy): ``xarm_bridge.node`` declares these
parameters; ``bridge_core.runtime.interface`` lists the node;
tests/core/ros/test_interface.py checks the topics and services against a running node."""

from __future__ import annotations

from bridge_core.runtime.interface import Service, Topic, bridge_node
from bridge_core.runtime.parameters import DeviceDefaults, ParameterSpec

from .registers import JOINT_COUNTS, JOINTS, USER_COILS

XARM_DEFAULTS = DeviceDefaults("UFactory xArm", "tcp", poll_rate_hz=50.0, pose_topic="~/tcp_pose")

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
    Service(
        "~/pause",
        "std_srvs/srv/Trigger",
        "pause motion (C144 and H33 = 3 at once); success only when H33 read back shows it",
    ),
    Service(
        "~/stop",
        "std_srvs/srv/Trigger",
        "stop motion (C145 and H33 = 4 at once); success only when H33 read back shows it",
    ),
    Service(
        "~/resume",
        "std_srvs/srv/Trigger",
        "resume motion (H33 = 0); success only when the state read back shows the arm ready",
    ),
    Service(
        "~/set_mode",
        "msg_defs/srv/SetInteger",
        "the arm's mode 0-13 (H32); in force after ~/set_state 0",
    ),
    Service(
        "~/set_state",
        "msg_defs/srv/SetInteger",
        "the arm's state: 0 start, 3 pause, 4 stop (H33); success only when the state read "
        "back shows it",
    ),
    Service(
        "~/set_digital_output",
        "msg_defs/srv/SetOutput",
        "switch one controller digital output (board 0, index 0-15)",
    ),
    Service(
        "~/set_digital_outputs",
        "msg_defs/srv/SetOutputs",
        "switch several controller digital outputs 0-15; nothing written unless all pass",
    ),
    Service(
        "~/set_user_coils",
        "msg_defs/srv/SetOutputs",
        "switch user coils (addresses) in the configured range; refused when none configured",
    ),
    Service(
        "~/set_joint_enable",
        "msg_defs/srv/SetJointEnable",
        "enable or disable one joint's motor, or all with joint 0; a disable is sent as a "
        "stop; success only when the enable coils read back show it",
    ),
    Service(
        "~/set_tool_digital_output",
        "msg_defs/srv/SetOutput",
        "switch one tool digital output (board 0, index 0-1)",
    ),
    Service(
        "~/set_analog_output",
        "msg_defs/srv/SetChannelValue",
        "controller analog output channel 0-1, value 0-10 V",
    ),
    Service(
        "~/set_reduced_mode",
        "msg_defs/srv/SetSafetyMode",
        "reduced mode on or off (C142), read back; off only with confirm = the service's name",
    ),
    Service(
        "~/set_fence_mode",
        "msg_defs/srv/SetSafetyMode",
        "fence mode on or off (C143), read back; off only with confirm = the service's name",
    ),
    Service(
        "~/run_offline_task",
        "msg_defs/srv/RunOfflineTask",
        "start offline (Blockly) projects by number, 1-16 of them; success only when the "
        "arm reads in motion",
    ),
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
