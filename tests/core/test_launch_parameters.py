"""Every launch file starts nodes that accept what it passes (issue: the cell lost MOTEC).

``launch_ros`` is not among the PyPI wheels, so each launch file is evaluated with the
tests' stand-ins (tests/support/launch_run.py) and each of its nodes started the way
``ros2 launch`` starts it: the config file, then the launch file's parameter dict as a
params file, under a namespace of the test's. A node that refuses its parameters exits
(code 2) before it activates; a node that accepts them becomes active (its lifecycle
state, asked through the ROS graph) and keeps running although its device is absent.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.srv import GetState

from ..support import forkserver
from ..support.fixtures import client_fixture
from ..support.launch_run import MissingArgument, evaluate, started
from ..support.ros import ROOT, Client, unique_namespace, wait_for

pytestmark = pytest.mark.ros

LAUNCH = ROOT / "launch"
START_S = 60.0
# What the tests give for arguments without a default (nothing listens there: the node
# must start, report its device unreachable and keep trying).
REQUIRED = {"host": "127.0.0.1"}


client = client_fixture("launch_parameters_client", scope="module")


def launch_files() -> list[Path]:
    return sorted(LAUNCH.glob("*.launch.py"))


def given_for(path: Path) -> dict[str, str]:
    """The required arguments only; every other argument keeps its default."""
    declared = evaluate_arguments(path)
    return {name: REQUIRED[name] for name in declared if name in REQUIRED}


def evaluate_arguments(path: Path) -> dict[str, Any]:
    given = dict(REQUIRED)
    return evaluate(path, given).arguments


@pytest.mark.parametrize("path", launch_files(), ids=lambda p: p.name)
def test_every_launch_argument_is_described(path: Path) -> None:
    for name, argument in evaluate_arguments(path).items():
        assert argument.description and argument.description != "no description given", (
            f"{path.name}: argument {name} has no description"
        )


@pytest.mark.parametrize("name", ["r6.launch.py", "xarm.launch.py"])
def test_tcp_launch_files_need_a_host_and_take_a_port(name: str) -> None:
    """No default address (a launch without arguments would dial a real network's
    machine); a port argument, as the UR driver has."""
    path = LAUNCH / name
    with pytest.raises(MissingArgument, match="host"):
        evaluate(path, {})
    (node,) = evaluate(path, {"host": "10.0.0.9", "port": "1502"}).nodes
    overrides = node.parameters[-1]
    assert isinstance(overrides, dict)
    assert overrides["host"] == "10.0.0.9" and overrides["port"] == 1502
    assert node.lifecycle and node.name == node.executable


@pytest.mark.parametrize("path", launch_files(), ids=lambda p: p.name)
def test_each_node_of_a_launch_file_accepts_its_parameters(
    client: Client, tmp_path: Path, path: Path
) -> None:
    launch = evaluate(path, given_for(path))
    assert launch.nodes, path.name
    prefix = unique_namespace(path.name.split(".")[0])
    with ExitStack() as stack:
        running = []
        for node in launch.nodes:
            namespace = (prefix + node.namespace).rstrip("/")
            work = tmp_path / node.executable
            work.mkdir()
            proc = stack.enter_context(started(node, namespace, work))
            running.append((node, namespace, work / f"{node.executable}.log", proc))
        for node, namespace, log, proc in running:
            check_started(client, f"{path.name}: {node.executable}", namespace, log, proc)


def check_started(
    client: Client, what: str, namespace: str, log: Path, proc: forkserver.Process
) -> None:
    """Active (its log says so, and the lifecycle state of every node of the process in
    ``namespace``), never exited."""
    wait_for(
        lambda: proc.poll() is not None or "active: polling" in log.read_text(),
        START_S,
        f"{what} to start",
    )
    assert proc.poll() is None, f"{what} exited with {proc.returncode}:\n{log.read_text()}"

    def in_graph() -> list[str]:
        graph = client.node.get_node_names_and_namespaces()
        return [name for name, ns in graph if ns == namespace]

    for name in wait_for(in_graph, START_S, f"the nodes of {what} in the graph"):
        state = client.call(GetState, f"{namespace}/{name}/get_state", GetState.Request())
        assert state.current_state.label == "active", (what, name)
    assert proc.poll() is None, f"{what} exited:\n{log.read_text()}"
