"""Every node's ROS interface as data, listed without starting ROS (no rclpy import).

Each bridge package declares its nodes in ``<bridge>/interface.py`` (``NODES``: one
``NodeInterface`` per kind of node an executable starts: its parameters, the topics it
publishes or subscribes, its services and actions) and names that tuple in the entry-point
group ``modbus_bridges.interface`` of pyproject.toml (or a function that returns them:
``modbus_bridge``'s come from description files), as the demo entries are named
(``bridge_core.runtime.entries``). ``nodes()`` collects them::

    for node in interface.nodes():
        print(node.executable, node.node, [spec.name for spec in node.parameters])

Names are relative to the node as the node creates them: ``~/state`` (the node's private
namespace), ``joint_states`` (the node's namespace), ``/diagnostics`` (absolute). A name
per joint, motor, drive or register is a pattern with ``{placeholders}``; ``expansion``
gives each placeholder's values in the node's default configuration, and ``topics()``,
``services()``, ``actions()`` expand the patterns (``declared_*`` keep them).
``tests/core/ros/test_interface.py`` compares each listing with a running node's ROS graph.
"""

from __future__ import annotations

import importlib
import itertools
import string
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TypeVar

from . import entries
from .parameters import (
    GOAL_TIMEOUT_SPEC,
    DeviceDefaults,
    ParameterSpec,
    bridge_specs,
    bus_specs,
)


@dataclass(frozen=True)
class Topic:
    name: str
    type: str  # e.g. "sensor_msgs/msg/JointState"
    published: bool  # else subscribed
    text: str = ""


@dataclass(frozen=True)
class Service:
    name: str
    type: str  # e.g. "std_srvs/srv/Trigger"
    text: str = ""


@dataclass(frozen=True)
class Action:
    name: str
    type: str  # e.g. "msg_defs/action/MoveTo"
    text: str = ""


E = TypeVar("E", Topic, Service, Action)


def expand(entries: Iterable[E], expansion: Mapping[str, Sequence[object]]) -> tuple[E, ...]:
    """Each entry whose name is a pattern, once per combination of its placeholders'
    values (a placeholder without values expands to nothing)."""
    out: list[E] = []
    for entry in entries:
        keys = [key for _, key, _, _ in string.Formatter().parse(entry.name) if key]
        for values in itertools.product(*(expansion[key] for key in keys)):
            out.append(
                replace(entry, name=entry.name.format(**dict(zip(keys, values, strict=True))))
            )
    return tuple(out)


@dataclass(frozen=True)
class NodeInterface:
    """One kind of node: what it declares and advertises in its default configuration."""

    package: str
    executable: str  # console script of pyproject.toml that starts it
    node: str  # its name (a pattern for one node per device: "motec_{unit_id}")
    text: str
    parameters: tuple[ParameterSpec, ...]
    declared_topics: tuple[Topic, ...] = ()
    declared_services: tuple[Service, ...] = ()
    declared_actions: tuple[Action, ...] = ()
    expansion: Mapping[str, Sequence[object]] = field(default_factory=dict)
    lifecycle: bool = True  # a managed node (rclpy.lifecycle)

    def topics(self) -> tuple[Topic, ...]:
        return expand(self.declared_topics, self.expansion)

    def services(self) -> tuple[Service, ...]:
        return expand(self.declared_services, self.expansion)

    def actions(self) -> tuple[Action, ...]:
        return expand(self.declared_actions, self.expansion)

    def node_names(self) -> tuple[str, ...]:
        """The node's name, or each name of a pattern (default configuration)."""
        return tuple(t.name for t in expand((Topic(self.node, "", True),), self.expansion))


# What every bridge node publishes (``BridgeNode``).
BRIDGE_TOPICS = (
    Topic("joint_states", "sensor_msgs/msg/JointState", True, "joint positions (SI units)"),
    Topic("~/connected", "std_msgs/msg/Bool", True, "link state; transient local, on change"),
    Topic(
        "/diagnostics",
        "diagnostic_msgs/msg/DiagnosticArray",
        True,
        "every diagnostic_period_s (1 s)",
    ),
)


def bridge_node(
    package: str,
    executable: str,
    node: str,
    text: str,
    defaults: DeviceDefaults,
    parameters: Iterable[ParameterSpec],
    *,
    owns_link: bool = True,
    topics: Iterable[Topic] = (),
    services: Iterable[Service] = (),
    actions: Iterable[Action] = (),
    expansion: Mapping[str, Sequence[object]] | None = None,
) -> NodeInterface:
    """A ``BridgeNode``: the base's parameters and topics, then the bridge's own
    (``goal_timeout_s`` with the first action server: ``ActionHost``)."""
    actions = tuple(actions)
    return NodeInterface(
        package,
        executable,
        node,
        text,
        (
            *bridge_specs(defaults, owns_link=owns_link),
            *parameters,
            *((GOAL_TIMEOUT_SPEC,) if actions else ()),
        ),
        (*BRIDGE_TOPICS, *topics),
        tuple(services),
        actions,
        dict(expansion or {}),
    )


