"""The behaviour every bridge promises (docs/behaviour.md), checked once
for all four bridges.

Each test runs against the table in ``tests/support/bridges.py``: the simulator in its
own process (write and read requests logged to files, SIGKILL-able), the node in
another, an rclpy client here. Waits are on conditions; "nothing was written" is always
acknowledged by a later round trip (a successful write that must be the only new one,
or a reply that could only come after the refused call was handled).

Tests 1, 3, 4 and 8 share one simulator + node per bridge (they restore what they
change); the others start their own.
"""

from __future__ import annotations

import functools
import importlib
import itertools
import json
import math
import re
import statistics
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml  # type: ignore[import-untyped]
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.node import NodeNameNonExistentError
from rclpy.parameter import Parameter, parameter_value_to_python
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from bridge_core.wire.codec import encode
from modbus_bridge.description import load as load_description
from msg_defs.msg import DeviceValues
from msg_defs.srv import ReadRegisters, SetValue

from ...support import forkserver
from ...support.bridges import BRIDGES, BridgeInfo, Call, JointCommandRow, SimProcess
from ...support.fixtures import client_fixture
from ...support.ros import (
    LATCHED,
    ROOT,
    Bridge,
    Client,
    node_process,
    refused_at_start,
    start_bridge,
    status_node,
    until_sent,
    values_of,
    wait_for,
    wait_subscribed,
    wall_minus_monotonic,
)

pytestmark = pytest.mark.ros

TIMEOUT = 30.0


@dataclass(frozen=True)
class DescribedInfo(BridgeInfo):
    """modbus_bridge on one of config/devices/'s examples; ``keepalive_address``: the
    register its keepalive feeds on its own (not a command's write, left out of
    ``Running.writes``)."""

    keepalive_address: int | None = None


DEVICES = ROOT / "config" / "devices"
VFD = DEVICES / "vfd_rtu.yaml"
VFD_MAP = load_description(VFD).device.register_map
INVERTER = DEVICES / "inverter_tcp_f32.yaml"
INVERTER_MAP = load_description(INVERTER).device.register_map
MODBUS_STARTUP_ONLY = ("unit_id", "timeout_s", "joint_prefix", "device_file")
# The two examples of config/devices/: a VFD on RTU 8E1 (velocity-only joint, a keepalive) and a
# TCP inverter with f32 in CDAB and ABCD. Their params-file test is config/modbus.yaml's
# (the "modbus" entry): ``config`` empty.
DESCRIBED: tuple[DescribedInfo, ...] = (
    DescribedInfo(
        key="modbus_vfd",
        module="modbus_bridge.node",
        node_name="modbus_bridge",
        state_type=DeviceValues,
        transport="rtu",
        sim_module="modbus_bridge.sim",
        sim_args=("--device-file", str(VFD)),
        params={"device_file": str(VFD)},
        good=Call("set_frequency", SetValue, {"value": 25.0}),
        good_write=(6, VFD_MAP["frequency_setpoint"].address, (2500,)),
        bad=Call("set_frequency", SetValue, {"value": 100.0}),
        position_register=VFD_MAP["output_frequency"],  # the velocity-only joint's
        slow_register=VFD_MAP["accel_time"],  # poll: slow in vfd_rtu.yaml
        slow_write=Call("set_accel_time", SetValue, {"value": 5.0}),
        unit_id=1,
        config="",
        startup_only=("serial_port", "baudrate", "parity", "stopbits", *MODBUS_STARTUP_ONLY),
        read_services={"read": Call("read", ReadRegisters, {"names": ["output_frequency"]})},
        mistyped=(("device_file", "/nonexistent/device.yaml"),),
        keepalive_address=VFD_MAP["comm_watchdog"].address,
    ),
    DescribedInfo(
        key="modbus_inverter",
        module="modbus_bridge.node",
        node_name="modbus_bridge",
        state_type=DeviceValues,
        transport="tcp",
        sim_module="modbus_bridge.sim",
        sim_args=("--device-file", str(INVERTER)),
        params={"timeout_s": 0.5, "device_file": str(INVERTER)},
        good=Call("set_torque_limit", SetValue, {"value": 50.0}),
        good_write=(
            16,
            INVERTER_MAP["torque_limit"].address,
            tuple(encode(INVERTER_MAP["torque_limit"], 50.0)),
        ),
        bad=Call("set_torque_limit", SetValue, {"value": 300.0}),
        position_register=INVERTER_MAP["motor_position"],
        slow_register=INVERTER_MAP["torque_limit"],  # poll: slow in inverter_tcp_f32.yaml
        unit_id=1,
        config="",
        startup_only=("host", "port", "max_in_flight", *MODBUS_STARTUP_ONLY),
        read_services={"read": Call("read", ReadRegisters, {"names": ["motor_speed"]})},
        mistyped=(("device_file", "/nonexistent/device.yaml"),),
        joint_commands=JointCommandRow("modbus_bridge", "shaft"),  # its velocity command
    ),
)
ALL: tuple[BridgeInfo, ...] = (*BRIDGES, *DESCRIBED)
IDS = [info.key for info in ALL]
SHARED_POLL_RATE_HZ = 20  # an int on purpose: `-p poll_rate_hz:=20` must be taken
# The shared nodes' status period: the tests that wait for a count or a value in the
# diagnostics wait a quarter of the default 1 s.
SHARED_DIAGNOSTIC_PERIOD_S = 0.25
NOT_DEVICE_SERVICES = ("rcl_interfaces/", "type_description_interfaces/", "lifecycle_msgs/")
ACTION_GOAL_SERVICE = "/_action/send_goal"  # every action server's hidden goal service


