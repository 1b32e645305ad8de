"""The TCP bridges bench/bridge_bench.py measures: one ``Profile`` each (package, device
class, the simulator register that moves joint 1, the command service it times); the
rest of the bench is shared. Adding a TCP bridge to the bench is adding a profile here
(and its messages to bench/floor_rclpy_publisher.py ``--device``).
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
AXES, IO_BOARDS = 6, 1


@dataclass(frozen=True)
class Profile:
    """What differs between the benchmarked bridges; the rest of the bench is shared."""

    name: str  # --device
    title: str
    package: str  # <package>.device / .sim / .node; the node's name and diagnostics prefix
    device_class: str  # in <package>.device, constructed with a DeviceChannel
    sim_args: tuple[int, ...]  # <package>.sim.make_simulator(*sim_args), the node's defaults
    joint_register: str  # simulator register (degrees) that joint_states position[0] follows
    joint_raw_max: int  # random raw values for it in +-joint_raw_max
    service: str  # ~/<service>, timed from call to register write
    service_type: str  # in msg_defs.srv
    # k, rng -> (request, table value, address) the service must write
    service_request: Callable[[int, random.Random], tuple[Any, str, int]]
    sim_package: str = ""  # whose simulator (default: package)
    node_params: tuple[str, ...] = ()  # extra -p name:=value of the node
    # channel -> the device layer (default: <package>.device.<device_class>(channel))
    make_device: Callable[[Any], Any] | None = None

    @property
    def simulator(self) -> str:
        return self.sim_package or self.package


def _r6_service(k: int, rng: random.Random) -> tuple[Any, str, int]:
    from msg_defs.srv import SetValue
    from r6_bridge.registers import R6_MAP

    request = SetValue.Request()
    request.value = 20.0 + (k % 2) * 40.0 + rng.randint(0, 100) / 10.0
    return request, "holding", R6_MAP["global_speed"].address


def _xarm_service(k: int, rng: random.Random) -> tuple[Any, str, int]:
    from msg_defs.srv import SetOutput

    request = SetOutput.Request()
    request.board, request.index, request.state = 0, rng.randint(0, 15), k % 2 == 0
    return request, "coil", request.index  # FC 05 to coil `index`


XARM_DESCRIPTION = ROOT / "config" / "devices" / "xarm.yaml"


def _modbus_device(channel: Any) -> Any:
    from modbus_bridge.description import load
    from modbus_bridge.device import DescribedDevice

    return DescribedDevice(channel, load(XARM_DESCRIPTION).device)


def _modbus_service(k: int, rng: random.Random) -> tuple[Any, str, int]:
    from msg_defs.srv import SetValue

    request = SetValue.Request()
    request.value = (k % 2) * 5.0 + rng.randint(0, 40) / 10.0  # 0-9 V
    return request, "holding", 3  # controller AO 0, FC 06 to H3


PROFILES = {
    "r6": Profile(
        name="r6",
        title="R6",
        package="r6_bridge",
        device_class="R6Device",
        sim_args=(AXES, IO_BOARDS),
        joint_register="axis_position_1",
        joint_raw_max=170_000,  # +-170 deg (x1000)
        service="set_global_speed",
        service_type="SetValue",
        service_request=_r6_service,
    ),
    "xarm": Profile(
        name="xarm",
        title="xArm",
        package="xarm_bridge",
        device_class="XArmDevice",
        sim_args=(),
        joint_register="joint_angle_1",
        joint_raw_max=1_800,  # +-180 deg (x10, signed 16-bit)
        service="set_digital_output",
        service_type="SetOutput",
        service_request=_xarm_service,
    ),
    "modbus": Profile(
        name="modbus",
        title="modbus_bridge (xArm description)",
        package="modbus_bridge",
        device_class="DescribedDevice",
        sim_args=(),
        joint_register="joint_angle_1",
        joint_raw_max=1_800,
        service="set_analog_output_0",
        service_type="SetValue",
        service_request=_modbus_service,
        sim_package="xarm_bridge",
        node_params=(f"device_file:={XARM_DESCRIPTION}",),
        make_device=_modbus_device,
    ),
}
