"""The bridges as data, for the contract suite (tests/core/ros/test_contract.py).

Each entry says how to start the bridge's simulator (its own process, so a test can
SIGKILL it; accepted writes and handled read requests logged to files) and its node, one
harmless write service call that succeeds (and the write it puts on the wire), one call
with a value the bridge must refuse, and the register whose read time stamps
``joint_states``. The contract tests are written once against this table.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from std_srvs.srv import Trigger

from bridge_core.sim.logs import ReadRecord, WriteRecord, read_read_log, read_write_log
from bridge_core.wire.ports import free_port
from bridge_core.wire.registers import Register
from modbus_bridge.description import load as load_description
from motec_bridge.registers import MOTEC_MAP
from msg_defs.msg import DeviceValues, MotecState, R6State, StepperState, XArmState
from msg_defs.srv import (
    ListCounters,
    ReadParameter,
    ReadRegisters,
    SetChannelValue,
    SetControlMode,
    SetOutput,
    SetValue,
)
from r6_bridge.registers import R6_MAP
from stepper_bridge.registers import STEPPER_MAP
from xarm_bridge.registers import XARM_MAP

from . import forkserver
from .ros import ROOT, wait_for

RTU_BAUD = 115200
SIM_START_S = 20.0
# modbus_bridge runs on the xArm's description, served by modbus_sim.
XARM_DESCRIPTION = ROOT / "config" / "devices" / "xarm.yaml"
XARM_DESCRIBED = load_description(XARM_DESCRIPTION).device.register_map


@dataclass(frozen=True)
class Call:
    """One service call: ``~/service`` of the bridge's node with these request fields."""

    service: str
    srv_type: Any
    fields: Mapping[str, Any] = field(default_factory=dict)

    def request(self) -> Any:
        request = self.srv_type.Request()
        for key, value in self.fields.items():
            setattr(request, key, value)
        return request


@dataclass(frozen=True)
class JointCommandRow:
    """A bridge's ``~/joint_commands``: the node that owns the topic, and a
    joint of it (as named in ``joint_states``)."""

    node: str
    joint: str


@dataclass(frozen=True)
class BridgeInfo:
    """What the contract suite needs to know about one bridge."""

    key: str  # pytest id
    module: str  # the node module, run as ``python -m module``
    node_name: str  # the node whose API is checked (MOTEC: one drive)
    state_type: Any
    transport: str  # "tcp" or "rtu"
    sim_module: str
    sim_args: tuple[str, ...]
    params: Mapping[str, Any]  # node parameters besides where the device is
    good: Call  # succeeds and writes exactly ``good_write``
    good_write: tuple[int, int, tuple[int, ...]]  # function code, address, values
    bad: Call  # a value out of range: refused, nothing written
    position_register: Register  # the block whose read time stamps joint_states
    unit_id: int
    config: str  # example YAML in config/
    startup_only: tuple[str, ...]  # read-only parameters of ``node_name``
    bus_node: str | None = None  # MOTEC: the bus owner in the same process
    bus_startup_only: tuple[str, ...] = ()
    read_services: Mapping[str, Call] = field(default_factory=dict)  # no writes: allowed
    mistyped: tuple[tuple[str, str], ...] = ()  # refused start-up values
    actions: int = 0  # action servers of its nodes (docs/actions.md)
    # A register of the slow group (read every slow_poll_period_s), and a call that writes
    # it or switches what it shows (None: ``good``).
    slow_register: Register | None = None
    slow_write: Call | None = None
    joint_commands: JointCommandRow | None = None  # None: the bridge has no such topic
    stop: Call | None = None  # a stop service (TCP bridges: the pipelining contract)

    @property
    def nodes(self) -> tuple[str, ...]:
        """Every node of the process whose services the contract covers."""
        return (self.node_name,) if self.bus_node is None else (self.node_name, self.bus_node)