def stamp_of(msg: Any) -> float:
    return float(msg.header.stamp.sec) + float(msg.header.stamp.nanosec) * 1e-9


def python_value(value: Any) -> Any:
    """A parameter value as plain Python (arrays as lists)."""
    if isinstance(value, str | bytes | bool | int | float) or value is None:
        return value
    return list(value)


def changed(value: Any) -> Any:
    """Another value of the same type (a refusal must not depend on the value)."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value * 2 + 1
    if isinstance(value, str):
        return value + "_changed"
    return [changed(item) for item in value]


@dataclass
class Running:
    """One simulator and one bridge process, and how to talk to the bridge's nodes."""

    info: BridgeInfo
    sim: SimProcess
    bridge: Bridge
    proc: forkserver.Process
    client: Client

    def path(self, node: str | None = None) -> str:
        return f"{self.bridge.ns}/{node or self.info.node_name}"

    def call(self, call: Call, node: str | None = None) -> Any:
        return self.client.call(
            call.srv_type, f"{self.path(node)}/{call.service}", call.request(), TIMEOUT
        )

    def set_params(self, node: str | None = None, **values: Any) -> list[Any]:
        """SetParameters, one parameter per entry; the results in order."""
        request = SetParameters.Request()
        request.parameters = [
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()
        ]
        reply = self.client.call(SetParameters, f"{self.path(node)}/set_parameters", request)
        return list(reply.results)

    def get_params(self, names: Sequence[str], node: str | None = None) -> list[Any]:
        """GetParameters: the values as plain Python (every name must be declared)."""
        request = GetParameters.Request()
        request.names = list(names)
        reply = self.client.call(GetParameters, f"{self.path(node)}/get_parameters", request)
        assert len(reply.values) == len(names), f"{node}: not all of {names} are declared"
        return [python_value(parameter_value_to_python(v)) for v in reply.values]

    def list_params(self, node: str | None = None) -> set[str]:
        """ListParameters: the names a node declared."""
        reply = self.client.call(
            ListParameters, f"{self.path(node)}/list_parameters", ListParameters.Request()
        )
        return set(reply.result.names)

    def statuses(self, since: float = 0.0) -> list[Any]:
        """This node's diagnostic statuses (matched by name and by its device's line)."""
        return [
            status
            for array in self.client.received("/diagnostics", since)
            for status in array.status
            if status_node(status) == self.info.node_name
            and self.sim.hardware_marker in status.hardware_id
        ]

    def wait_target_rate(self, text: str, since: float) -> None:
        wait_for(
            lambda: any(
                values_of(s).get("target poll rate (Hz)") == text for s in self.statuses(since)
            ),
            TIMEOUT,
            f"diagnostics 'target poll rate (Hz)' = {text}",
        )

    def joint_states(self, since: float = 0.0) -> list[Any]:
        return self.client.received(self.bridge.joint_states, since)

    def writes(self) -> list[tuple[int, int, int, tuple[int, ...]]]:
        """The writes of commands (a keepalive's own feeds left out)."""
        feeds = getattr(self.info, "keepalive_address", None)
        return [
            (w.unit_id, w.function_code, w.address, w.values)
            for w in self.sim.writes()
            if w.address != feeds
        ]

    def good_write(self) -> tuple[int, int, int, tuple[int, ...]]:
        return (self.info.unit_id, *self.info.good_write)


@contextmanager
def running(
    info: BridgeInfo,
    client: Client,
    workdir: Path,
    sim_args: tuple[str, ...] = (),
    **params: Any,
) -> Iterator[Running]:
    """Start the simulator (with ``sim_args`` besides its entry's), then the node against
    it; wait until it is connected."""
    sim = SimProcess(info, workdir)
    sim.extra_args = sim_args
    sim.start()
    try:
        all_params = {"reconnect_max_s": 1.0, **info.params, **sim.address_params(), **params}
        with start_bridge(
            client, workdir, info.module, info.node_name, info.state_type, all_params
        ) as (bridge, proc):
            bridge.wait_connected(True, timeout=TIMEOUT)
            client.wait_message(bridge.joint_states, timeout=TIMEOUT)
            yield Running(info, sim, bridge, proc, client)
    finally:
        sim.stop()


