"""ROS test harness: bridge nodes in their own processes, an rclpy client in this one.

The client is what ``ros2 topic echo`` / ``ros2 service call`` do underneath (there is no
ros2 CLI here). Every wait is on a condition with a timeout; nothing sleeps blindly.
"""

from __future__ import annotations

import contextlib
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
from rcl_interfaces.msg import Log
from rclpy.action.client import ActionClient, ClientGoalHandle
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import try_shutdown
from unique_identifier_msgs.msg import UUID

from tests.support import forkserver

ROOT = Path(__file__).resolve().parents[2]
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
# Every wait is bounded by this unless a test says otherwise: long enough for a shared,
# loaded CI machine (a wait returns as soon as its condition holds).
WAIT_S = 20.0
LINK_RETRY_S = 0.2  # until_sent: how soon a call the link kept from going out is asked again
ROSOUT = "/rosout"
PROBE_S = 2.0  # how long one query waits for its answer before it is asked again


CLOCK_PAIR_S = 0.001  # the widest bracket of monotonic readings taken for one wall reading


def wall_minus_monotonic() -> float:
    """``time.time() - time.monotonic()``, the wall reading bracketed by two monotonic ones
    at most CLOCK_PAIR_S apart (read once each, a thread descheduled between the two would
    skew the offset by as long: ~0.4 s beside two CPU burners). The tightest of 100
    brackets if none is that tight."""
    best: tuple[float, float] | None = None
    for _ in range(100):
        before = time.monotonic()
        wall = time.time()
        after = time.monotonic()
        width, offset = after - before, wall - (before + after) / 2
        if best is None or width < best[0]:
            best = (width, offset)
        if width <= CLOCK_PAIR_S:
            break
    assert best is not None
    return best[1]


