"""Bridge and simulator processes forked from a server that has imported them already.

A test that starts a bridge node runs ``python -m r6_bridge.node --ros-args ...`` in a
process of its own, as a user does. Most of such a process's start is the import of
rclpy, numpy, the message packages, pymodbus and the register maps: ~0.75 CPU-s each, and
the suite starts some 400 of them. This module's servers (one per test process for the
nodes, one for the simulators, started on first use) import those modules once, then fork
a child per request; the child sets its argv, environment, working directory and standard
streams, drops the module it is asked to run from ``sys.modules`` and runs it with
``runpy`` as ``python -m`` does. Everything after
the import is the real program in a process of its own: its own rclpy context, DDS
participant, sockets, signals and exit code.

What the fork changes, and why that is safe here:

- Threads: at fork the server has its main thread (in ``select``), OpenBLAS's thread pool
  (numpy's; OpenBLAS re-creates it after a fork) and LTTng-UST's two listener threads
  (rcl's tracing; with no session daemon they only wait). rclpy is imported, not
  initialised: DDS, rcl's logging and the executor start in the child. The interface
  types' C type supports are loaded (libraries of generated code, no threads, no DDS).
- The child's exit is the interpreter's own (atexit, non-daemon threads joined, streams
  flushed); an uncaught KeyboardInterrupt ends it by SIGINT as ``python -m`` does.
- The test side gets a ``ForkedProcess`` with ``Popen``'s ``pid``, ``poll``, ``wait``,
  ``send_signal``, ``terminate``, ``kill`` and ``returncode``; the server, the child's
  parent, sends the exit status. A child whose test process is gone is SIGKILLed.

Any module can be run so (``PRELOAD`` is what each server imports beforehand).
``BRIDGE_TESTS_FORKSERVER=0`` starts every process with ``subprocess.Popen`` instead (an
A/B of the two, or a suspicion about the fork); tests/support_tests/test_forkserver.py compares
the two. The demo, ``bridge_record`` and the colcon install are still started as typed.
"""

from __future__ import annotations

import atexit
import contextlib
import importlib
import inspect
import json
import os
import runpy
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bridge_core.runtime.entries import bridge_packages

ROOT = Path(__file__).resolve().parents[2]
# What each server imports before it forks: the bridges' nodes (they bring rclpy, the
# message packages, numpy, pymodbus and the register maps), and apart from them the
# simulators, which do not use ROS: a simulator forked with rclpy loaded paid for it at its
# exit (Fast DDS's factory destructor sleeps 0.1 s; a stop took 0.2 s instead of 0.06 s).
BRIDGE_PACKAGES = tuple(bridge_packages().values())
PRELOAD = {
    "node": tuple(f"{package}.node" for package in BRIDGE_PACKAGES),
    "sim": tuple(f"{package}.sim" for package in BRIDGE_PACKAGES),
}


def preload_kind(module: str) -> str:
    """Which server forks ``module``: the simulators' or the nodes' (any other module)."""
    return "sim" if module in PRELOAD["sim"] else "node"


SERVER_START_S = 60.0  # a loaded machine: the imports take ~1.5 CPU-s
REQUEST_MAX = 1 << 20  # bytes of one request (argv and environment as JSON)
STREAMS = 3  # stdin, stdout, stderr: the descriptors a request passes
ENABLED = os.environ.get("BRIDGE_TESTS_FORKSERVER", "1") != "0"


