"""Launch modbus_bridge with config/modbus.yaml: any Modbus device from a description file.

    ros2 launch launch/modbus.launch.py [device_file:=/path/to/device.yaml] [host:=...]
    ros2 launch modbus_bridge modbus.launch.py [device_file:=...] [serial_port:=...]

The first form runs from this checkout, the second from an install (the venv after
scripts/setup.sh, or a colcon install). The parameters come from the example file, then the
launch arguments; the default description is the xArm's (config/devices/xarm.yaml beside
this file's config). The link comes from the description: host, port and serial_port are
passed only when given (an RTU description declares no host / port, and the node refuses
a parameter it does not declare). Needs `launch_ros` (a sourced ROS 2 Jazzy; the PyPI
wheels in .venv have none: tests/core/test_launch_files.py checks what this file names).
Keep ROS discovery local when everything is on one machine:
`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`.
"""

from pathlib import Path
from typing import Any

from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode

CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"
CONFIG = CONFIG_DIR / "modbus.yaml"
DEVICE_FILE = CONFIG_DIR / "devices/xarm.yaml"
# Link overrides: passed to the node only when given (default ""); else the file's link.
LINK_ARGUMENTS = ("host", "port", "serial_port")


def bridge_node(context: LaunchContext) -> list[LifecycleNode]:
    overrides: dict[str, Any] = {"device_file": LaunchConfiguration("device_file").perform(context)}
    for name in LINK_ARGUMENTS:
        value = LaunchConfiguration(name).perform(context)
        if value:
            overrides[name] = int(value) if name == "port" else value
    return [
        LifecycleNode(  # a managed node: ros2 lifecycle works on it
            package="modbus_bridge",
            executable="modbus_bridge",
            name="modbus_bridge",
            namespace=LaunchConfiguration("namespace"),
            parameters=[str(CONFIG), overrides],
            output="screen",
        )
    ]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "device_file",
                default_value=str(DEVICE_FILE),
                description="the device description (YAML; docs/bridges/modbus.md)",
            ),
            *(
                DeclareLaunchArgument(
                    name,
                    default_value="",
                    description=f"{name} of the link, overriding the description's "
                    "(empty: the description's)",
                )
                for name in LINK_ARGUMENTS
            ),
            DeclareLaunchArgument(
                "namespace",
                default_value="",
                description="namespace of the node's topics and services",
            ),
            OpaqueFunction(function=bridge_node),
        ]
    )
