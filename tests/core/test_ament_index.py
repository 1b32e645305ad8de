"""``ros2 run <package> <executable>`` resolves every console script.

There is no ``ros2`` command here; ``ros2 run`` finds the package prefix through the
ament index and runs ``<prefix>/lib/<package>/<executable>``: the same lookup through
``ament_index_python``, then the executable itself.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from bridge_core.runtime.entries import bridge_packages

from ..support.ros import ROOT


def console_scripts() -> dict[str, list[str]]:
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    packages: dict[str, list[str]] = {}
    for name, target in scripts.items():
        packages.setdefault(target.split(".", 1)[0], []).append(name)
    return packages


def test_every_console_script_is_reachable_as_ros2_run(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AMENT_PREFIX_PATH", sys.prefix)
    from ament_index_python.packages import get_package_prefix

    packages = console_scripts()
    assert set(bridge_packages().values()) <= packages.keys()
    for package, names in packages.items():
        prefix = Path(get_package_prefix(package))
        for name in names:
            executable = prefix / "lib" / package / name
            assert os.access(executable, os.X_OK), executable
    # It is the bridge itself: a bad start-up value is its one-line refusal, exit 2.
    r6 = Path(get_package_prefix("r6_bridge")) / "lib" / "r6_bridge" / "r6_bridge"
    result = subprocess.run(
        [str(r6), "--ros-args", "-p", "port:=abc"],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ, AMENT_PREFIX_PATH=sys.prefix),
    )
    assert result.returncode == 2, result.stdout + result.stderr
    assert "port" in result.stderr and "abc" in result.stderr
