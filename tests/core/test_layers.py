"""The import rules of docs/architecture.md, read from the source (no import is run).

Layers, lowest first: ``bridge_core.wire`` (the Modbus pipe: the only layer that imports
pymodbus), ``bridge_core.runtime`` (polling, streams, goals, checks: plain Python),
``bridge_core.ros`` (the rclpy side). ``bridge_core.sim`` (the simulators' base, a pymodbus
server) sits beside the runtime. A module imports its own layer and the layers below;
nothing below the ROS side imports rclpy. In a bridge package (every bridge of
``bridge_packages()``), only the ROS side (``node``, ``bus``, ``demo``, ``node_services``)
imports rclpy, ``bridge_core.ros`` or ROS message packages; every other module, found by
walking the package, is ROS-free, and only the node side polls (``poller``); devices read
through ``reads``. Imports under ``if TYPE_CHECKING:`` are not imports at run time and are
left out of the cycle check.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from bridge_core.runtime.entries import bridge_packages

ROOT = Path(__file__).resolve().parents[2]
BRIDGES = tuple(bridge_packages().values())
LAYER_ORDER = {"wire": 0, "runtime": 1, "sim": 1, "ros": 2}
# Third-party packages each layer may import (besides the standard library and PyYAML).
PYMODBUS_LAYERS = {"wire", "sim"}
ROS_PACKAGES = (
    "rclpy",
    "std_msgs",
    "sensor_msgs",
    "geometry_msgs",
    "diagnostic_msgs",
    "lifecycle_msgs",
    "action_msgs",
    "std_srvs",
    "rcl_interfaces",
    "builtin_interfaces",
    "unique_identifier_msgs",
    "msg_defs",
    "rosbag2_py",
    "mcap_ros2",
)
# A bridge's ROS side: its node, a bus owner's node, its entry in the demo cell, and the
# services / actions a node registers. Every other module of a bridge is ROS-free.
ROS_SIDE_BRIDGE_MODULES = frozenset({"node", "bus", "demo", "node_services"})


@dataclass(frozen=True)
class Import:
    module: str  # the importing module, dotted
    target: str  # the imported module, dotted
    line: int
    type_only: bool


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _type_checking_lines(tree: ast.Module) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


def imports_of(path: Path, root: Path) -> Iterator[Import]:
    """Every import in one file, relative ones resolved to dotted names."""
    name = module_name(path, root)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(), str(path))
    type_only = _type_checking_lines(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Import(name, alias.name, node.lineno, node.lineno in type_only)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:
                # ``from pkg import module`` names a module when pkg is one of ours.
                target = (
                    f"{base}.{alias.name}" if node.level or base.startswith("bridge_core") else base
                )
                yield Import(name, target, node.lineno, node.lineno in type_only)


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] == "bridge_core" and len(parts) > 1 and parts[1] in LAYER_ORDER:
        return parts[1]
    return None


def _top(target: str) -> str:
    return target.split(".")[0]


def violations(root: Path) -> list[str]:
    """What breaks the rules under ``root`` (a tree holding bridge_core and the bridges)."""
    found: list[str] = []
    for path in sorted((root / "bridge_core").rglob("*.py")):
        own = layer_of(module_name(path, root))
        if own is None:
            continue
        for imp in imports_of(path, root):
            where = f"{path.relative_to(root)}:{imp.line}"
            if _top(imp.target) == "pymodbus" and own not in PYMODBUS_LAYERS:
                found.append(f"{where}: {own} imports pymodbus (only wire and sim may)")
            if _top(imp.target) in ROS_PACKAGES and own != "ros":
                found.append(f"{where}: {own} imports {imp.target} (only the ROS side may)")
            target_layer = layer_of(imp.target)
            upward = target_layer is not None and (
                LAYER_ORDER[target_layer] > LAYER_ORDER[own]
                or (target_layer != own and {own, target_layer} == {"runtime", "sim"})
            )
            if upward:
                found.append(f"{where}: {own} imports {imp.target} (an upward arrow)")
    for bridge in BRIDGES:
        for path in sorted((root / bridge).rglob("*.py")):
            if path.stem in ROS_SIDE_BRIDGE_MODULES:
                continue
            for imp in imports_of(path, root):
                where = f"{path.relative_to(root)}:{imp.line}"
                if _top(imp.target) in ROS_PACKAGES or layer_of(imp.target) == "ros":
                    found.append(f"{where}: {path.stem} imports {imp.target} (ROS-free module)")
                if _top(imp.target) == "pymodbus" and path.stem != "sim":
                    found.append(f"{where}: {path.stem} imports pymodbus (only the wire may)")
                if (imp.target + ".").startswith("bridge_core.runtime.poller."):
                    found.append(f"{where}: {path.stem} imports the poller (read through reads)")
    return list(dict.fromkeys(found))  # one line per import statement and rule


def cycles(root: Path) -> list[list[str]]:
    """Import cycles among our own modules (run-time imports only)."""
    ours = ("bridge_core", *BRIDGES)
    graph: dict[str, set[str]] = {}
    for top in ours:
        for path in (root / top).rglob("*.py"):
            name = module_name(path, root)
            edges = graph.setdefault(name, set())
            for imp in imports_of(path, root):
                if not imp.type_only and _top(imp.target) in ours and imp.target != name:
                    edges.add(imp.target)
    modules = set(graph)
    found: list[list[str]] = []
    state: dict[str, int] = {}  # 1 on the stack, 2 done

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in modules:
                continue
            if state.get(nxt) == 1:
                found.append([*stack[stack.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for module in sorted(modules):
        if module not in state:
            visit(module, [])
    return found


def test_the_tree_keeps_the_import_rules() -> None:
    assert violations(ROOT) == []


def test_the_import_graph_has_no_cycle() -> None:
    assert cycles(ROOT) == []


def test_every_bridge_core_module_is_in_a_layer() -> None:
    flat = [p.name for p in (ROOT / "bridge_core").glob("*.py") if p.name != "__init__.py"]
    assert flat == [], "a bridge_core module outside the layers"


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for bridge in BRIDGES:
        (tmp_path / bridge).mkdir(exist_ok=True)
    return tmp_path


@pytest.mark.parametrize(
    ("files", "expected"),
    [
        ({"bridge_core/wire/channel.py": "import rclpy\n"}, "wire imports rclpy"),
        (
            {"bridge_core/runtime/poller.py": "from pymodbus.client import X\n"},
            "runtime imports pymodbus",
        ),
        ({"bridge_core/wire/codec.py": "from ..runtime import checks\n"}, "an upward arrow"),
        (
            {"bridge_core/runtime/goals.py": "from bridge_core.ros.node_base import B\n"},
            "an upward arrow",
        ),
        (
            {"r6_bridge/device.py": "from bridge_core.runtime.poller import read\n"},
            "imports the poller",
        ),
        ({"r6_bridge/registers.py": "from sensor_msgs.msg import JointState\n"}, "ROS-free module"),
        # a module the rule was never told about: every non-ROS-side module is found
        ({"motec_bridge/lifeguard.py": "import rclpy\n"}, "ROS-free module"),
        ({"xarm_bridge/new_job.py": "from bridge_core.ros import node_base\n"}, "ROS-free module"),
        ({"stepper_bridge/node_services.py": "import rclpy\n"}, None),
    ],
)
def test_a_broken_rule_is_found(
    tmp_path: Path, files: dict[str, str], expected: str | None
) -> None:
    found = violations(_tree(tmp_path, files))
    if expected is None:  # the ROS side may
        assert found == []
    else:
        assert len(found) == 1 and expected in found[0], found


def test_a_type_only_import_is_no_cycle_and_a_real_one_is(tmp_path: Path) -> None:
    root = _tree(
        tmp_path,
        {
            "bridge_core/ros/a.py": (
                "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import b\n"
            ),
            "bridge_core/ros/b.py": "from . import a\n",
        },
    )
    assert cycles(root) == []
    (root / "bridge_core/ros/a.py").write_text("from . import b\n")
    assert cycles(root) == [["bridge_core.ros.a", "bridge_core.ros.b", "bridge_core.ros.a"]]
