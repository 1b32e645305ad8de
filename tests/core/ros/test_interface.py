"""``bridge_core.runtime.interface`` lists what each node really declares and advertises.

One process per executable (each against its simulator, as the other ROS tests run them);
every node of the process is compared with its listing through the ROS graph: parameters
(ListParameters, DescribeParameters, GetParameters), published and subscribed topics with
their types, services, action servers. Nothing missing, nothing extra: what rclpy gives
every node (``interface.standard_*``) is the only addition.
"""

from __future__ import annotations

import sys
import tomllib
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters
from rclpy.action.graph import get_action_server_names_and_types_by_node
from rclpy.node import NodeNameNonExistentError
from rclpy.parameter import parameter_value_to_python

from bridge_core.ros.node_parameters import descriptor
from bridge_core.runtime import interface
from bridge_core.runtime.interface import NodeInterface
from bridge_core.runtime.parameters import ParameterSpec
from bridge_core.wire.transport import SerialSettings
from modbus_bridge.description import load as load_description
from modbus_bridge.interface import DEFAULT_LINE_FILE, described_nodes
from modbus_bridge.sim import make_simulator as make_described_simulator
from motec_bridge.interface import drive_parameters
from stepper_bridge.sim import make_bus_simulator

from ...support.bridges import BRIDGES, RTU_BAUD, SimProcess
from ...support.fixtures import client_fixture
from ...support.ros import ROOT, Client, node_process, unique_namespace, wait_for
from ...support.serial_pair import served_on_pty

pytestmark = pytest.mark.ros

SETTLE_S = 30.0  # discovery of a new process's graph on a loaded machine
ACTION_PART = "/_action/"  # an action server's own topics and services


@dataclass(frozen=True)
class Run:
    """One process of an executable: its namespace, the parameters it was given, and
    what the listing says its nodes are (in this run's configuration)."""

    namespace: str
    given: dict[str, Any]
    nodes: list[NodeInterface]


def listed(executable: str) -> list[NodeInterface]:
    found = [node for node in interface.nodes() if node.executable == executable]
    assert found, f"bridge_core.runtime.interface lists no node of {executable}"
    return found


@contextmanager
def bridge_run(key: str, workdir: Path) -> Iterator[Run]:
    """A bridge of tests/support/bridges.py against its simulator process."""
    info = next(info for info in BRIDGES if info.key == key)
    sim = SimProcess(info, workdir)
    sim.start()
    namespace = unique_namespace(f"interface_{key}")
    given = {**info.params, **sim.address_params()}
    try:
        with node_process(info.module, given, workdir, ["-r", f"__ns:={namespace}"]):
            nodes = listed(info.module.split(".")[0])  # the package's own executable
            if key == "motec":
                nodes = motec_nodes(nodes, given)
            yield Run(namespace, given, nodes)
    finally:
        sim.stop()


def motec_nodes(nodes: list[NodeInterface], given: dict[str, Any]) -> list[NodeInterface]:
    """The drive's ``lifeguard_ms`` text names its bus's floor: this run's line."""
    hold_s = SerialSettings(
        str(given["serial_port"]), int(given["baudrate"]), timeout_s=float(given["timeout_s"])
    ).longest_hold_s()
    drive = drive_parameters(len(given["unit_ids"]), hold_s)
    names = {spec.name for spec in drive}
    return [
        replace(
            node,
            parameters=tuple(
                next(d for d in drive if d.name == spec.name) if spec.name in names else spec
                for spec in node.parameters
            ),
        )
        if node.node.startswith("motec_{")
        else node
        for node in nodes
    ]


@contextmanager
def stepper_bus_run(workdir: Path) -> Iterator[Run]:
    with served_on_pty(make_bus_simulator([1], reply_delay_s=0.0), RTU_BAUD) as port:
        namespace = unique_namespace("interface_stepper_bus")
        given = {"serial_port": port, "baudrate": RTU_BAUD, "unit_ids": [1], "timeout_s": 0.3}
        with node_process("stepper_bridge.bus", given, workdir, ["-r", f"__ns:={namespace}"]):
            yield Run(namespace, given, listed("stepper_bus"))


