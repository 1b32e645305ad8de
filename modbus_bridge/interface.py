"""The modbus_bridge nodes' ROS interface as data (no rclpy), from a description file:
``modbus_bridge.node`` and ``modbus_bridge.bus`` declare these parameters;
``bridge_core.runtime.interface`` lists the nodes of the launch file's default description
(config/devices/xarm.yaml) and of the multi-drop example (rtu_multidrop.yaml);
tests/core/ros/test_interface.py checks the topics and services against running nodes."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from bridge_core.runtime.interface import NodeInterface, Service, Topic, bridge_node, bus_node
from bridge_core.runtime.joint_commands import MAX_JUMP_SPEC
from bridge_core.runtime.parameters import DeviceDefaults, ParameterSpec
from bridge_core.runtime.stream_guard import COMMAND_TIMEOUT_RANGE_S

from .description import (
    COMMAND_RATE_RANGE_HZ,
    Device,
    Link,
    TopicSpec,
    load,
)

NODE_NAME = "modbus_bridge"
BUS_NODE_NAME = "modbus_bus"
DEVICES = Path(__file__).resolve().parent.parent / "config" / "devices"  # in a checkout
DEFAULT_DEVICE_FILE = DEVICES / "xarm.yaml"  # launch/modbus.launch.py's default
DEFAULT_LINE_FILE = DEVICES / "rtu_multidrop.yaml"

# bridge_doc prints this above the nodes on docs/bridges/modbus.md: what they depend on.
DOC_NOTE = (
    "A `modbus_bridge` node is what its description file makes it: its name on a line, its "
    "command topics and services (and their `<topic>_timeout_s`, `<topic>_rate_hz`), "
    "`~/joint_commands` if a joint has a command, and its link parameters' defaults. "
    "Listed here are the nodes of the default configuration (`default_nodes()`): "
    f"`modbus_bridge` on config/devices/{DEFAULT_DEVICE_FILE.name} "
    "(launch/modbus.launch.py's default) and `modbus_bus` on "
    f"config/devices/{DEFAULT_LINE_FILE.name} (the multi-drop example), with a node per "
    "device of that file. `modbus_doc FILE` prints a file's registers and commands."
)

DEVICE_FILE_SPEC = ParameterSpec("device_file", "", "device description YAML (required)")
LINE_FILE_SPEC = ParameterSpec("device_file", "", "description of the line's devices (required)")


def defaults_of(device: Device, line: Link | None = None) -> DeviceDefaults:
    """The node's (or with ``line``, the bus's) parameter defaults from the description."""
    spec = device.spec.device
    link = device.link or line
    if link is None:  # a device on a line its bus node opens
        return DeviceDefaults(spec.title or spec.name, "rtu", poll_rate_hz=spec.poll_rate_hz)
    if link.tcp is not None:
        return DeviceDefaults(
            spec.title or spec.name,
            "tcp",
            poll_rate_hz=spec.poll_rate_hz,
            host=link.tcp.host,
            port=link.tcp.port,
            timeout_s=link.timeout_s,
            unit_id=spec.unit_id,
            max_in_flight=link.tcp.max_in_flight,
        )
    assert link.rtu is not None
    return DeviceDefaults(
        spec.title or spec.name,
        "rtu",
        poll_rate_hz=spec.poll_rate_hz,
        serial_port=link.rtu.serial_port,
        baudrate=link.rtu.baudrate,
        parity=link.rtu.parity,
        stopbits=link.rtu.stopbits,
        frame_gap_s=link.rtu.frame_gap_s,
        timeout_s=link.timeout_s,
        unit_id=spec.unit_id,
    )


def stream_parameters(topic: TopicSpec) -> tuple[ParameterSpec, ParameterSpec]:
    """A command topic's deadman and rate: ``<topic>_timeout_s``, ``<topic>_rate_hz``."""
    return (
        ParameterSpec(
            f"{topic.name}_timeout_s",
            topic.timeout_s,
            f"~/{topic.name} deadman: write {topic.stop_value} after this silence",
            *COMMAND_TIMEOUT_RANGE_S,
            live=True,
        ),
        ParameterSpec(
            f"{topic.name}_rate_hz",
            topic.rate_hz,
            f"~/{topic.name}: most values written per second (a 0 at once)",
            *COMMAND_RATE_RANGE_HZ,
            live=True,
        ),
    )


