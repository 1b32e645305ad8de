"""Launch modbus_bridge with config/modbus.yaml: any Modbus device from a description file.

    ros2 launch launch/modbus.launch.py [device_file:=/path/to/device.yaml] [host:=...]
    ros2 launch modbus_bridge modbus.launch.py [device_file:=...] [namespace:=/cell]

The first form runs from this checkout, the second from an install (the venv after
scripts/setup.sh, or a colcon install). The parameters come from the example file, then the
launch arguments; the default description is the xArm's (config/devices/xarm.yaml beside
this file's config). Needs `launch_ros` (a sourced ROS 2 Jazzy; the PyPI wheels in .venv
have none: tests/core/test_launch_files.py checks what this file names). Keep ROS
discovery local when everything is on one machine: `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"
CONFIG = CONFIG_DIR / "modbus.yaml"
DEVICE_FILE = CONFIG_DIR / "devices/xarm.yaml"


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            DeclareLaunchArgument("device_file", default_value=str(DEVICE_FILE)),
            DeclareLaunchArgument("host", default_value="127.0.0.1"),
            DeclareLaunchArgument("namespace", default_value=""),
            Node(
                package="modbus_bridge",
                executable="modbus_bridge",
                namespace=LaunchConfiguration("namespace"),
                parameters=[
                    str(CONFIG),
                    {
                        "device_file": LaunchConfiguration("device_file"),
                        "host": LaunchConfiguration("host"),
                    },
                ],
                output="screen",
            ),
        ]
    )
