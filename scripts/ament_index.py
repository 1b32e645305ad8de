#!/usr/bin/env python3
"""The project's ament layout: ``ros2 run`` / ``ros2 launch`` in the venv, and colcon.

``ros2 run`` finds a package through the ament index (``share/ament_index/
resource_index/packages/<package>`` under a prefix on ``AMENT_PREFIX_PATH``) and runs
``<prefix>/lib/<package>/<executable>``; ``ros2 launch <package> <file>`` looks in
``<prefix>/share/<package>/``. pip installs console scripts in ``bin/`` only, so run as a
script this writes, under the venv's prefix, for every ``[project.scripts]`` entry of
pyproject.toml (``name = "package.module:f"``): the package's index marker, a
``lib/<package>/<name>`` that execs the ``bin/`` script, and ``share/<package>/`` with the
package's manifest (``ros/<package>/package.xml``) and its launch and config files
(symlinks into this checkout). Idempotent; run by scripts/setup.sh.

    .venv/bin/python scripts/ament_index.py

The same table drives the colcon build: ``ros/<package>/setup.py`` calls
``setup_ament_python``, so a colcon install tree has the same ``lib/`` and ``share/``
layout. The launch files find their config at ``../config``, which holds in this checkout,
in the venv's ``share/<package>/`` and in a colcon install.
"""

from __future__ import annotations

import os
import sys
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # a colcon build runs this before bridge_core is installed
    sys.path.insert(1, str(ROOT))

from bridge_core.runtime.entries import DEMO_GROUP, bridge_packages, entry_table  # noqa: E402

PYPROJECT = ROOT / "pyproject.toml"
INDEX = Path("share") / "ament_index" / "resource_index" / "packages"
# ros/<package>/ holds each Python package's ROS manifest and colcon setup.py.
ROS_PACKAGES = ROOT / "ros"
CELL_LAUNCH = "launch/cell.launch.py"
# What a bridge installs besides its launch file and example config.
EXTRA_SHARE_FILES: dict[str, tuple[str, ...]] = {
    "modbus_bridge": ("config/devices/xarm.yaml", "config/devices/rtu_multidrop.yaml"),
}


def share_files() -> dict[str, tuple[str, ...]]:
    """What each package installs under share/<package>/ besides package.xml (paths from
    the repository root; kept in the same relative place): each bridge of
    ``bridge_packages()`` its launch file and example config, named as its entry
    (``launch/<name>.launch.py``, ``config/<name>.yaml``), and ``EXTRA_SHARE_FILES``;
    bridge_core the demo cell's launch file, which reads the config of every bridge in the
    demo (the ``modbus_bridges.demo`` entries), and those configs."""
    table = {
        "bridge_core": (
            CELL_LAUNCH,
            *(f"config/{name}.yaml" for name in entry_table(DEMO_GROUP, ROOT)),
        )
    }
    for name, package in bridge_packages(ROOT).items():
        own = (f"launch/{name}.launch.py", f"config/{name}.yaml")
        table[package] = (*own, *EXTRA_SHARE_FILES.get(package, ()))
    return table


SHARE_FILES = share_files()


def project() -> dict[str, Any]:
    """pyproject.toml's ``[project]`` table: the one source of names and versions."""
    table: dict[str, Any] = tomllib.loads(PYPROJECT.read_text())["project"]
    return table


def package_of(target: str) -> str:
    """``"r6_bridge.node:main"`` -> ``"r6_bridge"``."""
    return target.split(".", 1)[0].split(":", 1)[0]


def executables(pyproject: Path = PYPROJECT) -> dict[str, list[str]]:
    """package -> its console scripts, from ``[project.scripts]``."""
    scripts = tomllib.loads(pyproject.read_text())["project"]["scripts"]
    packages: dict[str, list[str]] = {}
    for name, target in scripts.items():
        packages.setdefault(package_of(target), []).append(name)
    return packages


def link(path: Path, target: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.is_symlink() or path.exists():
        path.unlink()
    path.symlink_to(target)


def install(prefix: Path, packages: dict[str, list[str]]) -> list[Path]:
    written: list[Path] = []
    for package, names in sorted(packages.items()):
        marker = prefix / INDEX / package
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text("")
        written.append(marker)
        for name in names:
            target = prefix / "lib" / package / name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(f'#!/bin/sh\nexec "{prefix / "bin" / name}" "$@"\n')
            target.chmod(0o755)
            written.append(target)
        share = prefix / "share" / package
        link(share / "package.xml", ROS_PACKAGES / package / "package.xml")
        written.append(share / "package.xml")
        for file in SHARE_FILES.get(package, ()):
            link(share / file, ROOT / file)
            written.append(share / file)
    return written


def setup_ament_python(package: str) -> None:
    """``setup()`` of one ament_python package, for ``ros/<package>/setup.py`` (colcon).

    The package directory, ``launch/`` and ``config/`` are symlinks in ``ros/<package>/``
    to the repository's own, so nothing is copied and pip and colcon build the same code.
    """
    from setuptools import setup

    meta = project()
    scripts = [
        f"{name} = {target}"
        for name, target in meta["scripts"].items()
        if package_of(target) == package
    ]
    entry_points: dict[str, list[str]] = {"console_scripts": scripts}
    for group, entries in meta.get("entry-points", {}).items():
        mine = [
            f"{name} = {target}"
            for name, target in entries.items()
            if package_of(target) == package
        ]
        if mine:
            entry_points[group] = mine
    data_files: dict[str, list[str]] = {
        str(INDEX): [f"resource/{package}"],
        f"share/{package}": ["package.xml"],
    }
    for file in SHARE_FILES[package]:
        data_files.setdefault(f"share/{package}/{Path(file).parent}", []).append(file)
    lib = f"$base/lib/{package}"  # where ros2 run looks, not bin/
    setup(
        name=package,
        version=meta["version"],
        description=meta["description"],
        packages=[package],
        package_data={package: ["py.typed"]},
        data_files=sorted(data_files.items()),
        install_requires=meta["dependencies"],
        zip_safe=False,
        entry_points=entry_points,
        options={"install": {"install_scripts": lib}, "develop": {"script_dir": lib}},
    )


def main() -> None:
    written = install(Path(sys.prefix), executables())
    print(f"ament index: {len(written)} files under {sys.prefix}", file=sys.stderr)
    if not os.environ.get("AMENT_PREFIX_PATH"):
        print(f"(ros2 run needs AMENT_PREFIX_PATH={sys.prefix})", file=sys.stderr)


if __name__ == "__main__":
    main()