def wait_for(predicate: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


def wait_subscribed(publisher: Any, timeout: float = WAIT_S) -> None:
    """Until ``publisher`` has matched a subscription (a node's command topic)."""
    wait_for(
        lambda: publisher.get_subscription_count() > 0,
        timeout,
        f"a subscriber of {publisher.topic_name}",
    )


# Services that only read (parameters, lifecycle state): safe to ask twice (Client.call).
QUERY_SERVICES = frozenset(
    {"GetParameters", "ListParameters", "DescribeParameters", "GetParameterTypes", "GetState"}
)


class Client:
    """An rclpy node spinning on its own thread, collecting messages per topic."""

    def __init__(self, name: str = "test_client") -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.messages: dict[str, list[tuple[float, Any]]] = {}
        self.spin_errors: list[Exception] = []
        self._lock = threading.Lock()
        # Held by the spin thread for each spin_once; see ``between_spins``.
        self._spin_lock = threading.Lock()
        self._spin_allowed = threading.Event()
        self._spin_allowed.set()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while self.context.ok():
            self._spin_allowed.wait()
            try:
                with self._spin_lock:
                    self.executor.spin_once(timeout_sec=0.05)
            except Exception as err:
                if not self.context.ok():
                    return  # shutting down
                # E.g. a service or action client destroyed by a test thread while this
                # thread had it in its wait set (InvalidHandle): rclpy raises it here. The
                # client must go on spinning, or it hears nothing for the rest of its life.
                self.spin_errors.append(err)
                print(f"test client {self.node.get_name()}: {err!r}", file=sys.stderr)

    @contextmanager
    def between_spins(self) -> Iterator[None]:
        """Send an action request here, while the spin thread waits. rclpy's
        ``ActionClient`` registers a request's future only after the request is on the wire
        (``send_goal_async``, ``_get_result_async``, ``cancel_goal_async``): a response that
        the spin thread takes before that is dropped ("Ignoring unexpected goal response")
        and the future never completes. A loaded machine made that race likely: a goal
        response never came, in 60 s, on an idle run of the suite."""
        self._spin_allowed.clear()  # the spin thread stops at its next turn, not before
        try:
            with self._spin_lock:
                yield
        finally:
            self._spin_allowed.set()

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
        timeout: float = WAIT_S,
        since: float = 0.0,
    ) -> Any:
        def find() -> Any:
            for msg in reversed(self.received(topic, since)):
                if predicate(msg):
                    return msg
            return None

        return wait_for(find, timeout, f"a matching message on {topic}")

    def subscribe_log(self) -> None:
        """Collect ``/rosout`` (every node's log lines), for waits on what a node logged."""
        if ROSOUT not in self.messages:
            # Transient local like each node's /rosout publisher: a line logged before
            # this reader matched that (new) publisher is delivered on matching.
            self.subscribe(
                Log,
                ROSOUT,
                QoSProfile(
                    depth=1000,
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL,
                ),
            )

    def wait_log(self, logger: str, text: str, since: float = 0.0, timeout: float = WAIT_S) -> Any:
        """A ``/rosout`` line of a logger whose name contains ``logger`` and whose message
        contains ``text`` (call ``subscribe_log`` before the node starts)."""

        def find() -> Any:
            for msg in self.received(ROSOUT, since):
                if logger in msg.name and text in msg.msg:
                    return msg
            return None

        return wait_for(find, timeout, f"a log line of {logger} containing {text!r}")

    @contextlib.contextmanager
    def service_client(self, srv_type: Any, name: str, timeout: float = WAIT_S) -> Iterator[Any]:
        """A client already matched with its service (``call`` uses one per try): for a
        test that times a call from its request on, not from a fresh client's discovery."""
        client = self.node.create_client(srv_type, name)
        try:
            wait_for(client.service_is_ready, timeout, f"service {name}")
            yield client
        finally:
            self.node.destroy_client(client)

    def call(self, srv_type: Any, name: str, request: Any, timeout: float = WAIT_S) -> Any:
        """One service call from a fresh client.

        A query (``QUERY_SERVICES``: nothing changes on the node) whose reply does not come
        is asked once more: a fresh client may be "ready" before the server has matched
        its reply reader (a DDS discovery race that a loaded machine makes likely), and
        then the server's reply goes to no one. Commands are never sent twice.
        """
        attempts = 2 if srv_type.__name__ in QUERY_SERVICES else 1
        for attempt in range(attempts):
            with self.service_client(srv_type, name, timeout) as client:
                future = client.call_async(request)
                if attempt + 1 < attempts:
                    with contextlib.suppress(AssertionError):
                        wait_for(future.done, timeout, f"reply from {name}")
                    if future.done():
                        return future.result()
                    continue
                wait_for(future.done, timeout, f"reply from {name}")
                return future.result()
        raise AssertionError(f"no reply from {name}")

    def send_goal(
        self,
        action_type: Any,
        name: str,
        goal: Any,
        timeout: float = WAIT_S,
        *,
        refused: bool = False,
    ) -> Goal:
        """One goal from a fresh ``rclpy.action.ActionClient`` (what ``ros2 action
        send_goal --feedback`` does); waits for the server's accept or reject.

        ``refused``: a goal the server must reject, sent again while no response comes
        (the goal service's reply writer may not be matched with our reader yet, which
        ``answered_by_server`` cannot see: it asks the result service). A second one is
        rejected as well, or accepted and the test fails on it."""
        action_client = ActionClient(self.node, action_type, name)
        wait_for(action_client.server_is_ready, timeout, f"action server {name}")
        answered_by_server(self, action_client, action_type, timeout)
        sent = Goal(self, action_client)
        deadline = time.monotonic() + timeout
        while True:
            with self.between_spins():
                future = action_client.send_goal_async(goal, feedback_callback=sent.on_feedback)
            wait_s = deadline - time.monotonic()
            if refused:
                wait_s = min(PROBE_S, wait_s)
            with contextlib.suppress(AssertionError):
                wait_for(future.done, max(0.1, wait_s), "")
            if future.done():
                break
            if time.monotonic() >= deadline:
                raise AssertionError(
                    f"timed out after {timeout} s waiting for the goal response of {name}"
                )
        sent.handle = future.result()
        return sent

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        try_shutdown(context=self.context)
        self._thread.join(5)


def answered_by_server(
    client: Client, action_client: ActionClient, action_type: Any, timeout: float
) -> None:
    """Ask the server, through this client, for the result of a goal nobody sent (a query:
    it answers STATUS_UNKNOWN), until an answer comes back. "Server ready" means our
    requests reach it; on a loaded machine its replies may not reach us yet (discovery
    still matching its reply writer with our reader), and a goal's response lost that way
    leaves an accepted goal behind that the test cannot see. Goals are never sent twice."""
    deadline = time.monotonic() + timeout
    while True:
        goal_id = UUID(uuid=list(os.urandom(16)))
        response = action_type.Impl.SendGoalService.Response()
        handle = ClientGoalHandle(action_client, goal_id, response)
        with client.between_spins():
            future = action_client._get_result_async(handle)
        with contextlib.suppress(AssertionError):
            wait_for(future.done, min(PROBE_S, max(0.1, deadline - time.monotonic())), "")
        if future.done():
            return
        if time.monotonic() >= deadline:
            raise AssertionError(f"no answer from the action server after {timeout} s")