client = client_fixture("contract_client", diagnostics=True, scope="module")


@pytest.fixture(scope="module", params=ALL, ids=IDS)
def shared(
    request: pytest.FixtureRequest, client: Client, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Running]:
    """One simulator + node per bridge for the tests that restore what they change."""
    info: BridgeInfo = request.param
    workdir = tmp_path_factory.mktemp(f"contract_{info.key}")
    with running(
        info,
        client,
        workdir,
        poll_rate_hz=SHARED_POLL_RATE_HZ,
        diagnostic_period_s=SHARED_DIAGNOSTIC_PERIOD_S,
    ) as r:
        yield r


each_bridge = pytest.mark.parametrize("info", ALL, ids=IDS)


# ---------------------------------------------------------------- 1. refusals
def test_refused_value_writes_nothing(shared: Running) -> None:
    """An out-of-range value: success=False, one line, and no write (the next, good
    call's write is the only new record: it went after the refused one on the wire)."""
    r = shared
    before = len(r.writes())
    reply = r.call(r.info.bad)
    assert not reply.success, reply.message
    assert reply.message.strip() and "\n" not in reply.message, repr(reply.message)
    assert "refused" in reply.message, reply.message
    reply = r.call(r.info.good)
    assert reply.success, reply.message
    assert r.writes()[before:] == [r.good_write()]


# ---------------------------------------------------------------- 1b. joint_commands
def test_a_refused_joint_command_writes_nothing(shared: Running) -> None:
    """``~/joint_commands`` (docs/ros2_control.md): a message naming a joint the
    node does not have beside one it has, and one with a NaN, are refused whole: counted
    by kind in the diagnostics, nothing written (the next, good call's write is the only
    new record)."""
    r = shared
    row = r.info.joint_commands
    if row is None:
        pytest.skip(f"{r.info.key} has no ~/joint_commands")
    publisher = r.client.node.create_publisher(
        JointState, f"{r.bridge.ns}/{row.node}/joint_commands", 10
    )
    try:
        wait_subscribed(publisher, TIMEOUT)
        since = time.monotonic()
        before = len(r.writes())
        unknown = JointState(name=[row.joint, "no_such_joint"], velocity=[0.1, 0.1])
        publisher.publish(unknown)
        publisher.publish(JointState(name=[row.joint], velocity=[math.nan]))

        def counted() -> bool:
            for status in r.statuses(since):
                text = values_of(status).get("joint_commands refused", "")
                if "unknown joint: " in text and "not finite: " in text:
                    return True
            return False

        wait_for(counted, TIMEOUT, "both refusals in the diagnostics")
        reply = r.call(r.info.good)
        assert reply.success, reply.message
        assert r.writes()[before:] == [r.good_write()]
    finally:
        r.client.node.destroy_publisher(publisher)


# ---------------------------------------------------------------- 2. read_only at start-up
def write_services(r: Running) -> tuple[list[tuple[str, str, Any]], list[tuple[str, Any]]]:
    """Every device service of the bridge's nodes from the ROS graph: (node, name, type),
    without the parameter / type-description services and the ones that only read; and
    every action server: (name, action type), found by its hidden goal service."""

    def listing() -> list[tuple[str, str, str]]:
        found: list[tuple[str, str, str]] = []
        for node in r.info.nodes:
            try:
                services = r.client.node.get_service_names_and_types_by_node(node, r.bridge.ns)
            except NodeNameNonExistentError:  # not (or, briefly, no longer) in our graph
                return []
            found += [(node, name, types[0]) for name, types in services]
        return sorted(found)

    # Discovery delivers the endpoints over some time: take the list once it is stable.
    last: list[tuple[str, str, str]] = []
    since = time.monotonic()

    def stable() -> bool:
        nonlocal last, since
        now = listing()
        if now != last:
            last, since = now, time.monotonic()
        names = {name for _node, name, _type in now}
        every_node = all(
            any(n == node and not t.startswith(NOT_DEVICE_SERVICES) for n, _name, t in now)
            for node in r.info.nodes
        )
        return (
            time.monotonic() - since > 1.0
            and every_node
            and f"{r.path()}/{r.info.good.service}" in names
        )

    wait_for(stable, TIMEOUT, "a stable list of the bridge's services")
    services = []
    actions = []
    for node, name, type_name in last:
        if type_name.startswith(NOT_DEVICE_SERVICES):
            continue
        package, kind, srv = type_name.split("/")
        if "/_action/" in name:  # an action server's hidden services
            if name.endswith(ACTION_GOAL_SERVICE):
                action = srv.removesuffix("_SendGoal")
                actions.append(
                    (
                        name.removesuffix(ACTION_GOAL_SERVICE),
                        getattr(importlib.import_module(f"{package}.{kind}"), action),
                    )
                )
            continue
        if name.rsplit("/", 1)[1] in r.info.read_services:
            continue
        services.append((node, name, getattr(importlib.import_module(f"{package}.{kind}"), srv)))
    return services, actions


