"""The launch files name only what exists.

``launch_ros`` is not among the PyPI wheels here, so a launch file cannot be run. Each one
is read as Python source instead: every ``Node(package=..., executable=...)`` must be a
console script of that package (and reachable as ``ros2 run`` under the venv prefix),
every ``ExecuteProcess`` command a console script of this project, every config file it
builds a path to must exist. (With a sourced ROS 2 Jazzy, ``ros2 launch`` runs them.)
"""

from __future__ import annotations

import ast
import dataclasses
import os
import sys
import tomllib
from pathlib import Path

import yaml  # type: ignore[import-untyped]

from bridge_core.runtime.entries import bridge_packages
from bridge_core.runtime.parameters import DeviceDefaults

from ..support.ros import ROOT

LAUNCH = ROOT / "launch"
BRIDGES = set(bridge_packages().values())


def console_scripts() -> dict[str, str]:
    """executable -> package, from pyproject's ``[project.scripts]``."""
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    return {name: target.split(".", 1)[0] for name, target in scripts.items()}


def calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == name
    ]


def keyword(call: ast.Call, name: str) -> ast.expr | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def test_every_launch_file_names_existing_packages_executables_and_files() -> None:
    scripts = console_scripts()
    files = sorted(LAUNCH.glob("*.launch.py"))
    assert {f.name for f in files} >= {
        *(f"{name}.launch.py" for name in bridge_packages()),
        "cell.launch.py",
    }
    launched: set[str] = set()
    for path in files:
        tree = ast.parse(path.read_text(), str(path))
        assert any(
            isinstance(node, ast.FunctionDef) and node.name == "generate_launch_description"
            for node in tree.body
        ), path
        for call in calls(tree, "Node") + calls(tree, "LifecycleNode"):
            package, executable = keyword(call, "package"), keyword(call, "executable")
            if isinstance(package, ast.Constant) and isinstance(executable, ast.Constant):
                assert scripts.get(str(executable.value)) == package.value, (path, ast.dump(call))
                launched.add(str(package.value))
        for call in calls(tree, "bridge"):  # cell.launch.py's helper: bridge(package, ...)
            package = call.args[0]
            config = call.args[2]
            assert isinstance(package, ast.Constant) and isinstance(config, ast.Constant)
            assert scripts.get(str(package.value)) == package.value, path
            assert (ROOT / "config" / str(config.value)).exists(), (path, config.value)
            launched.add(str(package.value))
        for call in calls(tree, "simulator"):  # simulator(package, executable, *args)
            package, executable = call.args[0], call.args[1]
            assert isinstance(package, ast.Constant) and isinstance(executable, ast.Constant)
            assert scripts.get(str(executable.value)) == package.value, (path, ast.dump(call))
            launched.add(str(package.value))
        for call in calls(tree, "ExecuteProcess"):
            command = keyword(call, "cmd")
            assert isinstance(command, ast.List)
            program = command.elts[0]
            if isinstance(program, ast.Constant):  # a console script on PATH
                assert program.value in scripts, (path, program.value)
            else:  # found like ros2 run finds it; names checked at the simulator() calls
                assert isinstance(program, ast.Call) and isinstance(program.func, ast.Name)
                assert program.func.id == "ExecutableInPackage", (path, ast.dump(program))
        for node in ast.walk(tree):  # "config" / "<name>.yaml" path joins
            if isinstance(node, ast.Constant) and str(node.value).endswith(".yaml"):
                assert (ROOT / "config" / str(node.value)).exists(), (path, node.value)
    assert launched >= BRIDGES
    for name in launched:  # what `ros2 run` / launch_ros resolve (scripts/ament_index.py)
        for script in (n for n, owner in scripts.items() if owner == name):
            resolved = Path(sys.prefix) / "lib" / name / script
            assert os.access(resolved, os.X_OK), resolved


def test_ros2_launch_finds_each_launch_file_and_its_config_in_the_venv_share() -> None:
    """``ros2 launch <package> <file>`` looks in ``share/<package>/`` (scripts/ament_index.py
    links them there), and the file's ``../config`` is then the package's share too."""
    for package in (*BRIDGES, "bridge_core"):
        share = Path(sys.prefix) / "share" / package
        launch_files = sorted(share.glob("launch/*.launch.py"))
        assert launch_files, share
        for launch_file in launch_files:
            tree = ast.parse(launch_file.read_text(), str(launch_file))
            configs = {
                str(node.value)
                for node in ast.walk(tree)
                if isinstance(node, ast.Constant) and str(node.value).endswith(".yaml")
            }
            assert configs, launch_file
            for config in configs:
                assert (share / "config" / config).is_file(), (package, config)


# Parameters whose defaults a modbus_bridge description gives (its link, unit, timing).
DESCRIBED = {field.name for field in dataclasses.fields(DeviceDefaults) if field.init} - {
    "device_name",
    "transport",
    "timeout_min_s",
    "stop_timeout_s",
    "pose_topic",
}


def test_modbus_launch_and_config_leave_the_link_to_the_description() -> None:
    """An RTU description declares no host / port (and a TCP one no serial_port): the
    node refuses an undeclared parameter, so config/modbus.yaml sets none of the
    description's settings and the launch file passes a link argument only when given
    (default "", added in a loop that skips empty values)."""
    config = yaml.safe_load((ROOT / "config" / "modbus.yaml").read_text())
    for block in config.values():
        assert not set(block["ros__parameters"]) & DESCRIBED, block
    tree = ast.parse((LAUNCH / "modbus.launch.py").read_text())
    link_arguments: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "LINK_ARGUMENTS" for t in node.targets
        ):
            assert isinstance(node.value, ast.Tuple)
            link_arguments = {str(ast.literal_eval(e)) for e in node.value.elts}
    assert link_arguments and link_arguments <= DESCRIBED, link_arguments
    for call in calls(tree, "DeclareLaunchArgument"):
        name, default = call.args[0], keyword(call, "default_value")
        if isinstance(name, ast.Constant):  # a fixed name: never a link setting
            assert name.value not in DESCRIBED, ast.dump(call)
        else:  # one of LINK_ARGUMENTS: empty unless given
            assert isinstance(default, ast.Constant) and default.value == "", ast.dump(call)
    for node in ast.walk(tree):  # no link parameter passed unconditionally
        if isinstance(node, ast.Dict):
            keys = {k.value for k in node.keys if isinstance(k, ast.Constant)}
            assert not keys & DESCRIBED, ast.dump(node)
    loops = [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.For)
        and isinstance(node.iter, ast.Name)
        and node.iter.id == "LINK_ARGUMENTS"
        and any(isinstance(inner, ast.If) for inner in node.body)
    ]
    assert loops, "link arguments must be added only when given"
