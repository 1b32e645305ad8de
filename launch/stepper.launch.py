"""Launch stepper_bridge with config/stepper.yaml: 5-axis stepper controller (Modbus RTU).

    ros2 launch launch/stepper.launch.py serial_port:=/dev/ttyUSB0 [namespace:=/cell]
    ros2 launch stepper_bridge stepper.launch.py serial_port:=/dev/ttyUSB0 [namespace:=/cell]

The first form runs from this checkout, the second from an install (the venv after
scripts/setup.sh, or a colcon install). The parameters come from the example file, then the
launch arguments (`ros2 launch ... --show-args` lists them). Needs `launch_ros` (a
sourced ROS 2 Jazzy; the PyPI wheels in .venv have none: tests/core/test_launch_parameters.py
evaluates this file with a stand-in and starts its node with exactly these parameters).
Keep ROS discovery local when everything is on one machine:
`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode

CONFIG = Path(__file__).resolve().parent.parent / "config" / "stepper.yaml"

NAMESPACE = DeclareLaunchArgument(
    "namespace", default_value="", description="namespace of the node's topics and services"
)


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "serial_port",
                default_value="/dev/ttyUSB0",
                description="serial device (or pyserial URL) of the stepper controller",
            ),
            NAMESPACE,
            LifecycleNode(  # a managed node: ros2 lifecycle works on it
                package="stepper_bridge",
                executable="stepper_bridge",
                name="stepper_bridge",
                namespace=LaunchConfiguration("namespace"),
                parameters=[str(CONFIG), {"serial_port": LaunchConfiguration("serial_port")}],
                output="screen",
            ),
        ]
    )