class ForkedProcess:
    """A child of the fork server, with the part of ``subprocess.Popen`` the tests use."""

    def __init__(self, args: list[str], pid: int, status: socket.socket) -> None:
        self.args = args
        self.pid = pid
        self.returncode: int | None = None
        self._status = status  # the server writes the exit code here, then closes it
        self._lock = threading.Lock()

    def _read_status(self, timeout: float | None) -> bool:
        with self._lock:
            if self.returncode is not None:
                return True
            ready, _, _ = select.select([self._status], [], [], timeout)
            if not ready:
                return False
            data = b""
            while not data.endswith(b"\n"):
                chunk = self._status.recv(64)
                if not chunk:
                    raise RuntimeError(f"the fork server lost child {self.pid} ({self.args})")
                data += chunk
            self.returncode = int(data)
            self._status.close()
            return True

    def poll(self) -> int | None:
        self._read_status(0)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if not self._read_status(timeout):
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        assert self.returncode is not None
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class _Server:
    """One of this test process's fork servers (``kind``: a key of ``PRELOAD``): a child
    process and the socket it listens on."""

    def __init__(self, kind: str) -> None:
        self.dir = tempfile.TemporaryDirectory(prefix="forkserver-")
        self.path = str(Path(self.dir.name) / "socket")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.support.forkserver", self.path, kind],
            cwd=ROOT,
            stdin=subprocess.PIPE,  # its lifeline: the server ends when this process does
            stdout=subprocess.PIPE,
        )
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], SERVER_START_S)
        line = self.proc.stdout.readline() if ready else b""
        if line.strip() != b"ready":
            self.proc.kill()
            raise RuntimeError(f"the fork server did not start: {line!r}")
        atexit.register(self.close)

    def close(self) -> None:
        """End the server (its children are SIGKILLed) and reap it."""
        assert self.proc.stdin is not None
        with contextlib.suppress(OSError):
            self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)

    def spawn(
        self,
        module: str,
        args: Sequence[str],
        env: Mapping[str, str],
        cwd: Path,
        streams: Sequence[int],
        process_group: bool,
    ) -> ForkedProcess:
        request = {
            "module": module,
            "args": list(args),
            "env": dict(env),
            "cwd": str(cwd),
            "process_group": process_group,
        }
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        conn.connect(self.path)
        socket.send_fds(conn, [json.dumps(request).encode()], list(streams))
        reply = b""
        while not reply.endswith(b"\n"):
            chunk = conn.recv(64)
            if not chunk:
                raise RuntimeError(f"the fork server refused {module}")
            reply += chunk
        return ForkedProcess([sys.executable, "-m", module, *args], int(reply), conn)


Process = ForkedProcess | subprocess.Popen[bytes]
_servers: dict[str, _Server] = {}
_server_lock = threading.Lock()


def _the_server(kind: str) -> _Server:
    with _server_lock:
        server = _servers.get(kind)
        if server is None or server.proc.poll() is not None:
            server = _servers[kind] = _Server(kind)
        return server


def python_module(
    module: str,
    args: Sequence[str],
    *,
    stdout: int | Any = None,
    stderr: int | Any = None,
    env: Mapping[str, str] | None = None,
    cwd: Path = ROOT,
    process_group: bool = False,
) -> Process:
    """``python -m module args``: forked from the server, or ``Popen`` when it is off.

    ``stdout`` and ``stderr``: a file object, a descriptor, ``subprocess.STDOUT`` (stderr
    only) or None (this process's own). ``process_group``: a process group of its own.
    """
    if not ENABLED:
        return subprocess.Popen(
            [sys.executable, "-m", module, *args],
            cwd=cwd,
            env=dict(env if env is not None else os.environ),
            stdout=stdout,
            stderr=stderr,
            process_group=0 if process_group else None,
        )

    def descriptor(stream: int | Any, default: int) -> int:
        if stream is None:
            return default
        return stream if isinstance(stream, int) else int(stream.fileno())

    with open(os.devnull, "rb") as null:
        out = descriptor(stdout, 1)
        err = out if stderr == subprocess.STDOUT else descriptor(stderr, 2)
        return _the_server(preload_kind(module)).spawn(
            module,
            args,
            env if env is not None else os.environ,
            cwd,
            (null.fileno(), out, err),
            process_group,
        )


