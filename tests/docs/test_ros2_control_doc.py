"""docs/ros2_control.md's URDF tags and controller YAML name what the bridges really have:
the command and state topics of the demo's namespaces, the joint
names, the command and state interfaces, the stock interface's parameters."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import yaml  # type: ignore[import-untyped]

from bridge_core.runtime import interface
from bridge_core.runtime.interface import NodeInterface
from motec_bridge.demo import DEMO as MOTEC_DEMO
from motec_bridge.demo import UNITS
from stepper_bridge.demo import DEMO as STEPPER_DEMO
from stepper_bridge.registers import MOTORS

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "ros2_control.md"
BLOCK = re.compile(r"^```(\w+)\n(.*?)^```", re.MULTILINE | re.DOTALL)
PLUGIN = "joint_state_topic_hardware_interface/JointStateTopicSystem"
# The interface's hardware parameters (its README and source name these four).
HARDWARE_PARAMETERS = {
    "joint_commands_topic",
    "joint_states_topic",
    "trigger_joint_command_threshold",
    "sum_wrapped_joint_states",
}
INTERFACES = {"position", "velocity"}  # what ~/joint_commands takes
EVERY_CYCLE = "-1"  # the threshold velocity control needs (the page says why)

# The demo's namespaces (bridge_core/ros/demo.py: /<name in lower case>), the node that
# owns each bridge's ~/joint_commands, and the joints it names in joint_states.
SYSTEMS = {
    STEPPER_DEMO.namespace: (
        "stepper_bridge",
        [f"motor_{m}" for m in range(1, MOTORS + 1)],
    ),
    MOTEC_DEMO.namespace: ("motec_bridge", [f"drive_{u}" for u in UNITS]),
}


def blocks(language: str) -> list[str]:
    return [body for lang, body in BLOCK.findall(PAGE.read_text()) if lang == language]


def systems() -> list[ET.Element]:
    found = [ET.fromstring(body) for body in blocks("xml")]
    assert found, "no URDF tag on the page"
    return found


def listed(node: str) -> NodeInterface:
    (found,) = [n for n in interface.nodes() if n.node == node]
    return found


def test_each_urdf_tag_names_a_bridges_topics_and_joints() -> None:
    for system in systems():
        assert system.tag == "ros2_control" and system.get("type") == "system"
        hardware = system.find("hardware")
        assert hardware is not None
        plugin = hardware.find("plugin")
        assert plugin is not None and plugin.text == PLUGIN
        params = {p.get("name"): (p.text or "").strip() for p in hardware.findall("param")}
        assert set(params) <= HARDWARE_PARAMETERS, params
        commands, states = params["joint_commands_topic"], params["joint_states_topic"]
        namespace = states.removesuffix("/joint_states")
        owner, joints = SYSTEMS[namespace]
        assert commands == f"{namespace}/{owner}/joint_commands"
        topics = {(t.name, t.type, t.published) for t in listed(owner).topics()}
        assert ("~/joint_commands", "sensor_msgs/msg/JointState", False) in topics
        assert params["trigger_joint_command_threshold"] == EVERY_CYCLE
        names = [j.get("name") for j in system.findall("joint")]
        assert names and set(names) <= set(joints), names
        for joint in system.findall("joint"):
            command = {c.get("name") for c in joint.findall("command_interface")}
            state = {s.get("name") for s in joint.findall("state_interface")}
            assert len(command) == 1 and command <= INTERFACES, command  # decision 1
            assert "position" in state and state <= INTERFACES, state


def test_the_bridges_publish_the_state_topic_the_tags_read() -> None:
    for owner, _ in SYSTEMS.values():
        drive_or_node = "motec_{unit_id}" if owner == "motec_bridge" else owner
        topics = {t.name for t in listed(drive_or_node).topics() if t.published}
        assert "joint_states" in topics


def interfaces_by_joint() -> dict[str, str]:
    found: dict[str, str] = {}
    for system in systems():
        for joint in system.findall("joint"):
            (command,) = [c.get("name") for c in joint.findall("command_interface")]
            found[str(joint.get("name"))] = str(command)
    return found


def controllers() -> list[dict[str, Any]]:
    return [
        data["joint_trajectory_controller"]["ros__parameters"]
        for data in (yaml.safe_load(body) for body in blocks("yaml"))
        if "joint_trajectory_controller" in data
    ]


def test_the_controller_yaml_drives_the_tags_joints_by_their_interfaces() -> None:
    by_joint = interfaces_by_joint()
    found = controllers()
    assert {tuple(c["command_interfaces"]) for c in found} == {("position",), ("velocity",)}
    for controller in found:
        (kind,) = controller["command_interfaces"]
        assert controller["joints"], controller
        for joint in controller["joints"]:
            assert by_joint.get(joint) == kind, (joint, kind)
        assert set(controller["state_interfaces"]) <= INTERFACES
        if kind == "velocity":
            assert set(controller["gains"]) == set(controller["joints"])


def test_the_controller_manager_runs_the_stock_controllers() -> None:
    managers = [
        data["controller_manager"]["ros__parameters"]
        for data in (yaml.safe_load(body) for body in blocks("yaml"))
        if "controller_manager" in data
    ]
    (manager,) = managers
    assert manager["joint_trajectory_controller"]["type"] == (
        "joint_trajectory_controller/JointTrajectoryController"
    )
    assert manager["update_rate"] == 100


def test_the_lock_rule_figures_and_lines_are_the_codes() -> None:
    """The page's unlock tolerance (1 % of joint_command_max_jump, 0.001 when the
    check is off) and the line it quotes are what the code has."""
    from bridge_core.ros.node_streams import NOTHING_MOVED
    from bridge_core.runtime import joint_commands as jc

    text = " ".join(PAGE.read_text(encoding="utf-8").split())
    assert f"within {jc.UNLOCK_SHARE * 100:g} % of" in text
    assert f"({jc.unlock_tolerance(0.0):g})" in text
    assert NOTHING_MOVED in text