@each_bridge
def test_read_only_at_startup_refuses_every_write(
    info: BridgeInfo, client: Client, tmp_path: Path
) -> None:
    """read_only:=true on the command line: each write service says so, nothing is written."""
    with running(info, client, tmp_path, read_only=True) as r:
        services, actions = write_services(r)
        assert len(services) >= 3, services
        for _node, name, srv_type in services:
            reply = client.call(srv_type, name, srv_type.Request(), TIMEOUT)
            assert not reply.success, (name, reply.message)
            assert "read_only" in reply.message, (name, reply.message)
        for name, action_type in actions:  # goals are rejected under the same guard
            goal = client.send_goal(action_type, name, action_type.Goal(), TIMEOUT, refused=True)
            assert not goal.accepted, name
            goal.close()
        assert len(actions) == info.actions, actions
        for call in info.read_services.values():  # reads still reach the device
            reply = until_sent(functools.partial(r.call, call), TIMEOUT)  # a stalled pty
            assert reply.success, (call.service, reply.message)
        for node in info.nodes:
            assert r.get_params(["read_only"], node) == [True]
        # Every refusal was answered before this point; a write would be logged by now.
        assert r.writes() == []


# ---------------------------------------------------------------- 3. read_only at run time
def test_read_only_set_at_runtime(shared: Running) -> None:
    """SetParameters read_only=true is applied before it answers successful: the very
    next write is refused and writes nothing; false lets writes through again."""
    r = shared
    try:
        for _ in range(3):
            before = len(r.writes())
            (result,) = r.set_params(read_only=True)
            assert result.successful, result.reason
            reply = r.call(r.info.good)
            assert not reply.success and "read_only" in reply.message, reply.message
            assert r.get_params(["read_only"]) == [True]
            (result,) = r.set_params(read_only=False)
            assert result.successful, result.reason
            reply = r.call(r.info.good)
            assert reply.success, reply.message
            assert r.writes()[before:] == [r.good_write()]  # the refused call wrote nothing
    finally:
        r.set_params(read_only=False)


# ---------------------------------------------------------------- 4. parameters are honest
def test_startup_only_parameters_refused_live_poll_rate_applied(shared: Running) -> None:
    """Start-up-only parameters refuse a set (with a reason) and keep their value;
    poll_rate_hz given as an int at start-up was taken, and a set to 5.0 is applied."""
    r = shared
    groups = [(r.info.node_name, r.info.startup_only)]
    if r.info.bus_node is not None:
        groups.append((r.info.bus_node, r.info.bus_startup_only))
    for node, names in groups:
        current = r.get_params(names, node)
        assert None not in current, dict(zip(names, current, strict=True))
        for name, value in zip(names, current, strict=True):
            (result,) = r.set_params(node, **{name: changed(value)})
            assert not result.successful, f"{node}: {name} was accepted"
            assert result.reason.strip(), f"{node}: {name} refused without a reason"
        assert r.get_params(names, node) == current

    assert r.get_params(["poll_rate_hz"]) == [float(SHARED_POLL_RATE_HZ)]
    r.wait_target_rate(f"{SHARED_POLL_RATE_HZ:.2f}", 0.0)
    try:
        (result,) = r.set_params(poll_rate_hz=5.0)
        assert result.successful, result.reason
        applied = time.monotonic()
        assert r.get_params(["poll_rate_hz"]) == [5.0]
        r.wait_target_rate("5.00", applied)
        # The poller follows: joint_states now come 0.2 s apart on average (not 0.05 s,
        # nor the stepper's ~0.12 at 20 Hz, which its wire cannot carry). The mean over
        # eight gaps, not one gap: polls keep a deadline schedule, so a poll the loaded
        # machine started late is followed by a short gap (a stepper run once had gaps
        # 0.09, 0.16, 0.34, 0.05), and a stamp is its block's read inside the poll.
        since = time.monotonic() + 0.3  # after any snapshot of the old rate in flight
        wait_for(lambda: len(r.joint_states(since)) >= 9, TIMEOUT, "9 joint_states at 5 Hz")
        stamps = [stamp_of(m) for m in r.joint_states(since)[:9]]
        gaps = [b - a for a, b in itertools.pairwise(stamps)]
        assert statistics.mean(gaps) >= 0.15, gaps
    finally:
        r.set_params(poll_rate_hz=float(SHARED_POLL_RATE_HZ))