@contextmanager
def modbus_bus_run(workdir: Path) -> Iterator[Run]:
    simulator = make_described_simulator(load_description(DEFAULT_LINE_FILE))
    with served_on_pty(simulator, RTU_BAUD) as port:
        namespace = unique_namespace("interface_modbus_bus")
        given = {"device_file": str(DEFAULT_LINE_FILE), "serial_port": port}
        with node_process("modbus_bridge.bus", given, workdir, ["-r", f"__ns:={namespace}"]):
            nodes = list(described_nodes(DEFAULT_LINE_FILE))
            assert {n.node for n in nodes} <= {n.node for n in listed("modbus_bus")}
            yield Run(namespace, given, nodes)


RUNS: dict[str, Callable[[Path], Any]] = {
    "r6_bridge": lambda work: bridge_run("r6", work),
    "xarm_bridge": lambda work: bridge_run("xarm", work),
    "stepper_bridge": lambda work: bridge_run("stepper", work),
    "stepper_bus": stepper_bus_run,
    "motec_bridge": lambda work: bridge_run("motec", work),
    "modbus_bridge": lambda work: bridge_run("modbus", work),
    "modbus_bus": modbus_bus_run,
}


client = client_fixture("interface_client", scope="module")


def test_every_executable_is_listed_and_checked() -> None:
    """Each console script that starts bridge nodes (pyproject.toml: a ``node`` or ``bus``
    module's main) has a listing, and a run here."""
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    starting_nodes = {
        name
        for name, target in scripts.items()
        if target.split(":")[0].rsplit(".", 1)[-1] in ("node", "bus")
    }
    assert {node.executable for node in interface.nodes()} == starting_nodes == set(RUNS)


