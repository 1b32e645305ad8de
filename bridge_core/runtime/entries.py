"""Where the bridges' declared entries are found: pyproject.toml in a checkout, else the
installed entry points (plain Python, so ROS-free listings can use it as the demo does).

A name declared twice (a colcon install sourced over the editable install) is the same
device: the first on the path wins, as for imports.

``bridge_packages()`` is the one list of bridges: one per entry of ``BRIDGES_GROUP`` (each
bridge's nodes as data), used by the tests and scripts that go over every bridge, so a new
bridge joins them by its entry point alone. Standard library only: scripts/ament_index.py
imports it in a colcon build, before bridge_core is installed.
"""

from __future__ import annotations

import tomllib
from importlib.metadata import entry_points
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the checkout (or site-packages) holding us
PROJECT_NAME = "modbus-ros-bridges"
BRIDGES_GROUP = "modbus_bridges.interface"  # one entry per bridge: its nodes as data
DEMO_GROUP = "modbus_bridges.demo"  # a bridge's entry in bridge_demo (the demo cell's bridges)


def entry_table(group: str, root: Path = ROOT) -> dict[str, str]:
    """Each entry of ``group`` by name (``r6``, ...): its ``module:attr``, in declared order."""
    pyproject = root / "pyproject.toml"
    if pyproject.is_file():
        with pyproject.open("rb") as f:
            project = tomllib.load(f).get("project", {})
        if project.get("name") == PROJECT_NAME:
            table = project.get("entry-points", {}).get(group, {})
            return {str(name): str(spec) for name, spec in table.items()}
    found: dict[str, str] = {}
    for entry in entry_points(group=group):
        found.setdefault(entry.name, entry.value)
    return found


def entry_specs(group: str, root: Path = ROOT) -> list[str]:
    """The ``module:attr`` of every entry of ``group``."""
    return list(entry_table(group, root).values())


def package_of(spec: str) -> str:
    """The package of an entry: ``"r6_bridge.interface:NODES"`` -> ``"r6_bridge"``."""
    return spec.partition(":")[0].split(".")[0]


def bridge_packages(root: Path = ROOT) -> dict[str, str]:
    """Every bridge, in declared order: its name (``r6``) -> its package (``r6_bridge``)."""
    return {name: package_of(spec) for name, spec in entry_table(BRIDGES_GROUP, root).items()}