def test_diagnostic_period_is_live(shared: Running) -> None:
    """``diagnostic_period_s`` set to 2 s: the node's next status comes one new period
    after the set (node_diagnostics restarts its timer), not within the old 0.25 s (a
    loaded machine can only make it later: a lower bound). One status, not a gap between
    two: the same proof in half the wait."""
    r = shared
    node = r.info.node_name

    def stamps(after: float) -> list[float]:
        return [
            stamp
            for array in r.client.received("/diagnostics")
            if any(status_node(s) == node for s in array.status)
            and (stamp := stamp_of(array)) > after
        ]

    try:
        asked = time.time()
        (result,) = r.set_params(diagnostic_period_s=2.0)
        answered = time.time()  # applied in between; a status of the old period is older
        assert result.successful, result.reason
        first = wait_for(lambda: stamps(answered), TIMEOUT, "a status at the 2 s period")[0]
        assert first - asked >= 1.5, (asked, answered, first)
    finally:
        r.set_params(diagnostic_period_s=SHARED_DIAGNOSTIC_PERIOD_S)


# ---------------------------------------------------------------- 5. mistyped parameters
MISTYPED = [
    pytest.param(info, name, value, id=f"{info.key}-{name}")
    for info in ALL
    for name, value in info.mistyped
]


@pytest.mark.parametrize(("info", "name", "value"), MISTYPED)
def test_mistyped_startup_parameter_exits_2(
    info: BridgeInfo, name: str, value: str, tmp_path: Path
) -> None:
    """A value of the wrong type: exit code 2 and one line naming it, no traceback."""
    line = refused_at_start(info.module, ["--ros-args", "-p", f"{name}:={value}"], TIMEOUT * 2)
    assert name in line and value in line, line


# ---------------------------------------------------------------- 6. example YAML
def applies_to(key: str, node: str) -> bool:
    """Whether a params-file block (``/**`` or ``/**/<node>``) reaches ``node``."""
    return key == "/**" or key.rsplit("/", 1)[-1] == node


@pytest.mark.parametrize("info", BRIDGES, ids=[info.key for info in BRIDGES])
def test_example_yaml_configures_the_node(info: BridgeInfo, client: Client, tmp_path: Path) -> None:
    """config/<device>.yaml loads with --params-file; the nodes report its values.

    Only the device address is replaced (the simulator's port or pty); the serial line
    and the unit ids come from the file.
    """
    text = (ROOT / "config" / info.config).read_text()
    config = yaml.safe_load(text)
    sim = SimProcess(info, tmp_path / "sim")
    address_key = "port" if info.transport == "tcp" else "serial_port"
    address = sim.address_params()[address_key]
    nodes = [info.node_name]
    for block in config.values():
        values = block["ros__parameters"]
        if address_key in values:
            values[address_key] = address
        if "baudrate" in values:
            sim.baudrate = int(values["baudrate"])
        if "unit_ids" in values:  # MOTEC: one node per drive of the file, the bus node
            units = [int(u) for u in values["unit_ids"]]
            sim.extra_args = ("--unit-ids", ",".join(str(u) for u in units))
            nodes = [f"motec_{u}" for u in units]
    if info.bus_node is not None:
        nodes.append(info.bus_node)
    # The file as a user has it, only the address line changed (a YAML dump could lose
    # quotes that matter to ROS's parser, e.g. parity "N").
    text, count = re.subn(
        rf"^(\s*{address_key}:\s*)\S+", lambda m: m.group(1) + json.dumps(address), text, flags=re.M
    )
    # modbus_bridge's file leaves the link to its description: the address goes with -p.
    assert count == 1 or (count == 0 and info.key == "modbus"), (
        f"{info.config} has no single {address_key} line"
    )
    address_args = [] if count else ["-p", f"{address_key}:={address}"]
    params_file = tmp_path / info.config
    params_file.write_text(text)
    expected: dict[str, dict[str, Any]] = {
        node: {
            name: value
            for key, block in config.items()
            if applies_to(key, node)
            for name, value in block["ros__parameters"].items()
        }
        for node in nodes
    }

    namespace = f"/contract_yaml_{info.key}"
    connected = f"{namespace}/{info.node_name}/connected"
    client.subscribe(Bool, connected, LATCHED)
    sim.start()
    try:
        extra = ["--params-file", str(params_file), *address_args, "-r", f"__ns:={namespace}"]
        with node_process(info.module, {}, tmp_path, extra) as proc:
            client.wait_message(connected, lambda m: m.data, TIMEOUT)
            r = Running(
                info, sim, Bridge(client, namespace, info.node_name, info.state_type), proc, client
            )
            found: set[str] = set()
            for node, wanted in expected.items():
                names = sorted(set(wanted) & r.list_params(node))  # bus vs drive settings
                got = dict(zip(names, r.get_params(names, node), strict=True))
                for name in names:
                    assert got[name] == wanted[name], (node, name, got[name], wanted[name])
                found.update(names)
            every = {name for wanted in expected.values() for name in wanted}
            assert found == every, f"parameters of the file no node declares: {every - found}"
            assert proc.poll() is None
    finally:
        sim.stop()