def test_the_listing_needs_no_rclpy() -> None:
    import subprocess

    code = (
        "import sys; from bridge_core.runtime import interface; assert interface.nodes(); "
        "assert not [m for m in sys.modules if m.startswith('rclpy')], 'rclpy imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


@pytest.mark.parametrize("executable", sorted(RUNS))
def test_running_nodes_match_their_listing(client: Client, tmp_path: Path, executable: str) -> None:
    with ExitStack() as stack:
        run: Run = stack.enter_context(RUNS[executable](tmp_path))
        expected = {name: node for node in run.nodes for name in node.node_names()}
        in_graph = settled(
            lambda: {
                name
                for name, ns in client.node.get_node_names_and_namespaces()
                if ns == run.namespace
            },
            set(expected),
        )
        assert in_graph == set(expected), executable
        for name, node in expected.items():
            check_node(client, run, name, node)


def settled(fetch: Callable[[], Any], expected: Any) -> Any:
    """``fetch()`` once it equals ``expected`` (the graph is discovered over time), or
    its last value after ``SETTLE_S`` for the caller's assertion."""
    last: list[Any] = [None]

    def equal() -> bool:
        last[0] = fetch()
        return bool(last[0] == expected)

    with suppress(AssertionError):
        wait_for(equal, SETTLE_S, "the graph to settle")
    return last[0]


def resolve(name: str, namespace: str, node: str) -> str:
    if name.startswith("/"):
        return name
    if name.startswith("~/"):
        return f"{namespace}/{node}/{name[2:]}"
    return f"{namespace}/{name}"


def check_node(client: Client, run: Run, name: str, node: NodeInterface) -> None:
    ns, graph = run.namespace, client.node

    def by_node(query: Callable[[str, str], list[tuple[str, list[str]]]]) -> set[tuple[str, str]]:
        try:
            found = query(name, ns)
        except NodeNameNonExistentError:
            return set()
        return {(n, t) for n, types in found if ACTION_PART not in n for t in types}

    def expected(entries: Any) -> set[tuple[str, str]]:
        return {(resolve(e.name, ns, name), e.type) for e in entries}

    topics = (*node.topics(), *interface.standard_topics(node))
    published = expected(t for t in topics if t.published)
    subscribed = expected(t for t in topics if not t.published)
    services = expected((*node.services(), *interface.standard_services(node)))
    actions = expected(node.actions())
    assert settled(lambda: by_node(graph.get_publisher_names_and_types_by_node), published) == (
        published
    ), f"{name}: published topics"
    assert (
        settled(lambda: by_node(graph.get_subscriber_names_and_types_by_node), subscribed)
        == subscribed
    ), f"{name}: subscribed topics"
    assert settled(lambda: by_node(graph.get_service_names_and_types_by_node), services) == (
        services
    ), f"{name}: services"

    def action_servers() -> set[tuple[str, str]]:
        try:
            found = get_action_server_names_and_types_by_node(graph, name, ns)
        except NodeNameNonExistentError:
            return set()
        return {(n, t) for n, types in found for t in types}

    assert settled(action_servers, actions) == actions, f"{name}: actions"
    check_parameters(client, f"{ns}/{name}", node, run.given)


def check_parameters(client: Client, path: str, node: NodeInterface, given: dict[str, Any]) -> None:
    specs = {spec.name: spec for spec in node.parameters}
    reply = client.call(ListParameters, f"{path}/list_parameters", ListParameters.Request())
    assert set(reply.result.names) == set(specs) | set(interface.ROS_PARAMETERS), path
    names = sorted(specs)
    described = client.call(
        DescribeParameters, f"{path}/describe_parameters", DescribeParameters.Request(names=names)
    ).descriptors
    values = client.call(
        GetParameters, f"{path}/get_parameters", GetParameters.Request(names=names)
    ).values
    for name, got, value in zip(names, described, values, strict=True):
        spec = specs[name]
        want = descriptor(spec)
        assert (got.description, got.read_only) == (want.description, not spec.live), name
        assert type_name(got.type) == type_name(value.type) == spec.type_name, name
        assert ranges(got) == ranges(want), name
        expected_value = spec.coerce(given[name]) if name in given else spec.default
        got_value = parameter_value_to_python(value)
        if not isinstance(got_value, str | bool | int | float):
            got_value = list(got_value)  # an array.array or a sequence
        assert got_value == expected_value, name


def ranges(descriptor_msg: Any) -> tuple[Any, ...]:
    return (
        [(r.from_value, r.to_value) for r in descriptor_msg.integer_range],
        [(r.from_value, r.to_value) for r in descriptor_msg.floating_point_range],
    )


def type_name(kind: int) -> str:
    """The listing's ``ParameterSpec.type_name`` of a ROS parameter type."""
    return {
        ParameterType.PARAMETER_BOOL: "bool",
        ParameterType.PARAMETER_INTEGER: "integer",
        ParameterType.PARAMETER_DOUBLE: "double",
        ParameterType.PARAMETER_STRING: "string",
        ParameterType.PARAMETER_BOOL_ARRAY: "bool[]",
        ParameterType.PARAMETER_INTEGER_ARRAY: "integer[]",
        ParameterType.PARAMETER_DOUBLE_ARRAY: "double[]",
        ParameterType.PARAMETER_STRING_ARRAY: "string[]",
    }[kind]


def test_a_pattern_expands_per_value() -> None:
    (stepper,) = [n for n in interface.nodes() if n.node == "stepper_bridge"]
    jogs = [t.name for t in stepper.topics() if t.name.endswith("/jog")]
    assert jogs == [f"~/motor_{m}/jog" for m in range(1, 6)]
    spec = ParameterSpec("x", 1, "static", text_of=lambda n: f"floor {n}")
    assert spec.described(n=3).description == "floor 3"
