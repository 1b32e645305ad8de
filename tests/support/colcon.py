"""The colcon build of tests/core/test_colcon_build.py, started when the session begins.

Building ``msg_defs`` (C and C++ type support of 6 messages, 28 services and 7 actions)
takes minutes of compiler time. The build reuses the venv's msg_defs build directory
(``reuse_msg_defs_build``) when set-up left one, where it compiled the C type supports and
the Python bindings, so it compiles the C++ type supports only (~50 s on 2 idle cores, as
a unity build); when set-up installed a wheel it had built before (scripts/setup.sh), the
build is the whole package (~160 CPU-s). Either way colcon's install of msg_defs is kept
per machine under a hash of its inputs (``msg_defs_key``), and a later build of the same
msg_defs (a fresh clone's) copies it and builds the Python packages only (~15 s). It
starts at the lowest CPU priority (nice 19) when the tests are collected; the colcon
tests, scheduled last (each alone in xdist's schedule, tests/conftest.py), wait for it at
normal priority. Scheduled early, their worker waited ~135 s for it with 4 workers.

Under pytest-xdist the controller process starts it once the workers have collected the
colcon tests (tests/conftest.py) and tells the workers its workspace; the worker that runs
the tests waits for the exit code the build leaves in that workspace (``colcon.rc``).
Without xdist the test process starts it when its collection is done.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
import tempfile
import time
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


CMAKE_ARGS = (
    # The whole package, C++ type supports included, whatever the reused build directory
    # was configured with.
    "-DMSG_DEFS_PYTHON_ONLY=OFF",
    # As set-up builds msg_defs (scripts/setup.sh): the C++ type supports' generated
    # sources a few per compiler run (~70 CPU-s instead of ~130 on 2 cores). The install
    # is the same files.
    "-DCMAKE_UNITY_BUILD=ON",
)

# A colcon install of msg_defs kept per machine, under a hash of everything it is built
# from (as set-up keeps msg_defs's wheel, scripts/setup.sh): a fresh clone of the same
# msg_defs copies it into its workspace and builds the Python packages only. Building it
# is ~160 CPU-s of compilers and rosidl's generators, which a fresh clone's suite (CPU-bound
# on 2 cores) paid in ~20 s of its time. COLCON_MSG_DEFS_CACHE= (empty) builds it anyway.
MSG_DEFS_CACHE_ENV = "COLCON_MSG_DEFS_CACHE"


def msg_defs_cache_root() -> Path | None:
    """Where cached msg_defs installs are kept (None: not kept)."""
    configured = os.environ.get(MSG_DEFS_CACHE_ENV)
    if configured is not None:
        return Path(configured) if configured else None
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "modbus-ros-bridges" / "colcon-msg_defs"


def msg_defs_key() -> str:
    """A hash of what a colcon build of msg_defs depends on: its files (tracked or not,
    its build directory aside), ``CMAKE_ARGS``, the Python, and the venv's
    distributions (the ROS wheels and numpy it compiles against, colcon itself)."""
    digest = hashlib.sha256()
    source = ROOT / "msg_defs"
    for path in sorted(source.rglob("*")):
        relative = path.relative_to(source)
        if relative.parts[0] == "build" or not path.is_file():
            continue
        digest.update(f"{relative}\0".encode())
        digest.update(path.read_bytes())
    digest.update("\0".join(CMAKE_ARGS).encode())
    digest.update(f"{sys.version}\0{sysconfig.get_platform()}\0".encode())
    venv = sorted(
        f"{dist.metadata['Name']}=={dist.version}"
        for dist in importlib.metadata.distributions()
        if dist.metadata["Name"]
        and dist.metadata["Name"].lower().replace("_", "-")
        not in {"msg-defs", "modbus-ros-bridges"}
    )
    digest.update("\n".join(venv).encode())
    return digest.hexdigest()[:32]


class ColconBuild:
    """``colcon build`` of this checkout into a workspace, in the background: ``start()``
    starts it; a process that did not start it (an xdist worker, the controller's build)
    waits for it all the same."""

    def __init__(self, workspace: Path) -> None:
        self.workspace = workspace
        self.process: subprocess.Popen[bytes] | None = None

    @classmethod
    def new(cls) -> ColconBuild:
        """A build in a new temporary workspace, not started yet."""
        return cls(Path(tempfile.mkdtemp(prefix="colcon_ws_")))

    def start(self) -> None:
        cached = self.cached_msg_defs()
        if cached is not None:
            # This msg_defs, built by colcon before on this machine: copied as installed.
            shutil.copytree(cached, self.install / "msg_defs", symlinks=True)
        else:
            reuse_msg_defs_build(self.workspace / "build")
        colcon = [
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
            "--cmake-args",
            *CMAKE_ARGS,
            # Configure even when colcon's record of its last arguments matches: set-up's
            # pip build may have configured the reused directory since.
            "--cmake-force-configure",
        ]
        if cached is not None:
            # The Python packages only (colcon-core has no --packages-skip without
            # colcon-package-selection): msg_defs is found installed, as the copy holds
            # colcon's record of it.
            colcon[colcon.index("--base-paths") + 1] = str(ROOT / "ros")
        # The exit code is written when colcon ends (renamed into place: whole or absent).
        script = '"$@"; echo $? >"$RC.new" && mv "$RC.new" "$RC"'
        with self.output.open("wb") as out:
            self.process = subprocess.Popen(
                ["nice", "-n", "19", "sh", "-c", script, "colcon", *colcon],
                cwd=self.workspace,
                env={**venv_env(), "RC": str(self.rc_file)},
                stdout=out,
                stderr=subprocess.STDOUT,
                # Its own process group (reniced and killed whole), in the tests' session:
                # with the kernel's autogroup scheduling a session of its own would be a
                # CPU group of its own, given as much CPU as the tests whatever its nice.
                process_group=0,
            )
        self.group_file.write_text(str(self.process.pid))

    def cached_msg_defs(self) -> Path | None:
        """The cached install of this msg_defs (None: none, or no cache)."""
        root = msg_defs_cache_root()
        if root is None:
            return None
        cached = root / msg_defs_key() / "msg_defs"
        return cached if cached.is_dir() else None

    def keep_msg_defs(self) -> None:
        """After a build: its msg_defs install into the cache unless the cache holds it
        (the build copied it from there), whole or not at all (two runs may finish at once
        on one machine)."""
        root = msg_defs_cache_root()
        built = self.install / "msg_defs"
        if root is None or not built.is_dir():
            return
        key = root / msg_defs_key()
        if key.is_dir():
            return
        root.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".new.", dir=root))
        try:
            shutil.copytree(built, staging / "msg_defs", symlinks=True)
            staging.rename(key)
        except OSError:
            shutil.rmtree(staging, ignore_errors=True)

    @property
    def output(self) -> Path:
        return self.workspace / "colcon.out"

    @property
    def group_file(self) -> Path:
        """The build's process group id: written when it starts."""
        return self.workspace / "colcon.pgid"

    @property
    def rc_file(self) -> Path:
        return self.workspace / "colcon.rc"

    @property
    def install(self) -> Path:
        return self.workspace / "install"

    def wait(self, timeout_s: float = BUILD_TIMEOUT_S) -> tuple[int, str]:
        """Back to normal priority (a test waits now), then the exit code and output."""
        if not self.group_file.is_file():
            raise AssertionError(f"no colcon build was started in {self.workspace}")
        # Not allowed to raise it (not root), or already done: it goes on as it is.
        with contextlib.suppress(PermissionError, ProcessLookupError):
            os.setpriority(os.PRIO_PGRP, int(self.group_file.read_text()), 0)
        deadline = time.monotonic() + timeout_s
        while not self.rc_file.is_file():
            if self.process is not None and self.process.poll() is not None:
                break  # ended without writing its code (killed)
            if time.monotonic() > deadline:
                self.stop()
                raise TimeoutError(f"colcon build still running after {timeout_s} s")
            time.sleep(0.5)
        code = int(self.rc_file.read_text()) if self.rc_file.is_file() else -1
        if code == 0:
            self.keep_msg_defs()
        return code, self.output.read_text(errors="replace")

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(30)

    def remove(self) -> None:
        self.stop()
        shutil.rmtree(self.workspace, ignore_errors=True)


_build: ColconBuild | None = None
# The key of the workspace in an xdist worker's ``workerinput`` (tests/conftest.py).
WORKSPACE_INPUT = "colcon_workspace"


def session_build() -> ColconBuild:
    """This process's build (the test process's, or the xdist controller's), made (not
    started) on first use."""
    global _build
    if _build is None:
        _build = ColconBuild.new()
    return _build


def colcon_build(workerinput: dict[str, object] | None = None) -> ColconBuild:
    """The session's build: the controller's under xdist (its workspace in the worker's
    ``workerinput``), else this process's own, started now if it was not."""
    if workerinput is not None:
        return ColconBuild(Path(str(workerinput[WORKSPACE_INPUT])))
    build = session_build()
    if build.process is None:
        build.start()
    return build


def remove_colcon_build() -> None:
    global _build
    if _build is not None:
        _build.remove()
        _build = None