# ---------------------------------------------------------------- 7. simulator killed
@each_bridge
def test_simulator_killed_and_restarted(info: BridgeInfo, client: Client, tmp_path: Path) -> None:
    """SIGKILL mid-poll: connected false and no fresh joint_states while down; after a
    restart at the same port / pty path: connected true and joint_states again.

    "Fresh" is judged by order, not by a tolerance: the node publishes connected=false
    only after its last successful poll, so every stamp it publishes must be older than
    the moment that message reached us (a reply in flight at the kill may still be
    stamped a little after the kill itself).
    """
    rate = 50.0 if info.transport == "tcp" else 20.0
    # A slow period longer than the test: only the reconnect can make the slow group due.
    # Statuses every 0.25 s: the two ERROR statuses while down come in half a second, not 2.
    with running(
        info,
        client,
        tmp_path,
        poll_rate_hz=rate,
        timeout_s=0.3,
        slow_poll_period_s=3600.0,
        diagnostic_period_s=0.25,
    ) as r:
        b = r.bridge
        killed = time.monotonic()
        r.sim.kill()
        b.wait_connected(False, since=killed, timeout=TIMEOUT)
        down = time.monotonic()
        # Stay down through two diagnostics periods (ERROR both times).
        wait_for(
            lambda: sum(s.level == bytes([2]) for s in r.statuses(down)) >= 2,
            TIMEOUT,
            "two ERROR diagnostics while the device is down",
        )
        # Named with the node's full name: two bridges of a kind in a domain differ.
        assert {s.name.split(": ", 1)[0] for s in r.statuses(down)} == {f"{b.ns}/{info.node_name}"}
        wall_offset = wall_minus_monotonic()
        went_down = min(
            t for t, msg in list(client.messages[b.connected]) if t >= killed and not msg.data
        )
        went_down_wall = went_down + wall_offset
        for topic in (b.joint_states, b.state):
            fresh = [m for m in client.received(topic, killed) if stamp_of(m) >= went_down_wall]
            assert fresh == [], f"{topic}: stamps after the node reported the link down"
        assert r.proc.poll() is None

        restarted_wall, restarted = time.time(), time.monotonic()
        r.sim.start()
        b.wait_connected(True, since=restarted, timeout=TIMEOUT)
        client.wait_message(
            b.joint_states, lambda m: stamp_of(m) > restarted_wall, TIMEOUT, since=restarted
        )
        # No slow value of the old connection: every ~/state after the restart has its
        # slow group read on the new one.
        client.wait_message(b.state, timeout=TIMEOUT, since=restarted)
        for m in client.received(b.state, restarted):
            assert slow_stamp_of(m) > restarted_wall, "a slow value read before the restart"
        assert r.proc.poll() is None


# ---------------------------------------------------------------- 8. stamp = read time
def test_stamp_is_the_read_time_of_the_position_block(shared: Running) -> None:
    """Each joint_states stamp t lies between the handling of a read request covering the
    position register (t1) and the next read request of that unit (t3): the bridge
    stamps when the position block's reply arrived, not at the start or end of a poll."""
    r = shared
    reg = r.info.position_register
    since = time.monotonic()
    wait_for(lambda: len(r.joint_states(since)) >= 5, TIMEOUT, "5 joint_states")
    stamps = [stamp_of(m) for m in r.joint_states(since)[:5]]
    assert_stamped_by_reads(r, reg, stamps)


def assert_stamped_by_reads(r: Running, register: Any, stamps: Sequence[float]) -> None:
    """Each stamp t lies between the handling of the last read covering ``register`` up to
    t (t1) and the unit's next read request (t3)."""

    def unit_reads() -> list[Any]:
        return [rec for rec in r.sim.reads() if rec.unit_id == r.info.unit_id]

    wait_for(
        lambda: any(rec.time > max(stamps) for rec in unit_reads()),
        TIMEOUT,
        "a read request after the last stamp",
    )
    reads = unit_reads()
    for t in stamps:
        covering = [
            i
            for i, rec in enumerate(reads)
            if rec.covers(register.table, register.address) and rec.time <= t
        ]
        assert covering, f"no read of {register.name} before the stamp {t}"
        t1, t3 = reads[covering[-1]].time, reads[covering[-1] + 1].time
        assert t1 <= t <= t3, (t1, t, t3)