def run_module(
    module: str,
    args: Sequence[str],
    timeout: float,
    *,
    env: Mapping[str, str] | None = None,
    cwd: Path = ROOT,
) -> subprocess.CompletedProcess[str]:
    """``subprocess.run([python, -m, module, *args], capture_output=True, text=True)``."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = python_module(module, args, stdout=out, stderr=err, env=env, cwd=cwd)
        try:
            code = proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
            raise
        out.seek(0)
        err.seek(0)
        return subprocess.CompletedProcess(
            proc.args, code, out.read().decode(errors="replace"), err.read().decode()
        )


# --- the server ---------------------------------------------------------------------------


# The interface packages whose messages, services and actions a node creates (besides those
# the preloaded modules import): their type supports are loaded before the fork as well.
INTERFACE_PACKAGES = ("msg_defs", "service_msgs", "type_description_interfaces")


def _load_type_supports() -> None:
    """What every node did again after its fork, done once here: import each interface
    module and load its types' C type support (rclpy does it at a type's first use, with
    rosidl's parser), and fill ``inspect``'s module cache that rclpy's logger reads at its
    first line. A stepper node's first 3 s: 0.33-0.36 CPU-s after the fork, 0.25-0.27 so."""
    from rclpy.type_support import check_for_type_support

    packages = {name.split(".")[0] for name in sys.modules if name.endswith((".msg", ".srv"))}
    for package in sorted(packages.union(INTERFACE_PACKAGES)):
        for kind in ("msg", "srv", "action"):
            try:
                module = importlib.import_module(f"{package}.{kind}")
            except ImportError:
                continue
            for value in vars(module).values():
                if isinstance(value, type) and hasattr(value, "__import_type_support__"):
                    check_for_type_support(value)
    inspect.getmodule(inspect.currentframe())


def _serve(path: str, kind: str) -> dict[str, Any] | None:
    """Accept requests and fork; in a child, return its request (None: the server ends)."""
    for name in PRELOAD[kind]:
        importlib.import_module(name)
    if kind == "node":
        _load_type_supports()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(64)
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    children: dict[int, socket.socket] = {}  # pid: the connection its status goes to
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    lifeline = sys.stdin.fileno()
    while True:
        watched = [listener, wake_r, lifeline, *children.values()]
        ready, _, _ = select.select(watched, [], [])
        if lifeline in ready and not os.read(lifeline, 4096):
            for pid in children:  # the test process is gone: so are its children
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            return None
        if wake_r in ready:
            os.read(wake_r, 4096)
        for pid, conn in list(children.items()):
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                with contextlib.suppress(OSError):
                    conn.sendall(b"%d\n" % os.waitstatus_to_exitcode(status))
                conn.close()
                del children[pid]
            elif conn in ready:  # the test closed its end before the child ended
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        if listener not in ready:
            continue
        conn, _ = listener.accept()
        message, fds, _, _ = socket.recv_fds(conn, REQUEST_MAX, STREAMS)
        request = json.loads(message)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            signal.set_wakeup_fd(-1)
            signal.signal(signal.SIGCHLD, signal.SIG_DFL)
            for stream, fd in enumerate(fds):
                os.dup2(fd, stream)
            for fd in (*fds, wake_r, wake_w):
                os.close(fd)
            listener.close()
            conn.close()
            for other in children.values():
                other.close()
            return dict(request)
        if request["process_group"]:
            # Here as well as in the child, so the group exists when the pid is sent
            # whichever runs first (Popen's is made before its exec).
            with contextlib.suppress(OSError):
                os.setpgid(pid, pid)
        for fd in fds:
            os.close(fd)
        conn.sendall(b"%d\n" % pid)
        children[pid] = conn


def _run(request: dict[str, Any]) -> None:
    """In the child: become ``python -m module args`` and run it."""
    if request["process_group"]:
        os.setpgid(0, 0)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    module = request["module"]
    sys.argv = [module, *request["args"]]
    # Run afresh as __main__, as python -m does (runpy warns about a module already
    # imported, and its import-time state must be this process's own).
    sys.modules.pop(module, None)
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    _request = _serve(sys.argv[1], sys.argv[2])
    if _request is not None:
        _run(_request)