# ~/joint_commands' streams of their own (a joint's velocity without a command topic on
# its register, every position): the deadman and rate of the stepper's and MOTEC's.
JOINT_COMMAND_TIMEOUT_S = 0.5
JOINT_COMMAND_RATE_HZ = 10.0
JOINT_COMMAND_PARAMETERS = (
    ParameterSpec(
        "command_timeout_s",
        JOINT_COMMAND_TIMEOUT_S,
        "joint_commands deadman: stop a joint after this silence (a velocity: 0; a "
        "position: hold where it is)",
        *COMMAND_TIMEOUT_RANGE_S,
        live=True,
    ),
    ParameterSpec(
        "command_rate_hz",
        JOINT_COMMAND_RATE_HZ,
        "joint_commands: most values written per second per joint (a 0 velocity at once)",
        *COMMAND_RATE_RANGE_HZ,
        live=True,
    ),
    MAX_JUMP_SPEC,
)

TOPICS = (
    Topic("~/state", "msg_defs/msg/DeviceValues", True, "every poll: the readable registers"),
    Topic("~/{topic}", "std_msgs/msg/Float64", False, "a command topic of the file"),
)
JOINT_COMMAND_TOPICS = (
    Topic(
        "~/joint_commands",
        "sensor_msgs/msg/JointState",
        False,
        "position or velocity (SI) of the joints with a command, by joint_states' names",
    ),
)


def commanded(device: Device) -> bool:
    """Whether a joint of the file has a ``command`` (the node has ``~/joint_commands``)."""
    return any(joint.command is not None for joint in device.joints)


SERVICES = (
    Service("~/read", "msg_defs/srv/ReadRegisters", "registers by name"),
    Service("~/write", "msg_defs/srv/WriteRegister", "a register by name"),
    Service("~/{trigger}", "std_srvs/srv/Trigger", "a trigger of the file"),
    Service("~/{value}", "msg_defs/srv/SetValue", "a value service of the file"),
    Service("~/{coil}", "std_srvs/srv/SetBool", "a coil service of the file"),
)


def expansion(device: Device) -> dict[str, tuple[str, ...]]:
    """The names the file gives its commands, per placeholder of ``TOPICS``/``SERVICES``."""
    commands = device.commands
    return {
        "topic": tuple(t.name for t in commands.topics),
        "trigger": tuple(t.name for t in commands.triggers),
        "value": tuple(v.name for v in commands.values),
        "coil": tuple(c.name for c in commands.coils),
    }


def device_node(device: Device, line: bool) -> NodeInterface:
    """The node of one described device (``line``: on a bus ``modbus_bus`` owns)."""
    return bridge_node(
        "modbus_bridge",
        "modbus_bus" if line else "modbus_bridge",
        device.name if line else NODE_NAME,
        f"{device.spec.device.title or device.name}, described by a file",
        defaults_of(device),
        [
            *(spec for topic in device.commands.topics for spec in stream_parameters(topic)),
            *(JOINT_COMMAND_PARAMETERS if commanded(device) else ()),
        ],
        owns_link=not line,
        topics=(*TOPICS, *(JOINT_COMMAND_TOPICS if commanded(device) else ())),
        services=SERVICES,
        expansion=expansion(device),
    )


def described_nodes(path: Path | str) -> tuple[NodeInterface, ...]:
    """The nodes ``modbus_bridge`` (one device) or ``modbus_bus`` (a line) runs for a file."""
    description = load(path)
    if description.line is None:
        node = device_node(description.device, line=False)
        return (replace(node, parameters=(DEVICE_FILE_SPEC, *node.parameters)),)
    bus = bus_node(
        "modbus_bridge",
        "modbus_bus",
        BUS_NODE_NAME,
        "the line of a description file: opens it, one node per device",
        defaults_of(description.devices[0], description.line),
        unit_ids=False,
    )
    return (
        replace(bus, parameters=(LINE_FILE_SPEC, *bus.parameters)),
        *(device_node(device, line=True) for device in description.devices),
    )


def installed(path: Path) -> Path:
    """An example description in the checkout, else in the package's ament share
    (a colcon or ament-index install: ``share/modbus_bridge/config/devices``)."""
    if path.is_file():
        return path
    from ament_index_python.packages import get_package_share_directory

    share = Path(get_package_share_directory("modbus_bridge"))
    return share / "config" / "devices" / path.name


def default_nodes() -> tuple[NodeInterface, ...]:
    """The nodes of the launch file's default description and of the multi-drop example."""
    return (
        *described_nodes(installed(DEFAULT_DEVICE_FILE)),
        *described_nodes(installed(DEFAULT_LINE_FILE)),
    )
