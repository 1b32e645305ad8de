"""The demo cell: the four simulators and their bridges, as ``bash scripts/demo.sh`` runs them.

    ros2 launch launch/cell.launch.py      (from this checkout)
    ros2 launch bridge_core cell.launch.py (installed: the venv after setup, or colcon)

Namespaces /r6, /xarm, /stepper and /motec; the R6 and xArm simulators on 127.0.0.1 ports
5020 and 5021, the stepper and MOTEC simulators on socat pty pairs linked at
/tmp/cell_stepper and /tmp/cell_motec (the bridges retry until they exist). Everything stays
on this machine: set ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` before launching. Needs
``launch_ros`` (tests/core/test_launch_files.py checks what this file names).
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import ExecuteProcess
from launch_ros.actions import LifecycleNode, Node
from launch_ros.substitutions import ExecutableInPackage

CONFIG = Path(__file__).resolve().parent.parent / "config"
STEPPER_PTY = "/tmp/cell_stepper"
MOTEC_PTY = "/tmp/cell_motec"
MOTEC_LIFEGUARD_MS = 6000


def bridge(package: str, namespace: str, config: str, **params: object) -> Node:
    """A bridge with its example config, then ``params``. A process of one node is a
    ``LifecycleNode`` (launch names it); the MOTEC's (a bus node and a node per drive) a
    plain ``Node``."""
    if package == "motec_bridge":
        return Node(
            package=package,
            executable=package,
            namespace=namespace,
            parameters=[str(CONFIG / config), params],
            output="screen",
        )
    return LifecycleNode(
        package=package,
        executable=package,
        name=package,
        namespace=namespace,
        parameters=[str(CONFIG / config), params],
        output="screen",
    )


def simulator(package: str, executable: str, *args: str) -> ExecuteProcess:
    """A simulator, found like ``ros2 run`` finds it (``lib/<package>/``): in the venv or a
    colcon install alike."""
    return ExecuteProcess(
        cmd=[ExecutableInPackage(executable=executable, package=package), *args], output="screen"
    )


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            simulator("r6_bridge", "r6_sim", "--port", "5020", "--running"),
            simulator("xarm_bridge", "xarm_sim", "--port", "5021"),
            simulator("stepper_bridge", "stepper_sim", "--pty", STEPPER_PTY),
            simulator("motec_bridge", "motec_sim", "--pty", MOTEC_PTY, "--unit-ids", "1,2,3"),
            bridge("r6_bridge", "/r6", "r6.yaml", host="127.0.0.1", port=5020),
            bridge("xarm_bridge", "/xarm", "xarm.yaml", host="127.0.0.1", port=5021),
            bridge("stepper_bridge", "/stepper", "stepper.yaml", serial_port=STEPPER_PTY),
            # A simulator in another process may answer late on a busy machine: 1 s per try
            # (the demo's), and so a lifeguard the 3 drives can keep fed at that timeout
            # (the start-up check's floor is ~4.8 s; config/motec.yaml's 1 s is for 0.1 s).
            bridge(
                "motec_bridge",
                "/motec",
                "motec.yaml",
                serial_port=MOTEC_PTY,
                timeout_s=1.0,
                lifeguard_ms=MOTEC_LIFEGUARD_MS,
            ),
        ]
    )
