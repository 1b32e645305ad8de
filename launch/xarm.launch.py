"""Launch xarm_bridge with config/xarm.yaml: UFactory xArm controller (Modbus TCP).

    ros2 launch launch/xarm.launch.py host:=<controller address> [port:=502] [namespace:=/cell]
    ros2 launch xarm_bridge xarm.launch.py host:=<controller address> [port:=502] [namespace:=/cell]

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

CONFIG = Path(__file__).resolve().parent.parent / "config" / "xarm.yaml"

NAMESPACE = DeclareLaunchArgument(
    "namespace", default_value="", description="namespace of the node's topics and services"
)


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "host",
                description="IP address or host name of the xArm controller (required: no default "
                "address, so a launch never dials a machine it was not told to)",
            ),
            DeclareLaunchArgument(
                "port", default_value="502", description="Modbus TCP port of the xArm controller"
            ),
            NAMESPACE,
            LifecycleNode(  # a managed node: ros2 lifecycle works on it (autostart: active)
                package="xarm_bridge",
                executable="xarm_bridge",
                name="xarm_bridge",
                namespace=LaunchConfiguration("namespace"),
                parameters=[
                    str(CONFIG),
                    {"host": LaunchConfiguration("host"), "port": LaunchConfiguration("port")},
                ],
                output="screen",
            ),
        ]
    )
