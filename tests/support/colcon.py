"""The colcon build of tests/test_colcon_build.py, started when the session begins.

Building ``msg_defs`` (C and C++ type support of 6 messages, 28 services and 7 actions)
takes minutes of compiler time. The build reuses the venv's msg_defs build directory
(``reuse_msg_defs_build``), where set-up compiled the C type supports and the Python
bindings, so it compiles the C++ type supports only (~50 s on 2 idle cores, as a unity
build). The session starts it at the lowest CPU priority (nice 19) as soon as the colcon
tests are collected, so it uses the CPU the other tests leave idle (they mostly wait on
sockets, ptys and ROS discovery) without slowing them; the colcon tests, near the end of
the run, wait for it at normal priority. Under xdist the worker that takes the colcon
tests runs them first (tests/conftest.py): it starts the build and waits for it at once.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from .ros import ROOT

# The whole msg_defs from scratch (no venv build to reuse): ~3.5 min on 2 idle cores,
# ~7 min beside two CPU burners.
BUILD_TIMEOUT_S = 1500


def venv_env() -> dict[str, str]:
    """This venv activated, no ROS workspace sourced: where a user runs ``colcon build``."""
    env = {
        key: value
        for key, value in os.environ.items()
        if key not in {"AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH", "COLCON_PREFIX_PATH"}
    }
    env["VIRTUAL_ENV"] = sys.prefix
    # colcon's own make flags are -jN -lN (N = cores): beside other busy processes the load
    # limit leaves make one job at a time, and msg_defs takes twice as long.
    env["MAKEFLAGS"] = f"-j{os.cpu_count() or 2}"
    env["PATH"] = f"{Path(sys.prefix) / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return env


# Where scripts/setup.sh keeps msg_defs's CMake build directory (C type supports and Python).
VENV_MSG_DEFS_BUILD = Path(sys.prefix) / "build" / "msg_defs"


def reuse_msg_defs_build(build_base: Path) -> bool:
    """Let colcon build msg_defs in the venv's build directory (a link to it as the
    workspace's ``build/msg_defs``), so it compiles only what the venv build left out (the
    C++ type supports) and nothing twice. CMake resolves the link (the cache records the
    real path). False, and a build from scratch, when set-up left no such directory."""
    if not (VENV_MSG_DEFS_BUILD / "CMakeCache.txt").is_file():
        return False
    build_base.mkdir(parents=True, exist_ok=True)
    (build_base / "msg_defs").symlink_to(VENV_MSG_DEFS_BUILD, target_is_directory=True)
    return True


class ColconBuild:
    """``colcon build`` of this checkout into a temporary workspace, in the background."""

    def __init__(self) -> None:
        self.workspace = Path(tempfile.mkdtemp(prefix="colcon_ws_"))
        self.output = self.workspace / "colcon.out"
        reuse_msg_defs_build(self.workspace / "build")
        with self.output.open("wb") as out:
            self.process = subprocess.Popen(
                [
                    "nice",
                    "-n",
                    "19",
                    str(Path(sys.prefix) / "bin" / "colcon"),
                    "--log-base",
                    str(self.workspace / "log"),
                    "build",
                    "--base-paths",
                    str(ROOT),
                    "--build-base",
                    str(self.workspace / "build"),
                    "--install-base",
                    str(self.workspace / "install"),
                    # The whole package, C++ type supports included, whatever the reused
                    # build directory was configured with.
                    "--cmake-args",
                    "-DMSG_DEFS_PYTHON_ONLY=OFF",
                    # As set-up built the reused directory (scripts/setup.sh): the C++
                    # type supports' generated sources a few per compiler run (~70
                    # CPU-s instead of ~130 on 2 cores). The install is the same files.
                    "-DCMAKE_UNITY_BUILD=ON",
                    # Configure even when colcon's record of its last arguments matches:
                    # set-up's pip build may have configured the reused directory since.
                    "--cmake-force-configure",
                ],
                cwd=self.workspace,
                env=venv_env(),
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # its own process group: reniced and killed whole
            )

    @property
    def install(self) -> Path:
        return self.workspace / "install"

    def wait(self, timeout_s: float = BUILD_TIMEOUT_S) -> tuple[int, str]:
        """Back to normal priority (a test waits now), then the exit code and output."""
        # Not allowed to raise it (not root), or already done: it goes on as it is.
        with contextlib.suppress(PermissionError, ProcessLookupError):
            os.setpriority(os.PRIO_PGRP, self.process.pid, 0)
        try:
            code = self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.stop()
            raise
        return code, self.output.read_text(errors="replace")

    def stop(self) -> None:
        if self.process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(30)

    def remove(self) -> None:
        self.stop()
        shutil.rmtree(self.workspace, ignore_errors=True)


_build: ColconBuild | None = None


def colcon_build() -> ColconBuild:
    """The session's build, started now if the session did not start it."""
    global _build
    if _build is None:
        _build = ColconBuild()
    return _build


def remove_colcon_build() -> None:
    global _build
    if _build is not None:
        _build.remove()
        _build = None
