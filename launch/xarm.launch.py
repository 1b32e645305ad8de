"""Launch xarm_bridge with config/xarm.yaml: UFactory xArm controller (Modbus TCP).

    ros2 launch launch/xarm.launch.py host:=192.168.1.11 [namespace:=/cell]
    ros2 launch xarm_bridge xarm.launch.py host:=192.168.1.11 [namespace:=/cell]

The first form runs from this checkout, the second from an install (the venv after
scripts/setup.sh, or a colcon install). The parameters come from the example file, then the
launch arguments. Needs `launch_ros` (a sourced ROS 2 Jazzy; the PyPI wheels in .venv
have none: tests/core/test_launch_files.py checks what this file names). Keep ROS
discovery local when everything is on one machine: `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

CONFIG = Path(__file__).resolve().parent.parent / "config" / "xarm.yaml"


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            DeclareLaunchArgument("host", default_value="192.168.1.11"),
            DeclareLaunchArgument("namespace", default_value=""),
            Node(
                package="xarm_bridge",
                executable="xarm_bridge",
                namespace=LaunchConfiguration("namespace"),
                parameters=[str(CONFIG), {"host": LaunchConfiguration("host")}],
                output="screen",
            ),
        ]
    )