# ---------------------------------------------------------------- 10. rate groups
def slow_stamp_of(msg: Any) -> float:
    return float(msg.slow_stamp.sec) + float(msg.slow_stamp.nanosec) * 1e-9


def unit_reads_of(r: Running, register: Any, since: float = 0.0) -> list[Any]:
    """The simulator's handled read requests of this unit covering ``register``."""
    return [
        rec
        for rec in r.sim.reads()
        if rec.unit_id == r.info.unit_id
        and rec.covers(register.table, register.address)
        and rec.time >= since
    ]


@contextmanager
def slow_period(r: Running, period_s: float) -> Iterator[None]:
    """``slow_poll_period_s`` set live for the block, then back to its default."""
    (result,) = r.set_params(slow_poll_period_s=period_s)
    assert result.successful, result.reason
    try:
        yield
    finally:
        r.set_params(slow_poll_period_s=1.0)


def test_the_slow_group_is_read_less_often_than_the_fast_one(shared: Running) -> None:
    """Every bridge's slow group is read, again and again, and less often than its joints;
    ~/state's slow_stamp follows it."""
    r = shared
    slow = r.info.slow_register
    assert slow is not None
    with slow_period(r, 0.25):  # five fast polls (20 Hz) to a slow one
        since = time.time()
        wait_for(lambda: len(unit_reads_of(r, slow, since)) >= 3, TIMEOUT, "3 slow reads")
        slow_reads = unit_reads_of(r, slow, since)[:3]
        until = slow_reads[-1].time
        fast_reads = [
            rec for rec in unit_reads_of(r, r.info.position_register, since) if rec.time <= until
        ]
        assert len(fast_reads) > len(slow_reads), (len(fast_reads), len(slow_reads))
        wait_for(
            lambda: any(slow_stamp_of(m) >= until for m in r.client.received(r.bridge.state)),
            TIMEOUT,
            "a ~/state with the newest slow_stamp",
        )


def test_slow_stamp_is_the_read_time_of_the_slow_group(shared: Running) -> None:
    """slow_stamp t lies between the handling of a read covering the slow register (t1)
    and the unit's next read request (t3), as the joint stamp does for its block."""
    r = shared
    slow = r.info.slow_register
    assert slow is not None
    with slow_period(r, 0.3):
        since = time.monotonic()
        wait_for(
            lambda: len({slow_stamp_of(m) for m in r.client.received(r.bridge.state, since)}) >= 3,
            TIMEOUT,
            "3 distinct slow stamps",
        )
        stamps = sorted({slow_stamp_of(m) for m in r.client.received(r.bridge.state, since)})[:3]
    assert_stamped_by_reads(r, slow, stamps)


def test_a_write_to_the_slow_group_is_read_back_at_the_next_poll(shared: Running) -> None:
    """With a period far longer than the test, the slow register is read again before the
    joints are read twice after the write: only the write can have made it due."""
    r = shared
    slow = r.info.slow_register
    assert slow is not None
    call = r.info.slow_write or r.info.good
    with slow_period(r, 3600.0):
        settled = time.time()  # a refresh the period had made due is over after two polls
        wait_for(
            lambda: len(unit_reads_of(r, r.info.position_register, settled)) >= 2,
            TIMEOUT,
            "two polls",
        )
        before = time.time()
        reply = r.call(call)
        assert reply.success, reply.message
        writes = [w for w in r.sim.writes() if w.time >= before]
        assert writes, "the call wrote nothing"
        written = writes[-1].time
        wait_for(
            lambda: len(unit_reads_of(r, r.info.position_register, written)) >= 2,
            TIMEOUT,
            "two polls after the write",
        )
        second_poll = unit_reads_of(r, r.info.position_register, written)[1].time
        assert [rec for rec in unit_reads_of(r, slow, written) if rec.time <= second_poll], (
            f"{slow.name} was not read again within a poll of the write"
        )
        wait_for(
            lambda: any(slow_stamp_of(m) >= written for m in r.client.received(r.bridge.state)),
            TIMEOUT,
            "a ~/state whose slow group was read after the write",
        )