class Goal:
    """A goal sent by ``Client.send_goal``: its feedback as it comes, its result."""

    def __init__(self, client: Client, action_client: ActionClient) -> None:
        self.client = client
        self.action_client = action_client
        self.handle: Any = None
        self.feedback: list[Any] = []
        self._future: Any = None  # the result request, sent once

    def on_feedback(self, msg: Any) -> None:
        self.feedback.append(msg.feedback)

    @property
    def accepted(self) -> bool:
        return bool(self.handle is not None and self.handle.accepted)

    def wait_feedback(
        self, predicate: Callable[[Any], bool] = lambda f: True, timeout: float = WAIT_S
    ) -> Any:
        def find() -> Any:
            return next((f for f in reversed(self.feedback) if predicate(f)), None)

        return wait_for(find, timeout, "a matching feedback message")

    def cancel(self, timeout: float = WAIT_S) -> Any:
        with self.client.between_spins():
            future = self.handle.cancel_goal_async()
        wait_for(future.done, timeout, "the cancel response")
        return future.result()

    def _result_future(self) -> Any:
        if self._future is None:
            with self.client.between_spins():
                self._future = self.handle.get_result_async()
        return self._future

    def result(self, timeout: float = WAIT_S) -> tuple[int, Any]:
        """(GoalStatus status, result message)."""
        future = self._result_future()
        wait_for(future.done, timeout, "the goal's result")
        response = future.result()
        return response.status, response.result

    def fed_before_end(self, timeout: float = WAIT_S) -> bool:
        """Waits for feedback or the result: True if feedback came (the goal runs)."""
        future = self._result_future()
        wait_for(lambda: self.feedback or future.done(), timeout, "feedback or the result")
        return bool(self.feedback)

    def outcome(self, timeout: float = WAIT_S) -> Any:
        return self.result(timeout)[1].outcome

    def close(self) -> None:
        self.action_client.destroy()


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
) -> Iterator[forkserver.Process]:
    """Run ``python -m module --ros-args ...`` in its own process; stop it with SIGINT.
    Its output goes to ``node_log(log_dir, module)``."""
    log = node_log(log_dir, module).open("wb")
    proc = forkserver.python_module(
        module, [*ros_args(params), *extra], stdout=log, stderr=subprocess.STDOUT
    )
    try:
        yield proc
    finally:
        interrupt(proc, 10)
        log.close()


def node_log(log_dir: Path, module: str) -> Path:
    """Where ``node_process`` writes the output (stdout and stderr) of ``module``."""
    return log_dir / f"{module.replace('.', '_')}.log"


# What a clean exit never prints: an ERROR log line, rclpy's word for a callback's error
# that nobody collected, a traceback.
EXIT_COMPLAINTS = ("ERROR", "The following exception was never retrieved", "Traceback")


def exit_complaints(log: Path, since: int = 0) -> list[str]:
    """The lines of ``log`` from byte ``since`` on (its size when the exit began) that a
    clean exit must not print (``EXIT_COMPLAINTS``)."""
    with log.open("rb") as f:
        f.seek(since)
        text = f.read().decode(errors="replace")
    return [line for line in text.splitlines() if any(c in line for c in EXIT_COMPLAINTS)]


def interrupt(proc: forkserver.Process, timeout_s: float) -> None:
    """Ctrl-C (SIGINT) to a process still running; killed if it is not gone in time."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def refused_at_start(module: str, args: Sequence[str], timeout: float = 60.0) -> str:
    """Run ``python -m module args`` that must refuse to start: exit code 2 and exactly one
    non-blank line on stderr, no traceback. Returns that line for the caller's checks."""
    result = forkserver.run_module(module, args, timeout)
    output = result.stdout + result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and len(lines) == 1, output
    assert "Traceback" not in output, output
    return lines[0]


def status_node(status: Any) -> str:
    """The node name (no namespace) of a bridge's DiagnosticStatus ("/ns/node: ...")."""
    return str(status.name).split(": ", 1)[0].rsplit("/", 1)[-1]


def values_of(status: Any) -> dict[str, str]:
    """A DiagnosticStatus's key-value pairs as a dict."""
    return {kv.key: kv.value for kv in status.values}


def until_sent(call: Callable[[], Any], timeout: float = WAIT_S) -> Any:
    """``call()``'s reply, asked again while the node says the link kept it from going out
    at all ("refused: not connected to", "; nothing was sent"): for a test's
    preconditions and reads, where a pty stalled past the reply timeout
    (tests/support/serial_pair.py) cost the link a moment before. A command that went out
    is never sent twice."""
    deadline = time.monotonic() + timeout
    while True:
        reply = call()
        unsent = "refused: not connected to" in reply.message or reply.message.endswith(
            "; nothing was sent"
        )
        if reply.success or not unsent or time.monotonic() > deadline:
            return reply
        time.sleep(LINK_RETRY_S)