def bus_node(
    package: str,
    executable: str,
    node: str,
    text: str,
    defaults: DeviceDefaults,
    parameters: Iterable[ParameterSpec] = (),
    *,
    unit_ids: bool = True,
    topics: Iterable[Topic] = (),
    services: Iterable[Service] = (),
) -> NodeInterface:
    """A ``BusNode``: the line's parameters, then the bus's own (the MOTEC bus owner's
    ``~/joint_commands``)."""
    return NodeInterface(
        package,
        executable,
        node,
        text,
        (*bus_specs(defaults, unit_ids=unit_ids), *parameters),
        declared_topics=tuple(topics),
        declared_services=tuple(services),
    )


# What rclpy gives every node (and rclpy.lifecycle every managed node), not the bridge:
# not in a bridge's declarations, but in its ROS graph.
ROS_PARAMETERS = ("use_sim_time", "start_type_description_service")
ROS_TOPICS = (
    Topic("/rosout", "rcl_interfaces/msg/Log", True),
    Topic("/parameter_events", "rcl_interfaces/msg/ParameterEvent", True),
)
ROS_SERVICES = (
    *(
        Service(f"~/{name}", f"rcl_interfaces/srv/{kind}")
        for name, kind in (
            ("describe_parameters", "DescribeParameters"),
            ("get_parameter_types", "GetParameterTypes"),
            ("get_parameters", "GetParameters"),
            ("list_parameters", "ListParameters"),
            ("set_parameters", "SetParameters"),
            ("set_parameters_atomically", "SetParametersAtomically"),
        )
    ),
    Service("~/get_type_description", "type_description_interfaces/srv/GetTypeDescription"),
)
LIFECYCLE_TOPICS = (Topic("~/transition_event", "lifecycle_msgs/msg/TransitionEvent", True),)
LIFECYCLE_SERVICES = tuple(
    Service(f"~/{name}", f"lifecycle_msgs/srv/{kind}")
    for name, kind in (
        ("change_state", "ChangeState"),
        ("get_available_states", "GetAvailableStates"),
        ("get_available_transitions", "GetAvailableTransitions"),
        ("get_state", "GetState"),
        ("get_transition_graph", "GetAvailableTransitions"),
    )
)


def standard_topics(node: NodeInterface) -> tuple[Topic, ...]:
    return ROS_TOPICS + (LIFECYCLE_TOPICS if node.lifecycle else ())


def standard_services(node: NodeInterface) -> tuple[Service, ...]:
    return ROS_SERVICES + (LIFECYCLE_SERVICES if node.lifecycle else ())


@dataclass(frozen=True)
class Bridge:
    """One bridge package as the entry-point group names it (``r6`` -> ``r6_bridge``)."""

    name: str
    spec: str  # module:attr of its NODES

    @property
    def module(self) -> str:
        return self.spec.partition(":")[0]

    @property
    def package(self) -> str:
        return entries.package_of(self.spec)

    @property
    def source(self) -> str:
        return self.module.replace(".", "/") + ".py"


def bridges() -> dict[str, Bridge]:
    """Every bridge by name, in declared order: one per entry of the group
    ``entries.BRIDGES_GROUP`` (pyproject.toml in a checkout, else the installed entry
    points), as ``entries.bridge_packages()`` lists them."""
    table = entries.entry_table(entries.BRIDGES_GROUP)
    return {name: Bridge(name, spec) for name, spec in table.items()}


def entry_specs() -> list[str]:
    """The ``module:attr`` of every bridge's ``NODES`` (pyproject.toml in a checkout, else
    the installed entry points: ``bridge_core.runtime.entries``)."""
    return [bridge.spec for bridge in bridges().values()]


def nodes(specs: Sequence[str] | None = None) -> list[NodeInterface]:
    """Every node of every bridge (``specs``: ``module:attr`` of the tuples to list)."""
    found: list[NodeInterface] = []
    for spec in entry_specs() if specs is None else specs:
        module, _, attr = spec.partition(":")
        declared = getattr(importlib.import_module(module), attr or "NODES")
        found += declared() if callable(declared) else declared
    return found


__all__ = [
    "Action",
    "Bridge",
    "NodeInterface",
    "Service",
    "Topic",
    "bridge_node",
    "bridges",
    "bus_node",
    "expand",
    "nodes",
    "standard_services",
    "standard_topics",
]
