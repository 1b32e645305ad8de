"""Launch motec_bridge with config/motec.yaml: MOTEC β drives on one RS-485 bus (one process:
the bus node and a node per drive).

    ros2 launch launch/motec.launch.py serial_port:=/dev/ttyUSB0 [namespace:=/cell]
    ros2 launch motec_bridge motec.launch.py serial_port:=/dev/ttyUSB0 [namespace:=/cell]

The first form runs from this checkout, the second from an install (the venv after
scripts/setup.sh, or a colcon install). The parameters come from the example file, then the
launch arguments (`ros2 launch ... --show-args` lists them). Each node of the process is
managed (`ros2 lifecycle`), but launch_ros's `LifecycleNode` names one node per process, so
this is a plain `Node`. Needs `launch_ros` (a sourced ROS 2 Jazzy; the PyPI wheels in .venv
have none: tests/core/test_launch_parameters.py evaluates this file with a stand-in and starts
its node with exactly these parameters).
Keep ROS discovery local when everything is on one machine:
`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

CONFIG = Path(__file__).resolve().parent.parent / "config" / "motec.yaml"

NAMESPACE = DeclareLaunchArgument(
    "namespace", default_value="", description="namespace of the node's topics and services"
)


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "serial_port",
                default_value="/dev/ttyUSB0",
                description="serial device (or pyserial URL) of the RS-485 bus",
            ),
            NAMESPACE,
            Node(  # several managed nodes in one process (see above)
                package="motec_bridge",
                executable="motec_bridge",
                namespace=LaunchConfiguration("namespace"),
                parameters=[str(CONFIG), {"serial_port": LaunchConfiguration("serial_port")}],
                output="screen",
            ),
        ]
    )