def test_diagnostics_show_the_wire_budget(shared: Running) -> None:
    """Every bridge's diagnostics carry its wire budget once it polled without the slow
    group: the load, the rate the wire carries, the wire time of a poll, and the measured
    reply delay (serial) or round trip (TCP); a bus's devices also show their line's sum."""
    r = shared
    turnaround = "reply delay (ms)" if r.info.transport == "rtu" else "round trip (ms)"
    since = time.monotonic()

    def budget() -> dict[str, str] | None:
        for status in reversed(r.statuses(since)):
            values = values_of(status)
            if values.get("wire load (%)", "n/a") != "n/a":
                return values
        return None

    values = wait_for(budget, TIMEOUT, "diagnostics with the wire budget")
    assert float(values["wire load (%)"]) >= 0
    assert float(values["wire time per poll (ms)"]) > 0
    assert float(values[turnaround]) >= 0
    achievable = values["achievable poll rate (Hz)"]
    assert achievable == "unbounded" or float(achievable) > 0
    if r.info.bus_startup_only:  # a node on a line a bus owner shares
        line = wait_for(
            lambda: next(
                (
                    v["line load, all devices (%)"]
                    for s in reversed(r.statuses(since))
                    if (v := values_of(s)).get("line load, all devices (%)", "n/a") != "n/a"
                ),
                None,
            ),
            TIMEOUT,
            "the line's load",
        )
        assert float(line) >= float(values["wire load (%)"])


# ---------------------------------------------------------------- pipelined Modbus TCP
PIPELINED = [info for info in ALL if info.stop is not None]
FALLBACK_WARN = "pipelining (13 requests in flight) failed"


@pytest.mark.parametrize("info", PIPELINED, ids=[info.key for info in PIPELINED])
def test_pipelining_falls_back_on_a_device_that_answers_one_request_at_a_time(
    info: BridgeInfo, client: Client, tmp_path: Path
) -> None:
    """``max_in_flight`` 13 against a simulator that drops a request arriving while one is
    unanswered: the node falls back to one at a time, says so once (WARN), counts it in
    diagnostics, and keeps publishing."""
    with running(
        info, client, tmp_path, ("--one-request-at-a-time",), max_in_flight=13, poll_rate_hz=20
    ) as r:
        since = time.monotonic()

        def fallen_back() -> dict[str, str] | None:
            for status in reversed(r.statuses(since)):
                values = values_of(status)
                if values.get("pipelining fallbacks") == "1":
                    return values
            return None

        values = wait_for(fallen_back, TIMEOUT, "diagnostics counting one pipelining fallback")
        assert values["max in flight"] == "1 (asked 13)"
        after = time.monotonic()
        wait_for(lambda: len(r.joint_states(after)) >= 5, TIMEOUT, "joint_states after it")
        log = (tmp_path / f"{info.module.replace('.', '_')}.log").read_text()
        assert log.count(FALLBACK_WARN) == 1, log[-2000:]
        assert "WARN" in next(line for line in log.splitlines() if FALLBACK_WARN in line)


@pytest.mark.parametrize("info", PIPELINED, ids=[info.key for info in PIPELINED])
def test_a_stop_is_on_the_wire_within_one_transaction_while_a_pipelined_poll_is_in_flight(
    info: BridgeInfo, client: Client, tmp_path: Path
) -> None:
    """A stop called while a pipelined poll is in flight goes in the next free slot: the
    device sees at most the reads already in flight (two) before it, plus those a slow
    service call lets through (two more per 100 ms round trip), never the rest of the poll.

    The poll is slow on purpose (100 ms round trips, two in flight: 8-13 reads take
    0.4-0.7 s), and the stop is called just after a poll's first read reached the device
    (the position block is the last of a poll), so most of that poll is still ahead."""
    window = 2
    assert info.stop is not None
    with running(
        info, client, tmp_path, ("--reply-delay-ms", "100"), max_in_flight=window, poll_rate_hz=1000
    ) as r:
        position = r.info.position_register

        def poll_began() -> bool:
            """A poll's first read reached the device (after the second poll, the first
            pipelined one, ended): most of that poll is ahead."""
            reads = r.sim.reads()
            ends = [i for i, x in enumerate(reads) if x.covers(position.table, position.address)]
            return len(ends) >= 2 and ends[-1] < len(reads) - 1

        stop_call = info.stop
        service = f"{r.path()}/{stop_call.service}"
        # Matched before the clock starts: a fresh client's discovery (tens of ms, more on
        # a loaded machine) would let further reads through that are not the bridge's.
        with client.service_client(stop_call.srv_type, service, TIMEOUT) as stop_client:
            wait_for(poll_began, TIMEOUT, "a pipelined poll to begin")
            called = time.time()
            reply = stop_client.call_async(stop_call.request())
            wait_for(reply.done, TIMEOUT, f"reply from {service}")
        stop = [w for w in r.sim.writes() if w.time >= called]
        assert stop, "the stop wrote nothing"
        ahead = [x for x in r.sim.reads() if called <= x.time <= stop[0].time]
        assert len(ahead) <= 2 * window, [(x.table.value, x.address) for x in ahead]
