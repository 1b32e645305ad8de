#!/usr/bin/env python3
"""Make the project's console scripts reachable as ``ros2 run <package> <executable>``.

``ros2 run`` finds a package through the ament index (``share/ament_index/
resource_index/packages/<package>`` under a prefix on ``AMENT_PREFIX_PATH``) and runs
``<prefix>/lib/<package>/<executable>``. pip installs console scripts in ``bin/`` only,
so for every ``[project.scripts]`` entry of pyproject.toml (``name = "package.module:f"``)
this writes the package's index marker and a ``lib/<package>/<name>`` that execs the
``bin/`` script, under the venv's prefix. Idempotent; run by scripts/setup.sh.

    .venv/bin/python scripts/ament_index.py
"""

from __future__ import annotations

import os
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
INDEX = Path("share") / "ament_index" / "resource_index" / "packages"


def executables(pyproject: Path) -> dict[str, list[str]]:
    """package -> its console scripts, from ``[project.scripts]``."""
    scripts = tomllib.loads(pyproject.read_text())["project"]["scripts"]
    packages: dict[str, list[str]] = {}
    for name, target in scripts.items():
        packages.setdefault(target.split(".", 1)[0], []).append(name)
    return packages


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
    return written


def main() -> None:
    written = install(Path(sys.prefix), executables(ROOT / "pyproject.toml"))
    print(f"ament index: {len(written)} files under {sys.prefix}", file=sys.stderr)
    if not os.environ.get("AMENT_PREFIX_PATH"):
        print(f"(ros2 run needs AMENT_PREFIX_PATH={sys.prefix})", file=sys.stderr)


if __name__ == "__main__":
    main()