BRIDGES: tuple[BridgeInfo, ...] = (
    BridgeInfo(
        key="r6",
        module="r6_bridge.node",
        node_name="r6_bridge",
        state_type=R6State,
        transport="tcp",
        sim_module="r6_bridge.sim",
        sim_args=(),
        params={"timeout_s": 0.5},
        good=Call("set_global_speed", SetValue, {"value": 25.0}),
        good_write=(6, R6_MAP["global_speed"].address, (250,)),
        bad=Call("set_global_speed", SetValue, {"value": 150.0}),
        position_register=R6_MAP["axis_position_1"],
        slow_register=R6_MAP["global_speed"],
        unit_id=1,
        config="r6.yaml",
        stop=Call("stop", Trigger, {}),
        startup_only=(
            "host",
            "port",
            "max_in_flight",
            "unit_id",
            "timeout_s",
            "joint_prefix",
            "gear_ratios",
            "extra_world_axes",
            "m_boards",
            "eu_board",
        ),
        read_services={
            "read_parameter": Call("read_parameter", ReadParameter, {"index": 3}),
            "list_counters": Call("list_counters", ListCounters, {}),
        },
        mistyped=(
            ("port", "abc"),
            ("poll_rate_hz", "fast"),
            ("pol_rate_hz", "5"),
            ("extra_world_axes", "3"),
        ),
        actions=2,  # ~/upload_points, ~/run_cycle
    ),
    BridgeInfo(
        key="xarm",
        module="xarm_bridge.node",
        node_name="xarm_bridge",
        state_type=XArmState,
        transport="tcp",
        sim_module="xarm_bridge.sim",
        sim_args=(),
        params={"timeout_s": 0.5},
        good=Call("set_analog_output", SetChannelValue, {"channel": 0, "value": 2.5}),
        good_write=(6, XARM_MAP["controller_ao_0"].address, (2500,)),
        bad=Call("set_analog_output", SetChannelValue, {"channel": 0, "value": 100.0}),
        position_register=XARM_MAP["joint_angle_1"],
        slow_register=XARM_MAP["controller_ao_0"],
        unit_id=1,
        config="xarm.yaml",
        stop=Call("stop", Trigger, {}),
        startup_only=(
            "host",
            "port",
            "max_in_flight",
            "unit_id",
            "timeout_s",
            "joint_prefix",
            "joint_count",
            "user_coil_first",
            "user_coil_count",
        ),
        mistyped=(
            ("port", "abc"),
            ("poll_rate_hz", "fast"),
            ("port", "70000"),
            ("joint_count", "8"),
            ("user_coil_count", "many"),
        ),
    ),
    BridgeInfo(
        key="stepper",
        module="stepper_bridge.node",
        node_name="stepper_bridge",
        state_type=StepperState,
        transport="rtu",
        sim_module="stepper_bridge.sim",
        sim_args=("--reply-delay-ms", "2"),
        params={"timeout_s": 0.3, "command_timeout_s": 0.5},
        good=Call("set_output", SetOutput, {"board": 0, "index": 1, "state": True}),
        good_write=(5, STEPPER_MAP["output_1_on"].address, (1,)),
        bad=Call("set_output", SetOutput, {"board": 0, "index": 13, "state": True}),
        position_register=STEPPER_MAP["motor1_coordinate"],
        slow_register=STEPPER_MAP["output_1"],  # set_output writes its ON coil
        unit_id=1,
        config="stepper.yaml",
        startup_only=(
            "serial_port",
            "baudrate",
            "parity",
            "unit_id",
            "joint_types",
            "units_per_revolution",
        ),
        mistyped=(("baudrate", "fast"), ("poll_rate_hz", "fast"), ("unit_id", "0")),
        actions=14,  # move_by and home per motor, home_all, return_to_zero, line, arc
        joint_commands=JointCommandRow("stepper_bridge", "motor_1"),
    ),
    BridgeInfo(
        key="motec",
        module="motec_bridge.node",
        node_name="motec_1",
        state_type=MotecState,
        transport="rtu",
        sim_module="motec_bridge.sim_cli",
        sim_args=("--unit-ids", "1"),
        params={"unit_ids": [1], "timeout_s": 0.5, "command_timeout_s": 0.5},
        good=Call("set_analog_max_speed", SetValue, {"value": 1500.0}),
        good_write=(6, MOTEC_MAP["analog_max_speed"].address, (1500,)),
        bad=Call("set_analog_max_speed", SetValue, {"value": 70000.0}),
        position_register=MOTEC_MAP["position_actual"],
        slow_register=MOTEC_MAP["control_mode"],
        slow_write=Call("set_control_mode", SetControlMode, {"mode": 2}),  # position (0x25)
        unit_id=1,
        config="motec.yaml",
        startup_only=(
            "counts_per_rev",
            "gear_ratio",
            "joint_prefix",
            "output1_coil",
            "read_io_tables",
            "allow_unlisted_parameters",
        ),
        bus_node="motec_bridge",
        bus_startup_only=("serial_port", "baudrate", "unit_ids", "interface"),
        read_services={"read_parameter": Call("read_parameter", ReadParameter, {"index": 0x6D})},
        mistyped=(("baudrate", "fast"), ("poll_rate_hz", "fast"), ("unit_id", "300")),
        actions=1,  # ~/move_to
        joint_commands=JointCommandRow("motec_bridge", "drive_1"),  # the bus owner's
    ),
    BridgeInfo(
        key="modbus",
        module="modbus_bridge.node",
        node_name="modbus_bridge",
        state_type=DeviceValues,
        transport="tcp",
        sim_module="modbus_bridge.sim",
        sim_args=("--device-file", str(XARM_DESCRIPTION)),
        params={"timeout_s": 0.5, "device_file": str(XARM_DESCRIPTION)},
        good=Call("set_analog_output_0", SetValue, {"value": 2.5}),
        good_write=(6, XARM_DESCRIBED["controller_ao_0"].address, (2500,)),
        bad=Call("set_analog_output_0", SetValue, {"value": 100.0}),
        position_register=XARM_DESCRIBED["joint_angle_1"],
        slow_register=XARM_DESCRIBED["controller_ao_0"],  # poll: slow in xarm.yaml
        unit_id=1,
        config="modbus.yaml",
        stop=Call("stop", Trigger, {}),
        startup_only=(
            "host",
            "port",
            "max_in_flight",
            "unit_id",
            "timeout_s",
            "joint_prefix",
            "device_file",
        ),
        read_services={"read": Call("read", ReadRegisters, {"names": ["joint_angle_1"]})},
        # Without a readable device_file nothing else is read: the file's is the one typo.
        mistyped=(("device_file", "/nonexistent/device.yaml"),),
    ),
)


