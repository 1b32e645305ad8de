"""The repository is a ROS 2 workspace package set that colcon builds.

colcon comes from PyPI (the ``dev`` extra) and builds against the ROS 2 wheels in the venv:
``msg_defs`` as ament_cmake (its CMakeLists.txt finds the wheels itself), the five Python
packages as ament_python from ``ros/<package>/``. The build goes to a temp workspace; the
tests then source its ``setup.bash`` as a user would and check what ``ros2 run`` and
``ros2 launch`` resolve there, and that the installed bridge serves its simulator.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tomllib
import xml.etree.ElementTree as ElementTree
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

from bridge_core.runtime.entries import bridge_packages
from bridge_core.wire.ports import free_port

from ..support.colcon import BUILD_TIMEOUT_S, colcon_build, venv_env
from ..support.ros import ROOT, ros_client, unique_namespace, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.timeout(BUILD_TIMEOUT_S + 300)]
BRIDGES = set(bridge_packages().values())
PACKAGES = {"msg_defs", "bridge_core", *BRIDGES}
CPP_TYPESUPPORTS = (
    "rosidl_typesupport_cpp",
    "rosidl_typesupport_fastrtps_cpp",
    "rosidl_typesupport_introspection_cpp",
)


def ament_layout() -> ModuleType:
    """scripts/ament_index.py: the table of what each package installs."""
    spec = importlib.util.spec_from_file_location(
        "ament_index", ROOT / "scripts" / "ament_index.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def install(pytestconfig: pytest.Config) -> Path:
    """The session's colcon build (started at collection, at low priority), finished."""
    build = colcon_build(getattr(pytestconfig, "workerinput", None))
    code, output = build.wait()
    assert code == 0, output[-4000:]
    install = build.install
    for package in PACKAGES:  # colcon's own record of each package it installed
        assert (install / package / "share" / "colcon-core" / "packages" / package).is_file()
    # The whole interface package, though it reuses the venv's C/Python-only build dir.
    for typesupport in CPP_TYPESUPPORTS:
        library = install / "msg_defs" / "lib" / f"libmsg_defs__{typesupport}.so"
        assert library.is_file(), f"{library} missing: msg_defs built without C++"
    return install


@pytest.fixture(scope="module")
def sourced(install: Path) -> dict[str, str]:
    """The environment after ``source install/setup.bash``."""
    result = subprocess.run(
        ["bash", "-c", 'source "$0/setup.bash" && env -0', str(install)],
        env=venv_env(),
        capture_output=True,
        check=True,
        timeout=60,
    )
    pairs = (entry.split(b"=", 1) for entry in result.stdout.split(b"\0") if b"=" in entry)
    return {key.decode(): value.decode() for key, value in pairs}


def test_every_python_package_has_a_manifest_that_matches_pyproject() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    layout = ament_layout()
    assert set(layout.SHARE_FILES) == PACKAGES - {"msg_defs"}
    for package in layout.SHARE_FILES:
        manifest = ElementTree.parse(ROOT / "ros" / package / "package.xml").getroot()
        assert manifest.findtext("name") == package
        assert manifest.findtext("version") == project["version"], package
        assert manifest.findtext("export/build_type") == "ament_python", package
        depends = {element.text for element in manifest.iter("exec_depend")}
        if package in BRIDGES:
            assert {"bridge_core", "msg_defs", "rclpy"} <= depends, package
        if any(str(file).endswith(".launch.py") for file in layout.SHARE_FILES[package]):
            assert {"launch", "launch_ros"} <= depends, package  # what its launch files import
        # The package directory in ros/<package>/ is the repository's own, not a copy.
        assert (ROOT / "ros" / package / package).resolve() == ROOT / package
        for file in layout.SHARE_FILES[package]:
            assert (ROOT / file).is_file(), file


def test_colcon_installs_what_ros2_run_and_ros2_launch_resolve(
    install: Path, sourced: dict[str, str], tmp_path: Path
) -> None:
    layout = ament_layout()
    probe = """
import importlib, json, sys
from ament_index_python.packages import get_package_prefix
packages = sys.argv[1:]
print(json.dumps({
    "prefix": {p: get_package_prefix(p) for p in packages},
    "module": {p: importlib.import_module(p).__file__ for p in packages},
}))
"""
    result = subprocess.run(
        [sys.executable, "-c", probe, *sorted(PACKAGES)],
        cwd=tmp_path,  # not the checkout: ``python -c`` imports from its working directory
        env=sourced,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    found = json.loads(result.stdout)
    for package in PACKAGES:
        # The workspace's own build, not the venv's editable install or pip-built msg_defs.
        assert Path(found["prefix"][package]) == install / package
        assert Path(found["module"][package]).is_relative_to(install / package), package
    for package, names in layout.executables().items():
        for name in names:
            executable = install / package / "lib" / package / name
            assert os.access(executable, os.X_OK), executable
    for package, files in layout.SHARE_FILES.items():
        for file in files:
            assert (install / package / "share" / package / file).is_file(), (package, file)


@pytest.fixture
def installed_r6_sim(install: Path, sourced: dict[str, str], tmp_path: Path) -> Iterator[int]:
    port = free_port()
    with (tmp_path / "r6_sim.log").open("wb") as log:
        sim = subprocess.Popen(
            [str(install / "r6_bridge" / "lib" / "r6_bridge" / "r6_sim"), "--port", str(port)],
            cwd=tmp_path,
            env=sourced,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            yield port
        finally:
            sim.terminate()
            sim.wait(10)


def test_the_installed_bridge_serves_its_simulator_with_the_installed_config(
    install: Path, sourced: dict[str, str], installed_r6_sim: int, tmp_path: Path
) -> None:
    from sensor_msgs.msg import JointState

    share = install / "r6_bridge" / "share" / "r6_bridge"
    namespace = unique_namespace("colcon")
    with ros_client() as client, (tmp_path / "r6_bridge.log").open("wb") as log:
        client.subscribe(JointState, f"{namespace}/joint_states")
        bridge = subprocess.Popen(
            [
                str(install / "r6_bridge" / "lib" / "r6_bridge" / "r6_bridge"),
                "--ros-args",
                "--params-file",
                str(share / "config" / "r6.yaml"),
                "-p",
                f"port:={installed_r6_sim}",
                "-r",
                f"__ns:={namespace}",
            ],
            cwd=tmp_path,
            env=sourced,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            try:
                msg = client.wait_message(f"{namespace}/joint_states", timeout=60)
            except AssertionError as err:  # what the bridge said
                raise AssertionError(f"{err}\n{(tmp_path / 'r6_bridge.log').read_text()}") from None
            assert len(msg.name) == len(msg.position) > 0
            assert bridge.poll() is None
        finally:
            bridge.send_signal(2)  # SIGINT, as Ctrl-C
            wait_for(lambda: bridge.poll() is not None, 30, "the bridge to exit")
    assert bridge.returncode == 0, (tmp_path / "r6_bridge.log").read_text()
