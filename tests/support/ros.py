"""ROS test harness: bridge nodes in their own processes, an rclpy client in this one.

The client is what ``ros2 topic echo`` / ``ros2 service call`` do underneath (there is no
ros2 CLI here). Every wait is on a condition with a timeout; nothing sleeps blindly.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

ROOT = Path(__file__).resolve().parents[2]
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


def wait_for(predicate: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


class Client:
    """An rclpy node spinning on its own thread, collecting messages per topic."""

    def __init__(self, name: str = "test_client") -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.messages: dict[str, list[tuple[float, Any]]] = {}
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # shutting down
                return

    def subscribe(
        self, msg_type: Any, topic: str, qos: QoSProfile | int = 10, raw: bool = False
    ) -> None:
        self.messages.setdefault(topic, [])

        def store(msg: Any) -> None:
            with self._lock:
                self.messages[topic].append((time.monotonic(), msg))

        self.node.create_subscription(msg_type, topic, store, qos, raw=raw)

    def received(self, topic: str, since: float = 0.0) -> list[Any]:
        with self._lock:
            return [m for t, m in self.messages.get(topic, []) if t >= since]

    def last(self, topic: str) -> Any:
        got = self.received(topic)
        return got[-1] if got else None

    def wait_message(
        self,
        topic: str,
        predicate: Callable[[Any], bool] = lambda m: True,
        timeout: float = 15.0,
        since: float = 0.0,
    ) -> Any:
        def find() -> Any:
            for msg in reversed(self.received(topic, since)):
                if predicate(msg):
                    return msg
            return None

        return wait_for(find, timeout, f"a matching message on {topic}")

    def call(self, srv_type: Any, name: str, request: Any, timeout: float = 15.0) -> Any:
        client = self.node.create_client(srv_type, name)
        try:
            wait_for(lambda: client.service_is_ready(), timeout, f"service {name}")
            future = client.call_async(request)
            wait_for(future.done, timeout, f"reply from {name}")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(5)


@contextmanager
def ros_client(name: str = "test_client") -> Iterator[Client]:
    client = Client(name)
    try:
        yield client
    finally:
        client.close()


def ros_args(params: dict[str, Any]) -> list[str]:
    args = ["--ros-args"]
    for key, value in params.items():
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, list | tuple):
            text = (
                "["
                + ",".join(repr(float(v)) if isinstance(v, float) else str(v) for v in value)
                + "]"
            )
        else:
            text = str(value)
        args += ["-p", f"{key}:={text}"]
    return args


@contextmanager
def node_process(
    module: str, params: dict[str, Any], log_dir: Path, extra: Sequence[str] = ()
) -> Iterator[subprocess.Popen[bytes]]:
    """Run ``python -m module --ros-args ...`` in its own process; stop it with SIGINT."""
    log = (log_dir / f"{module.replace('.', '_')}.log").open("wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", module, *ros_args(params), *extra],
        cwd=ROOT,
        env=dict(os.environ),
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        log.close()