class SimProcess:
    """A bridge's simulator as its own process (and process group, with its socat).

    TCP: a fixed free port. RTU: ``--pty`` makes a socat pair whose bridge end is linked
    at a fixed path, so a restart after SIGKILL serves the same path (socat replaces the
    dangling link). Writes and reads are logged to files that survive a restart.
    """

    def __init__(self, info: BridgeInfo, workdir: Path) -> None:
        self.info = info
        workdir.mkdir(parents=True, exist_ok=True)
        self.write_log = workdir / "writes.jsonl"
        self.read_log = workdir / "reads.jsonl"
        self.output = workdir / "sim.out"
        self.port = free_port() if info.transport == "tcp" else 0
        self.pty = workdir / "bus"
        self.proc: forkserver.Process | None = None
        self.starts = 0
        self.baudrate = RTU_BAUD
        self.extra_args: tuple[str, ...] = ()  # after the entry's own sim_args

    @property
    def hardware_marker(self) -> str:
        """The part of the node's diagnostics hardware id that names this device's line."""
        if self.info.transport == "tcp":
            return f"tcp://127.0.0.1:{self.port} unit"
        return f"{self.pty}@"

    def address_params(self) -> dict[str, Any]:
        """The node parameters that point it at this simulator."""
        if self.info.transport == "tcp":
            return {"host": "127.0.0.1", "port": self.port}
        return {"serial_port": str(self.pty), "baudrate": self.baudrate}

    def start(self) -> None:
        if self.info.transport == "tcp":
            where = ["--port", str(self.port)]
        else:
            where = ["--pty", str(self.pty), "--baudrate", str(self.baudrate)]
        arguments = [
            *where,
            *self.info.sim_args,
            *self.extra_args,
            "--write-log",
            str(self.write_log),
            "--read-log",
            str(self.read_log),
        ]
        with self.output.open("ab") as out:
            self.proc = forkserver.python_module(
                self.info.sim_module,
                arguments,
                stdout=out,
                stderr=subprocess.STDOUT,
                # A process group of its own, so its socat dies with it on SIGKILL
                # (killpg), but not a session of its own: with the kernel's autogroup
                # scheduling (on by default) a session is a CPU group, and a simulator
                # alone in one was left runnable but unscheduled for up to 2 s beside
                # two CPU burners (perf sched: max delay 1539 ms); its replies then came
                # after the bridge's timeout.
                process_group=True,
            )
        self.starts += 1
        proc = self.proc

        def listening() -> bool:
            if proc.poll() is not None:
                raise AssertionError(f"{self.info.sim_module} exited: {self.output.read_text()}")
            return self.output.read_text().count("listening") >= self.starts

        wait_for(listening, SIM_START_S, f"{self.info.sim_module} to listen")

    def kill(self) -> None:
        """SIGKILL the simulator (and its socat): no goodbye on the wire.

        RTU: the pty link is removed first. A SIGKILLed socat leaves it dangling at a
        /dev/pts number the kernel soon gives to someone else's pty (other tests'
        socat pairs): a reconnecting bridge would then poll a stranger's line.
        """
        if self.info.transport == "rtu":
            self.pty.unlink(missing_ok=True)  # open descriptors keep working
        if self.proc is not None and self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGTERM)
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.kill()

    def writes(self) -> list[WriteRecord]:
        return read_write_log(self.write_log)

    def reads(self) -> list[ReadRecord]:
        return read_read_log(self.read_log)


__all__ = ["BRIDGES", "BridgeInfo", "Call", "JointCommandRow", "SimProcess"]