class Bridge:
    """Names of one running bridge node's topics and services."""

    def __init__(self, client: Client, namespace: str, node_name: str, state_type: Any) -> None:
        from geometry_msgs.msg import PoseStamped
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool

        self.client = client
        self.ns = namespace
        self.node_name = node_name
        self.joint_states = f"{namespace}/joint_states"
        self.state = f"{namespace}/{node_name}/state"
        self.pose = f"{namespace}/{node_name}/tcp_pose"
        self.connected = f"{namespace}/{node_name}/connected"
        client.subscribe(JointState, self.joint_states)
        client.subscribe(state_type, self.state)
        client.subscribe(PoseStamped, self.pose)
        client.subscribe(Bool, self.connected, LATCHED)

    def service(self, name: str) -> str:
        return f"{self.ns}/{self.node_name}/{name}"

    def call(self, srv_type: Any, name: str, **fields: Any) -> Any:
        request = srv_type.Request()
        for key, value in fields.items():
            setattr(request, key, value)
        return self.client.call(srv_type, self.service(name), request)

    def call_sent(self, srv_type: Any, name: str, **fields: Any) -> Any:
        """``call``, asked again while the link keeps it from going out (``until_sent``)."""
        return until_sent(lambda: self.call(srv_type, name, **fields))

    def send_goal(self, action_type: Any, name: str, **fields: Any) -> Goal:
        """A goal to the node's action ``name`` with ``fields`` set (``Client.send_goal``)."""
        goal = action_type.Goal()
        for key, value in fields.items():
            setattr(goal, key, value)
        return self.client.send_goal(action_type, self.service(name), goal)

    def diagnostics(self, since: float = 0.0) -> list[Any]:
        return [
            status
            for array in self.client.received("/diagnostics", since)
            for status in array.status
            if status.name.startswith(f"{self.ns}/{self.node_name}: ")
        ]

    def wait_diagnostic(
        self,
        level: int,
        since: float,
        port: int,
        timeout: float = WAIT_S,
        where: Callable[[dict[str, str]], bool] = lambda values: True,
    ) -> Any:
        """The newest status at ``level`` for ``port`` whose key-value pairs pass ``where``
        (a device's own keys appear only once its first snapshot was published)."""

        def find() -> Any:
            for status in reversed(self.diagnostics(since)):
                if (
                    f":{port} " in status.hardware_id
                    and status.level == bytes([level])
                    and where(values_of(status))
                ):
                    return status
            return None

        return wait_for(find, timeout, f"diagnostics level {level} for port {port}")

    def wait_connected(self, value: bool, since: float = 0.0, timeout: float = WAIT_S) -> None:
        self.client.wait_message(self.connected, lambda m: m.data == value, timeout, since)


def wait_status(
    client: Client,
    node_name: str,
    where: Callable[[dict[str, str]], bool],
    since: float,
    timeout: float = WAIT_S,
) -> Any:
    """The newest ``/diagnostics`` status of ``node_name`` (any namespace) received after
    ``since`` whose key-value pairs pass ``where``."""

    def find() -> Any:
        for array in reversed(client.received("/diagnostics", since)):
            for status in array.status:
                if status_node(status) == node_name and where(values_of(status)):
                    return status
        return None

    return wait_for(find, timeout, f"a diagnostics status of {node_name}")


def wait_stream_refusals(client: Client, node_name: str, count: int, since: float) -> None:
    """Until ``node_name`` reports ``count`` refused stream commands in all: each refused
    message was handled (a command stream keeps only its newest value, so a test sends a
    refused value and waits for it before the next)."""
    wait_status(
        client, node_name, lambda v: int(v.get("stream commands refused", -1)) >= count, since
    )


_NAMESPACE_COUNTER = iter(range(1_000_000))


def unique_namespace(stem: str) -> str:
    """A namespace no other test, nor another test run on this machine, uses: a ROS
    domain id (1-100 by pid) may be shared with a concurrent run."""
    return f"/{stem}_{os.getpid()}_{next(_NAMESPACE_COUNTER)}"


@contextmanager
def start_bridge(
    client: Client,
    log_dir: Path,
    module: str,
    node_name: str,
    state_type: Any,
    params: dict[str, Any],
) -> Iterator[tuple[Bridge, forkserver.Process]]:
    """A bridge node in its own process under a fresh namespace; asserts it did not die."""
    namespace = unique_namespace(f"{node_name}_test")
    bridge = Bridge(client, namespace, node_name, state_type)
    with node_process(module, params, log_dir, ["-r", f"__ns:={namespace}"]) as proc:
        yield bridge, proc
        assert proc.poll() is None, f"the bridge process died; see {log_dir}"
