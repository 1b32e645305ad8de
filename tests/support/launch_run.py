"""Evaluate a launch file with the tests' own ``launch`` / ``launch_ros`` stand-ins
(tests/support/launch_standin; the real ones are not among the PyPI wheels) and start its
nodes the way ``ros2 launch`` does: each dict of parameters becomes a params file after the
files before it, the namespace a remap."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml  # type: ignore[import-untyped]

from . import forkserver
from .ros import ROOT, interrupt

STANDIN = Path(__file__).resolve().parent / "launch_standin"


@dataclass
class LaunchedNode:
    """One ``Node`` / ``LifecycleNode`` of a launch file, its substitutions performed."""

    package: str
    executable: str
    namespace: str
    parameters: list[str | dict[str, Any]]
    lifecycle: bool
    name: str | None = None


@dataclass
class Launch:
    arguments: dict[str, Any]  # name -> DeclareLaunchArgument
    nodes: list[LaunchedNode] = field(default_factory=list)
    processes: list[list[Any]] = field(default_factory=list)


class MissingArgument(Exception):
    """A launch argument without a default was not given (``ros2 launch`` refuses it)."""


def _load(path: Path) -> tuple[Any, Any]:
    """The launch file as a module, and the stand-in ``launch`` package it imported."""
    sys.path.insert(0, str(STANDIN))
    saved = {name: sys.modules.pop(name) for name in list(sys.modules) if _ours(name)}
    try:
        spec = importlib.util.spec_from_file_location(f"launch_file_{path.stem}", path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module, importlib.import_module("launch")
    finally:
        for name in [name for name in sys.modules if _ours(name)]:
            del sys.modules[name]
        sys.path.remove(str(STANDIN))
        sys.modules.update(saved)


def _ours(name: str) -> bool:
    return name.split(".")[0] in ("launch", "launch_ros")


def evaluate(path: Path, given: dict[str, str]) -> Launch:
    """The launch file's arguments and what it would start with ``given`` arguments."""
    module, launch = _load(path)
    description = module.generate_launch_description()
    context = launch.LaunchContext(given)
    result = Launch(arguments={})
    entities = list(description.entities)
    while entities:
        entity = entities.pop(0)
        kind = type(entity).__name__
        if kind == "DeclareLaunchArgument":
            result.arguments[entity.name] = entity
            if entity.name not in given:
                if entity.default_value is None:
                    raise MissingArgument(entity.name)
                context.launch_configurations[entity.name] = str(entity.default_value)
        elif kind == "OpaqueFunction":
            entities[:0] = list(entity.function(context) or [])
        elif kind in ("Node", "LifecycleNode"):
            result.nodes.append(
                LaunchedNode(
                    package=_performed(entity.package, context),
                    executable=_performed(entity.executable, context),
                    namespace=_performed(entity.namespace, context),
                    parameters=[_parameters(p, context) for p in entity.parameters],
                    lifecycle=entity.lifecycle,
                    name=None if entity.name is None else _performed(entity.name, context),
                )
            )
        elif kind == "ExecuteProcess":
            result.processes.append([_performed(part, context) for part in entity.cmd])
        else:
            raise AssertionError(f"{path.name}: the stand-in does not know {kind}")
    return result


def _parameters(value: Any, context: Any) -> Any:
    """A params file path, or a dict whose substituted values are read as YAML (what
    launch_ros does with a substitution of no declared type: "502" is the integer 502)."""
    if not isinstance(value, dict):
        return _performed(value, context)
    return {
        key: yaml.safe_load(item.perform(context)) if hasattr(item, "perform") else item
        for key, item in value.items()
    }


def _performed(value: Any, context: Any) -> Any:
    if isinstance(value, dict):
        return {key: _performed(item, context) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_performed(item, context) for item in value]
    if hasattr(value, "perform"):
        return value.perform(context)
    return value


def node_module(executable: str) -> str:
    """The module ``python -m`` runs for a console script (``r6_bridge.node``)."""
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    return str(scripts[executable]).split(":")[0]


@contextmanager
def started(node: LaunchedNode, namespace: str, work: Path) -> Iterator[forkserver.Process]:
    """The node's process as ``ros2 launch`` starts it, under ``namespace`` (which replaces
    the launch file's), output in ``work/<executable>.log``."""
    args: list[str] = ["--ros-args"]
    for index, parameters in enumerate(node.parameters):
        if isinstance(parameters, dict):  # launch_ros writes a dict to a params file
            file = work / f"{node.executable}_{index}.yaml"
            file.write_text(yaml.safe_dump({"/**": {"ros__parameters": parameters}}))
            parameters = str(file)
        args += ["--params-file", str(parameters)]
    if namespace:
        args += ["-r", f"__ns:={namespace}"]
    if node.name:
        args += ["-r", f"__node:={node.name}"]
    log = (work / f"{node.executable}.log").open("wb")
    proc = forkserver.python_module(
        node_module(node.executable), args, stdout=log, stderr=subprocess.STDOUT
    )
    try:
        yield proc
    finally:
        interrupt(proc, 10)
        log.close()
