"""The rclpy node base every bridge shares, and the ``main()`` that spins bridges.

What it gives a bridge (DESIGN §2): the common parameters (one ``ParameterSpec`` each:
start-up-only ones read-only, live ones validated and applied), the link and its channel
(or a channel on a bus someone else owns), the poller (``bridge_core.poller``: its own
thread, pacing, re-plan on device exceptions, a publisher thread), ``joint_states`` /
``~/connected`` / ``/diagnostics``, the stale-data policy (no fresh stamps while the link
is down), and the command guard that refuses, writing nothing, when the link is down or
``read_only`` is set, and turns device errors into a clear ``message``.

Threading: the poll and publisher threads belong to the poller (bench/r6_bench.py
measured an executor timer at ~1 ms of CPU per poll cycle); a MultiThreadedExecutor runs
services and command topics in one mutually exclusive group and diagnostics in another.
Modbus traffic never interleaves because every transaction holds the link's PriorityLock,
which also lets a waiting command go before the next poll request.

Live parameters (``ros2 param set``): ``read_only``, ``poll_rate_hz``, and whatever a
bridge registers with ``on_parameter`` (``command_timeout_s`` where there is a deadman).
Every other parameter is read-only after start-up.
"""

from __future__ import annotations

import contextlib
import functools
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.callback_groups import (
    CallbackGroup,
    MutuallyExclusiveCallbackGroup,
    ReentrantCallbackGroup,
)
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.time import Time
from rclpy.utilities import try_shutdown
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from .channel import DeviceChannel, Priority
from .checks import bounded_text
from .diagnostics import Level, Report, link_report
from .errors import (
    CommandRejected,
    ConfigurationError,
    DeviceException,
    LinkError,
    NotConfirmed,
    NotSent,
)
from .motion_ledger import MotionLedger
from .node_actions import ActionHost
from .parameters import ParameterSpec, ParameterValue
from .poller import Poller, PollOutcome
from .stream_guard import StreamGuard
from .transport import ModbusLink, SerialSettings, TcpSettings

T = TypeVar("T")
SnapshotT = TypeVar("SnapshotT")
DIAGNOSTICS_PERIOD_S = 1.0
LINK_DOWN_LOG_PERIOD_S = 10.0  # while a device stays down, say so this often on the console
# A halt's stop of a service's motion that failed is tried again this often (a probe of a
# dead line each time: the streams' deadman retries at 0.05 s).
PENDING_STOP_RETRY_S = 0.25
# How long a halt waits for a command that was past its guards (on the wire) to finish.
HALT_COMMAND_WAIT_S = 30.0
JOINT_STATES_DEPTH = 10
PARITIES = ("N", "E", "O")
UNIT_ID_RANGE = (0, 247)
# RTU: unit 0 is the broadcast address, and no device answers a broadcast (a bridge that
# polls it never gets a reply). TCP devices often answer unit 0, so it stays allowed there.
RTU_UNIT_ID_RANGE = (1, 247)
# The deadman looks every command_timeout_s / DEADMAN_CHECKS (within these bounds): its
# stop comes at most one period after the timeout (issue 9: within command_timeout_s and
# one bus transaction of the last message).
DEADMAN_CHECKS = 20
DEADMAN_PERIOD_MIN_S = 0.01
DEADMAN_PERIOD_MAX_S = 0.05
STREAM_DEPTH = 1  # command streams: only the newest message matters
# The poll threads wait on the line and then need the GIL for a moment; with Python's
# default 5 ms switch interval, each such moment waits out a busy thread's whole slice
# (the executor handling a flood of command messages). bench/stream_flood.py, 1000 msg/s
# on one MOTEC drive: polls of every drive 10.3 -> 6.0-7.2 Hz at 5 ms, 9.4-9.8 Hz at
# 0.5 ms.
GIL_SWITCH_INTERVAL_S = 0.0005
EXIT_CONFIGURATION_ERROR = 2
EXIT_FATAL_ERROR = 1  # a bug or an error nothing handled: motion stopped, then exit

_KINDS: dict[type, int] = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}


def descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """The ROS descriptor of a spec: type, range, read-only unless live."""
    text = spec.description
    if spec.choices:
        text += f" ({', '.join(spec.choices)})"
    text += "; live" if spec.live else "; start-up only"
    result = ParameterDescriptor(description=text, read_only=not spec.live)
    if spec.kind in _KINDS:
        result.type = _KINDS[spec.kind]
    if spec.low is not None and spec.high is not None:
        if spec.kind is int:
            result.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high))]
        else:
            result.floating_point_range = [
                FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high))
            ]
    return result


@dataclass(frozen=True)
class DeviceDefaults:
    """A kind of device as its bridge knows it: its name and the defaults of its parameters.

    One value per bridge (e.g. ``R6_DEFAULTS``), so that the node, the bus owner and the
    docs agree on them; users override each default with a ROS parameter.
    """

    device_name: str
    transport: str  # "tcp" or "rtu"
    poll_rate_hz: float = 20.0
    host: str = "127.0.0.1"
    port: int = 502
    serial_port: str = "/dev/ttyUSB0"
    baudrate: int = 9600
    parity: str = "N"
    stopbits: int = 1
    unit_id: int = 1
    timeout_s: float = 0.5
    timeout_min_s: float = 0.01  # a reply timeout below this can never be met
    frame_gap_s: float = 0.0  # RTU: least silence between frames beyond t3.5
    # RTU: reply timeout of a stop sent while the device is marked down (None: timeout_s).
    # Short, so that a stop repeated over a dead line is not still waiting out a long
    # timeout when the line comes back (issue 9: a stop within 0.3 s of the line's return).
    stop_timeout_s: float | None = None


def transport_specs(defaults: DeviceDefaults) -> list[ParameterSpec]:
    """Where the device is: the parameters of a node (or bus) that opens its own link."""
    if defaults.transport == "tcp":
        specs = [
            ParameterSpec("host", defaults.host, "device IP address or host name"),
            ParameterSpec("port", defaults.port, "Modbus TCP port", 1, 65535),
        ]
    else:
        specs = [
            ParameterSpec(
                "serial_port",
                defaults.serial_port,
                "serial device path or pyserial URL (e.g. socket://host:port)",
            ),
            ParameterSpec("baudrate", defaults.baudrate, "serial baud rate", 300, 4_000_000),
            ParameterSpec("parity", defaults.parity, "serial parity", choices=PARITIES),
            ParameterSpec("stopbits", defaults.stopbits, "serial stop bits", 1, 2),
            ParameterSpec(
                "frame_gap_s",
                defaults.frame_gap_s,
                "least silence between frames beyond the 3.5 characters of Modbus RTU",
                0.0,
                1.0,
            ),
        ]
    return [
        *specs,
        ParameterSpec(
            "timeout_s",
            defaults.timeout_s,
            "reply timeout per transaction",
            defaults.timeout_min_s,
            10.0,
        ),
    ]


def channel_specs() -> list[ParameterSpec]:
    """One device's retry and reconnect policy."""
    return [
        ParameterSpec(
            "retries", 1, "extra attempts for a failed read; writes are never retried", 0, 10
        ),
        ParameterSpec(
            "reconnect_max_s", 5.0, "cap of the exponential reconnect backoff", 0.1, 300.0
        ),
    ]


def link_settings(values: dict[str, Any]) -> TcpSettings | SerialSettings:
    """Typed link settings from the transport parameters' values."""
    if "host" in values:
        return TcpSettings(str(values["host"]), int(values["port"]), float(values["timeout_s"]))
    return SerialSettings(
        str(values["serial_port"]),
        int(values["baudrate"]),
        str(values["parity"]).upper(),
        int(values["stopbits"]),
        timeout_s=float(values["timeout_s"]),
        frame_gap_s=float(values["frame_gap_s"]),
    )


AUTOSTART_SPEC = ParameterSpec(
    "autostart", True, "configure and activate at start (false: wait for lifecycle transitions)"
)


class ParameterNode(LifecycleNode):
    """A managed node whose parameters are declared from specs and applied when they
    change. Lifecycle (REP-2002-style, ``rclpy.lifecycle``): ``autostart`` (default true)
    configures and activates it at start, so plain use needs no lifecycle manager."""

    def __init__(self, node_name: str, **node_kwargs: Any) -> None:
        super().__init__(node_name, **node_kwargs)
        change_state = self._service_change_state
        change_state.callback = self._refuse_unavailable_transitions(change_state.callback)
        self._specs: dict[str, ParameterSpec] = {}
        self._appliers: dict[str, Callable[[Any], None]] = {}
        self._writers: dict[str, Callable[[Any], str | None]] = {}
        self.add_pre_set_parameters_callback(self._coerce_parameters)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

    def _refuse_unavailable_transitions(
        self, change_state: Callable[[Any, Any], Any]
    ) -> Callable[[Any, Any], Any]:
        """rclpy (7.1) raises out of ``~/change_state`` when asked for a transition the
        current state does not have (transition id 6 while unconfigured), which would end
        the process: answer ``success: false`` instead, as rclcpp does."""

        def guarded(request: Any, response: Any) -> Any:
            try:
                return change_state(request, response)
            except _rclpy.RCLError:
                state = self._state_machine.current_state[1]
                transition = request.transition.label or request.transition.id
                self.get_logger().warning(
                    f"lifecycle: transition {transition} is not available in state {state}"
                )
                response.success = False
                return response

        return guarded

    def declare_specs(self, specs: Iterable[ParameterSpec]) -> dict[str, Any]:
        """Declare parameters; their start-up values by name.

        Raises ``ConfigurationError`` (one line) for a value of the wrong type or range.
        """
        values: dict[str, Any] = {}
        overrides: dict[str, Parameter] = getattr(self, "_parameter_overrides", {})
        for spec in specs:
            self._specs[spec.name] = spec
            value: ParameterValue = spec.default
            ignore_override = False
            if spec.name in overrides:
                given = overrides[spec.name].value
                coerced = spec.coerce(given)
                if coerced is not given:
                    value, ignore_override = coerced, True
            try:
                self.declare_parameter(spec.name, value, descriptor(spec), ignore_override)
            except ParameterException as err:
                given_value = overrides[spec.name].value if spec.name in overrides else None
                raise ConfigurationError(
                    f"{self.get_name()}: parameter {spec.name}: {_one_line(err)}"
                    + spec.type_hint(given_value)
                ) from err
            values[spec.name] = self.get_parameter(spec.name).value
        return values

    def on_parameter(self, name: str, apply: Callable[[Any], None]) -> None:
        """Apply a live parameter's new value (after it passed its spec's checks)."""
        if not self._specs[name].live:
            raise ValueError(f"parameter {name} is start-up only")
        self._appliers[name] = apply

    def on_parameter_write(self, name: str, write: Callable[[Any], str | None]) -> None:
        """A live parameter applied by writing to the device: ``write(value)`` runs while
        the set is checked and returns None once the device took it, or the reason it did
        not (the set is then refused and the parameter keeps its value). Of several
        parameters set at once, the ones written before a refusal stay written."""
        if not self._specs[name].live:
            raise ValueError(f"parameter {name} is start-up only")
        self._writers[name] = write

    def _coerce_parameters(self, parameters: list[Parameter]) -> list[Parameter]:
        out = []
        for parameter in parameters:
            spec = self._specs.get(parameter.name)
            value = parameter.value
            coerced = spec.coerce(value) if spec is not None else value
            out.append(parameter if coerced is value else Parameter(parameter.name, value=coerced))
        return out

    def _check_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            spec = self._specs.get(parameter.name)
            if spec is None:
                continue
            reason = spec.validate(parameter.value)
            if reason is not None:
                return SetParametersResult(successful=False, reason=reason)
        for parameter in parameters:
            write = self._writers.get(parameter.name)
            if write is not None and (reason := write(parameter.value)) is not None:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            apply = self._appliers.get(parameter.name)
            if apply is not None:
                apply(parameter.value)
                self.get_logger().info(f"parameter {parameter.name} set to {parameter.value!r}")


class BridgeNode(ParameterNode, Generic[SnapshotT]):
    """Base of the bridge nodes; subclasses poll, publish and add services.

    The node opens its own link from its transport parameters, unless it is given
    ``link`` and ``unit_id`` (a device on a bus a ``BusNode`` owns): then it declares
    no transport parameters and never closes the link. ``defaults`` may be a function of
    the node that returns them (after declaring the parameters they come from: a
    ``modbus_bridge`` device file). ``last_snapshot`` is the latest
    poll's, set before ``publish_snapshot`` runs (diagnostics and services read it).
    """

    def __init__(
        self,
        node_name: str,
        defaults: DeviceDefaults | Callable[[ParameterNode], DeviceDefaults],
        *,
        link: ModbusLink | None = None,
        unit_id: int | None = None,
        **node_kwargs: Any,
    ) -> None:
        super().__init__(node_name, **node_kwargs)
        if not isinstance(defaults, DeviceDefaults):
            defaults = defaults(self)
        self.device_name = defaults.device_name
        self.last_snapshot: SnapshotT | None = None
        self.joint_names: list[str] = []
        self.command_group = MutuallyExclusiveCallbackGroup()
        # Stop services: never queued behind a command or a deadman retry that waits out a
        # timeout on a dead link (a stop is attempted on the wire at once).
        self.stop_group = MutuallyExclusiveCallbackGroup()
        # Command stream arrivals: recorded at once, never behind a write (stream_topic).
        self.stream_inbox_group = MutuallyExclusiveCallbackGroup()
        self.diagnostics_group = MutuallyExclusiveCallbackGroup()
        self.stream_guards: list[StreamGuard[Any]] = []
        # Motions services started (fire-and-forget): stopped by a halt like the streams'.
        self.service_motions = MotionLedger()
        self.stream_refusals = 0  # stream commands refused (diagnostics)
        self._command_mutex = threading.RLock()  # one command (not stop) at a time
        # Set before a halt (deactivate, shutdown, error, exit) stops anything, cleared on
        # activate: a command or stream value that waited for its turn while the halt ran
        # is refused instead of restarting what the halt stopped.
        self._halted = False

        specs = [
            *channel_specs(),
            ParameterSpec(
                "poll_rate_hz",
                defaults.poll_rate_hz,
                "full-state polls per second",
                0.1,
                1000.0,
                live=True,
            ),
            ParameterSpec("joint_prefix", "", "prefix of every joint name"),
            ParameterSpec("frame_id", "base_link", "frame of published poses and states"),
            ParameterSpec(
                "read_only", False, "refuse every command that writes to the device", live=True
            ),
            AUTOSTART_SPEC,
        ]
        if link is None:
            specs = [
                *transport_specs(defaults),
                ParameterSpec(
                    "unit_id",
                    defaults.unit_id,
                    "Modbus unit (slave) id"
                    + (
                        " (0 is the RTU broadcast: nobody answers)"
                        if defaults.transport == "rtu"
                        else ""
                    ),
                    *(RTU_UNIT_ID_RANGE if defaults.transport == "rtu" else UNIT_ID_RANGE),
                ),
                *specs,
            ]
        values = self.declare_specs(specs)
        self.joint_prefix = str(values["joint_prefix"])
        self.autostart = bool(values["autostart"])
        self.frame_id = str(values["frame_id"])
        self.read_only = bool(values["read_only"])
        self._owned_link: ModbusLink | None = None
        if link is None:
            link = self._owned_link = ModbusLink(link_settings(values))
            unit_id = int(values["unit_id"])
        if unit_id is None:
            raise ValueError("a node on a shared link needs its unit_id")
        self.link = link
        stop_timeout_s = defaults.stop_timeout_s
        if stop_timeout_s is not None:
            stop_timeout_s = min(stop_timeout_s, link.settings.timeout_s)
        self.channel = DeviceChannel(
            link,
            unit_id,
            retries=int(values["retries"]),
            reconnect_max_s=float(values["reconnect_max_s"]),
            down_write_timeout_s=stop_timeout_s,
        )
        self.hardware_id = f"{self.device_name}@{self.channel.describe()}"

        self.joint_states_pub = self.create_publisher(
            JointState, "joint_states", JOINT_STATES_DEPTH
        )
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self.connected_pub = self.create_publisher(Bool, "~/connected", latched)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._connected_published: bool | None = None
        self._connected_lock = threading.Lock()
        self._down_said_at = 0.0  # monotonic time the console last said the link is down
        self._publish_connected(False)
        self.actions = ActionHost(self)
        self.poller: Poller[tuple[float, SnapshotT]] = Poller(
            self.channel,
            self._poll,
            self._publish,
            rate_hz=float(values["poll_rate_hz"]),
            link_up=self._link_up,
            replan=self.replan,
            report=self._poll_report,
            connected_changed=self._poll_connected,
            name=node_name,
        )
        self.poller.pause()  # polls and publishes only while the node is active (lifecycle)
        self.on_parameter("read_only", self._set_read_only)
        self.on_parameter("poll_rate_hz", lambda rate: setattr(self.poller, "rate_hz", rate))
        # Start polling once the executor runs, i.e. after the subclass finished __init__.
        self._poll_starter = self.create_timer(0.0, self._start_polling)
        self.diagnostics_timer = self.create_timer(
            DIAGNOSTICS_PERIOD_S, self.publish_diagnostics, callback_group=self.diagnostics_group
        )
        self.create_timer(
            PENDING_STOP_RETRY_S,
            self._retry_pending_stops,
            callback_group=MutuallyExclusiveCallbackGroup(),  # never in a stop service's way
        )

    # ------------------------------------------------------------ for subclasses
    def param(self, name: str) -> Any:
        return self.get_parameter(name).value

    def poll_device(self) -> SnapshotT:
        """Read the device's state; raise LinkError on failure."""
        raise NotImplementedError

    def publish_snapshot(self, snapshot: SnapshotT) -> None:
        raise NotImplementedError

    def on_link_up(self) -> None:
        """Called before the first poll after (re)connecting, e.g. to read a version."""

    def replan(self) -> None:
        """The device refused part of a poll: re-derive what to read from its configuration."""

    def _link_up(self) -> None:
        """Before the first poll after a (re)connect: pending stops first, then the node's
        ``on_link_up``. A stop that failed while the link was down goes out before any
        poll; if it fails again the link is still down and the poller says so."""
        for guard in self.stream_guards:
            for key in guard.pending_stops():
                try:
                    guard.stop(key)
                except DeviceException as err:  # answered: not a link fault; polls go on
                    self.get_logger().error(f"stream {key}: the device refused its stop: {err}")
                    continue
                self.get_logger().info(f"stream {key}: the pending stop was sent on reconnect")
        for stopped in self.service_motions.retry_pending():
            if isinstance(stopped.error, DeviceException):
                # Answered: the device refused the stop. Said loudly, not retried for ever
                # (polls must go on); the motion may still run.
                self.service_motions.stopped(stopped.axis)
                self.get_logger().error(
                    f"{stopped.what}: the device refused its pending stop: {stopped.error}"
                )
            elif stopped.error is not None:
                raise stopped.error  # still down: the poller says so, and tries again
            else:
                self.get_logger().info(f"{stopped.what}: the pending stop was sent on reconnect")
        self.on_link_up()

    def device_report(self) -> Report | None:
        """The device's own status (alarm code and its meaning) for diagnostics."""
        return None

    def stamp(self, wall_time: float) -> Any:
        return Time(nanoseconds=int(wall_time * 1e9)).to_msg()

    def publish_joints(
        self,
        wall_time: float,
        position: Sequence[float],
        velocity: Sequence[float] = (),
        effort: Sequence[float] = (),
    ) -> None:
        """``joint_states`` for ``joint_names``, in SI units (REP 103), stamped ``wall_time``."""
        msg = JointState()
        msg.header.stamp = self.stamp(wall_time)
        msg.name = list(self.joint_names)
        msg.position = [float(v) for v in position]
        msg.velocity = [float(v) for v in velocity]
        msg.effort = [float(v) for v in effort]
        self.joint_states_pub.publish(msg)

    def stamped(self, msg: Any, wall_time: float) -> Any:
        """``msg`` with its header stamped with ``wall_time`` and the node's frame_id."""
        msg.header.stamp = self.stamp(wall_time)
        msg.header.frame_id = self.frame_id
        return msg

    @property
    def poll_rate_hz(self) -> float:
        return self.poller.rate_hz

    # ------------------------------------------------------------ polling
    def _poll(self) -> tuple[float, SnapshotT]:
        """The poll and the (monotonic) time it began: a goal judges only polls begun after
        its start was acknowledged."""
        began = time.monotonic()
        return began, self.poll_device()

    def _publish(self, polled: tuple[float, SnapshotT]) -> None:
        began, snapshot = polled
        self.last_snapshot = snapshot
        self.publish_snapshot(snapshot)
        self.actions.offer(snapshot, began)

    def _start_polling(self) -> None:
        self._poll_starter.cancel()
        self.poller.start()

    # ------------------------------------------------------------ lifecycle
    # configure: nothing to open yet (the link opens with the first poll, and reconnects
    # by itself); activate: poll, publish, accept commands; deactivate: stop every motion
    # this node started, then no polls, no publishing, commands refused (stops are not);
    # cleanup: close the link this node owns; shutdown (from any state): stop first.
    @property
    def active(self) -> bool:
        """Accepting commands: activated, and no halt since."""
        return self.poller.active and not self._halted

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.get_logger().info(f"configured for {self.channel.describe()}")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._halted = False
        self.poller.resume()
        self.get_logger().info("active: polling, publishing, accepting commands")
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._halt("the node was deactivated")
        self.get_logger().info("inactive: motion stopped, not polling, commands refused")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close_owned_link()
        self.get_logger().info("unconfigured: link closed")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._halt("the node shut down")
        self._close_owned_link()
        self.get_logger().info("finalized: motion stopped, link closed (Ctrl-C ends the process)")
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._halt("lifecycle error")
        self.get_logger().error("lifecycle error: motion stopped, not polling")
        return TransitionCallbackReturn.SUCCESS

    def _halt(self, reason: str) -> None:
        """Refuse every command from now on, stop every motion this node started, then
        poll and publish no more."""
        self._halted = True
        self.stop_motion(reason)
        self._wait_for_command_on_the_wire()
        self.poller.pause()

    def _wait_for_command_on_the_wire(self) -> None:
        """A command past its guards when the halt came finishes (its own check then stops
        what it started: ``_halted_meanwhile``) before the halt goes on; bounded."""
        if self._command_mutex.acquire(timeout=HALT_COMMAND_WAIT_S):
            self._command_mutex.release()
        else:
            self.get_logger().error(
                f"a command still runs {HALT_COMMAND_WAIT_S:g} s after the halt began"
            )

    def _close_owned_link(self) -> None:
        if self._owned_link is not None:
            with self._owned_link.lock.hold(Priority.COMMAND):  # never mid-transaction
                self._owned_link.close()

    def _poll_report(self, outcome: PollOutcome, text: str) -> None:
        logger = self.get_logger()
        if outcome is PollOutcome.INCOMPLETE:
            logger.info(text)
        elif outcome is PollOutcome.REFUSED:
            logger.warn(f"{text}; re-reading the device's configuration", throttle_duration_sec=5.0)
        elif outcome is PollOutcome.SPLIT:
            logger.warn(text)  # once per split: the poll itself went on
        elif outcome is PollOutcome.UNREACHABLE:
            logger.warn(f"cannot reach {self.channel.describe()}: {text}; retrying")
            self._down_said_at = time.monotonic()
        elif outcome is PollOutcome.LINK_LOST:
            logger.error(f"link to {self.channel.describe()} lost: {text}; reconnecting")
            self._down_said_at = time.monotonic()
        elif outcome is PollOutcome.STILL_DOWN:
            # Every LINK_DOWN_LOG_PERIOD_S after the line that said it went down (rclpy's
            # own throttle would say it again on the first retry).
            now = time.monotonic()
            if now - self._down_said_at >= LINK_DOWN_LOG_PERIOD_S:
                logger.warn(f"{self.channel.describe()} still down: {text}")
                self._down_said_at = now
        else:
            logger.error(text)

    def _poll_connected(self, up: bool) -> None:
        self.actions.wake_all()  # a goal ends at once when its link is lost
        if up:
            self.get_logger().info(f"connected to {self.channel.describe()}")
        self._publish_connected(up)

    def _publish_connected(self, connected: bool) -> None:
        with self._connected_lock:
            if connected == self._connected_published:
                return
            self._connected_published = connected
        self.connected_pub.publish(Bool(data=connected))

    def _set_read_only(self, value: bool) -> None:
        was = self.read_only
        # Refusing first, then stopping: a command or stream value waiting for its turn is
        # refused, never written after the stop.
        self.read_only = bool(value)
        if value and not was:
            self.stop_motion("read_only was set")
            self._wait_for_command_on_the_wire()

    # ------------------------------------------------------------ commands
    def run_command(
        self,
        what: str,
        action: Callable[[], T],
        *,
        writes: bool = True,
        stop: bool = False,
        own_motion: bool = False,
        starts: tuple[Hashable, Callable[[], object]] | None = None,
        stops_axes: Iterable[Hashable] = (),
    ) -> tuple[bool, str, T | None]:
        """Guard and run one command: (success, message, result). Never raises.

        ``starts`` (axis, its stop): the command sets the axis moving; once any of its
        writes went out the node's ``service_motions`` remember it, so a halt stops it.
        ``stops_axes``: the command, when acknowledged, stopped those axes.

        ``stop``: a command that ends motion (stop, e-stop, disable, a stream's stop). It
        is attempted on the wire at once even while the link is marked down (one try,
        nothing queued, the answer says what happened); every other command is refused
        while the link is down. ``own_motion``: a stop of motion this node started
        (a stream's stop, the deadman): allowed under read_only too.
        """
        what = bounded_text(what)
        # Commands take turns whole (services, streams and action goals run in different
        # callback groups), so two commands' writes never interleave, and the guards are
        # read once it is this command's turn (a deactivate or read_only that came while
        # it waited is obeyed). A stop never waits for that.
        with contextlib.nullcontext() if stop else self._command_mutex:
            if not stop and not self.active:
                return False, f"{what} refused: the node is not active (lifecycle)", None
            if writes and self.read_only and not own_motion:
                return False, f"{what} refused: read_only is set, nothing was written", None
            if not stop and not self.channel.connected:
                return (
                    False,
                    f"{what} refused: not connected to {self.channel.describe()}",
                    None,
                )
            writes_before = self.channel.writes_tried()
            outcome = self._run_guarded(what, action, writes=writes, stop=stop)
            wrote = self.channel.writes_tried() > writes_before
            if starts is not None and wrote:
                # Acknowledged, or written and then lost or refused (it may be running).
                self.service_motions.started(starts[0], what, starts[1])
            if outcome[0]:
                self.service_motions.stopped(*stops_axes)
            if not stop and wrote and (self._halted or (self.read_only and not own_motion)):
                return self._halted_meanwhile(what)
            return outcome

    def _halted_meanwhile(self, what: str) -> tuple[bool, str, None]:
        """A command that was on the wire when a halt came (deactivate, exit, read_only):
        the halt's stops went out before its writes, so everything is stopped again now
        (``stop_motion``: what it started, the streams it may have taken over locked)."""
        self.get_logger().warn(f"{what} went out while the node halted: stopping again")
        self.stop_motion(f"{what} went out while the node halted")
        return False, f"{what} went out while the node halted, and was stopped again", None

    def _run_guarded(
        self, what: str, action: Callable[[], T], *, writes: bool, stop: bool
    ) -> tuple[bool, str, T | None]:
        writes_before = self.channel.writes_tried()
        try:
            # A stop is not tied to the connection it started on (command_session): it
            # must go out on whatever link there is now.
            with contextlib.nullcontext() if stop else self.channel.command_session():
                result = action()
        except CommandRejected as err:
            return False, f"{what} refused: {bounded_text(str(err))}", None
        except NotConfirmed as err:
            return False, f"{what}: not confirmed: {bounded_text(str(err))}", None
        except DeviceException as err:
            return False, f"{what}: the device answered {err}", None
        except LinkError as err:
            if not self.channel.connected:
                self.poller.link_lost(f"{what}: {err}")
            went_out = self.channel.writes_tried() - writes_before
            if isinstance(err, NotSent) and not went_out:
                hint = "; nothing was sent"
            elif isinstance(err, NotSent):
                hint = f"; {went_out} earlier write(s) of it went out, the rest was not sent"
            elif writes and not went_out:
                hint = "; nothing was written"
            else:
                hint = " (it may or may not have been executed)" if writes else ""
            return False, f"{what} failed: {bounded_text(str(err))}{hint}", None
        except Exception as err:
            self.get_logger().error(f"{what} failed: {err}\n{traceback.format_exc()}")
            return False, f"{what} failed: internal error: {err}", None
        return True, f"{what}: done", result

    def command_service(
        self,
        srv_type: Any,
        name: str,
        describe: Callable[[Any], str],
        action: Callable[[Any], T],
        *,
        writes: bool = True,
        stop: bool | Callable[[Any], bool] = False,
        fill: Callable[[Any, T], None] | None = None,
        starts: Callable[[Any], tuple[Hashable, Callable[[], object]] | None] | None = None,
        stops_axes: Callable[[Any], Iterable[Hashable]] | None = None,
    ) -> None:
        """A service that runs one guarded command per request.

        ``starts(request)``: (axis, its stop) when the request sets an axis moving (the
        node's halts stop it), None when it does not; ``stops_axes(request)``: the axes an
        acknowledged request stopped.

        ``describe(request)`` names the command in the reply message, ``action(request)``
        does it through the device layer, ``fill(response, result)`` copies a result into
        the response on success. ``stop`` (or ``stop(request)``, e.g. a disable): the
        command ends motion, so it is tried even while the link is down (``run_command``),
        and the service runs in ``stop_group``, never behind another command.
        """

        def handle(request: Any, response: Any) -> Any:
            ok, message, result = self.run_command(
                describe(request),
                lambda: action(request),
                writes=writes,
                stop=stop(request) if callable(stop) else stop,
                starts=starts(request) if starts is not None else None,
                stops_axes=stops_axes(request) if stops_axes is not None else (),
            )
            response.success, response.message = ok, message
            if ok and fill is not None:
                fill(response, result)  # type: ignore[arg-type]
            return response

        group: CallbackGroup = self.command_group
        if callable(stop):
            # Stops and non-stops in one service (enable true / false): reentrant, so a
            # non-stop waiting for its turn holds no group a stop needs.
            group = ReentrantCallbackGroup()
        elif stop:
            group = self.stop_group
        self.create_service(srv_type, name, handle, callback_group=group)

    def trigger_service(
        self,
        name: str,
        what: str,
        action: Callable[[], object],
        *,
        stop: bool = False,
        starts: tuple[Hashable, Callable[[], object]] | None = None,
        stops_axes: Iterable[Hashable] = (),
    ) -> None:
        """A std_srvs/Trigger service that runs one guarded command (``starts`` /
        ``stops_axes`` as in ``command_service``)."""
        from std_srvs.srv import Trigger

        self.command_service(
            Trigger,
            name,
            lambda _request: what,
            lambda _request: action(),
            stop=stop,
            starts=None if starts is None else lambda _request: starts,
            stops_axes=lambda _request: stops_axes,
        )

    # ------------------------------------------------------------ command streams
    def stream_topic(
        self,
        guard: StreamGuard[T],
        msg_type: Any,
        topics: dict[T, str],
        what: Callable[[T, float], str],
        value_of: Callable[[Any], float],
        *,
        convert: Callable[[T, float], float] = lambda _key, value: value,
        timeout_parameter: str = "command_timeout_s",
        rate_parameter: str = "command_rate_hz",
    ) -> None:
        """Command topics of one guard (jog, cmd_velocity) with their deadman.

        Arrival and writing are apart. A message is only recorded (``guard.offer``: newest
        value per stream, the deadman counts from its arrival) in a callback group of its
        own with a depth-1 subscription, so a flood costs no bus time and never waits
        behind a write. The writer runs in the command group, woken by each arrival and by
        the deadman timer: it applies what the guard says is ``ready`` (a 0 at once, other
        values at most ``rate_parameter`` times a second per stream) through the command
        guard (a refused value stops what the stream had started). The timer also stops
        streams that fell silent. Both parameters are live; ``close()`` stops every stream.
        ``convert`` checks a value and turns it into the guard's units (inside the command
        guard: a bad value is a refusal, not an exception in a callback).
        """
        self.stream_guards.append(guard)
        guard.permit = self._stream_permit

        def write_ready() -> None:
            self._write_ready(guard, convert, what)

        writer = self.create_guard_condition(write_ready, callback_group=self.command_group)
        for key, topic in topics.items():
            self.create_subscription(
                msg_type,
                topic,
                self._stream_callback(guard, key, value_of, writer.trigger),
                STREAM_DEPTH,
                callback_group=self.stream_inbox_group,
            )

        def period() -> float:
            return min(
                DEADMAN_PERIOD_MAX_S, max(DEADMAN_PERIOD_MIN_S, guard.timeout_s / DEADMAN_CHECKS)
            )

        def tick() -> None:
            write_ready()  # values held back by the rate limit
            self._deadman(guard, what)

        timer = self.create_timer(period(), tick, callback_group=self.command_group)

        def set_timeout(value: float) -> None:
            guard.timeout_s = float(value)
            timer.timer_period_ns = int(period() * 1e9)
            timer.reset()

        def set_rate(rate_hz: float) -> None:
            guard.min_interval_s = 1.0 / float(rate_hz)

        self.on_parameter(timeout_parameter, set_timeout)
        self.on_parameter(rate_parameter, set_rate)
        set_rate(self.param(rate_parameter))

    def _stream_permit(self) -> str | None:
        """Asked by a stream guard, under its lock, before every non-zero write."""
        if not self.active:
            return "the node is not active (lifecycle): nothing was written"
        if self.read_only:
            return "read_only is set, nothing was written"
        return None

    def _stream_callback(
        self,
        guard: StreamGuard[T],
        key: T,
        value_of: Callable[[Any], float],
        wake_writer: Callable[[], None],
    ) -> Callable[[Any], None]:
        def arrived(msg: Any) -> None:
            if guard.offer(key, value_of(msg)):
                wake_writer()  # else the deadman timer's pass applies it (a flood wakes
                # the writer at most command_rate_hz times a second, not per message)

        return arrived

    def _write_ready(
        self,
        guard: StreamGuard[T],
        convert: Callable[[T, float], float],
        what: Callable[[T, float], str],
    ) -> None:
        for key in guard.ready():
            value = guard.take(key)
            if value is None:
                continue
            ok, message, _ = self.run_command(
                what(key, value), functools.partial(_apply, guard, key, value, convert)
            )
            if not ok:
                self._stream_refused(guard, key, message, what)

    def _stream_refused(
        self, guard: StreamGuard[T], key: T, message: str, what: Callable[[T, float], str]
    ) -> None:
        self.stream_refusals += 1
        self.get_logger().warn(message, throttle_duration_sec=2.0)
        stream = guard[key]
        if stream.may_move and not stream.stop_pending:
            # A refused value must not leave the motor running at the previous one. A stop
            # already pending is the deadman's: it retries at its own period, not per message.
            self.run_command(
                f"{what(key, 0.0)} (stop after a refused command)",
                lambda: guard.stop(key),
                stop=True,
                own_motion=True,
            )

    def _deadman(self, guard: StreamGuard[T], what: Callable[[T, float], str]) -> None:
        for key in guard.due():
            was_moving = guard[key].may_move
            ok, message, _ = self.run_command(
                f"{what(key, 0.0)} (deadman)",
                functools.partial(guard.expire, key),
                stop=True,
                own_motion=True,
            )
            if not was_moving:
                continue
            if ok:
                self.get_logger().info(
                    f"{what(key, 0.0)}: no command for {guard.timeout_s} s, stopped"
                )
            else:
                self.get_logger().warn(message, throttle_duration_sec=2.0)

    def stop_motion(self, reason: str = "the node stops") -> None:
        """Stop everything this node's streams, services and action goals started; tried on
        the wire even while the link is marked down (no connected guard, no command
        session). Each part is tried whatever another raised; the streams' and services'
        stops go before the goals' (whose stop may wait for a start on the wire)."""
        for guard in self.stream_guards:
            try:
                moving = guard.moving()
                failed = guard.stop_all()
            except Exception as bug:  # a bug in one part must not skip the others
                self.get_logger().error(f"stopping streams failed: {bug}")
                continue
            for key, err in failed:
                self.get_logger().error(f"stopping stream {key} failed: {err}")
            for key in set(moving) - {key for key, _ in failed}:
                self.get_logger().info(f"stream {key}: stopped")
        for stopped in self.service_motions.stop_all():
            if stopped.error is None:
                self.get_logger().info(f"{stopped.what}: stopped ({reason})")
            else:
                self.get_logger().error(
                    f"{stopped.what}: its stop failed ({reason}): {stopped.error}; "
                    "tried again until it gets through"
                )
        try:
            self.actions.stop_all(reason)
        except Exception as err:
            self.get_logger().error(f"stopping action goals failed: {err}")

    def _retry_pending_stops(self) -> None:
        """A halt's stop that failed (the link was down) is tried again on a timer, also
        while the node is inactive (nobody reactivates it to get the stop out)."""
        if not self.service_motions.pending():
            return
        for stopped in self.service_motions.retry_pending():
            if stopped.error is None:
                self.get_logger().info(f"{stopped.what}: the pending stop got through")
            else:
                self.get_logger().warn(
                    f"{stopped.what}: its stop still fails: {stopped.error}",
                    throttle_duration_sec=LINK_DOWN_LOG_PERIOD_S,
                )

    # ------------------------------------------------------------ diagnostics
    def publish_diagnostics(self) -> None:
        if not self.active:
            return  # an inactive node publishes nothing
        try:
            self._publish_diagnostics()
        except Exception as err:  # diagnostics must never take the node down
            self.get_logger().error(f"diagnostics failed: {err}\n{traceback.format_exc()}")

    def _publish_diagnostics(self) -> None:
        poller = self.poller
        link = link_report(
            self.channel,
            poll_rate=poller.rate,
            target_rate_hz=poller.rate_hz,
            poll_failures=poller.failures,
        )
        device = self.device_report() if self.channel.connected else None
        level, message, values = link.level, link.message, list(link.values)
        values.append(("snapshots dropped (publisher behind)", str(poller.snapshots_dropped)))
        values.append(("read_only", str(self.read_only).lower()))
        if self.stream_guards:
            values.append(("stream commands refused", str(self.stream_refusals)))
        if self.actions.servers:
            values.append(("action goals running", "; ".join(self.actions.running) or "none"))
        if self.channel.connected and poller.last_error:
            # Connected but no fresh state: as bad as a lost link for a consumer.
            level, message = Level.ERROR, poller.last_error
        if device is not None:
            values += device.values
            if device.level > level:
                level, message = device.level, device.message
        status = DiagnosticStatus(
            level=bytes([int(level)]),
            # The full name: two bridges of one kind in one domain differ by namespace.
            name=f"{self.get_fully_qualified_name()}: {self.device_name} Modbus bridge",
            message=message,
            hardware_id=self.hardware_id,
            values=[KeyValue(key=k, value=v) for k, v in values],
        )
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self.diagnostics_pub.publish(array)

    def close(self) -> None:
        """Stop motion, then polling, then close the link if this node opened it."""
        self._halted = True  # nothing but stops from here on
        try:
            self.stop_motion("the node is exiting")
            self._wait_for_command_on_the_wire()
        finally:
            self.poller.stop()
            self._close_owned_link()


class BusNode(ParameterNode):
    """One serial line shared by several devices (any bridges): the bus owner.

    It holds the line's parameters and its one ``ModbusLink``; device nodes get the link
    and their unit id as Python values (``BridgeNode(link=..., unit_id=...)``) and take
    turns on it through its PriorityLock.
    """

    def __init__(
        self,
        node_name: str,
        defaults: DeviceDefaults | Callable[[ParameterNode], DeviceDefaults],
        *,
        unit_id_range: range,
        unit_ids: Callable[[], Sequence[int]] | None = None,
        **node_kwargs: Any,
    ) -> None:
        super().__init__(node_name, **node_kwargs)
        if not isinstance(defaults, DeviceDefaults):
            defaults = defaults(self)  # as BridgeNode's (a modbus_bridge device file)
        # unit_ids: the devices' ids when something else names them (a device file);
        # else the ``unit_ids`` parameter.
        own_units = (
            []
            if unit_ids is not None
            else [ParameterSpec("unit_ids", [1], "devices on the bus, one node each")]
        )
        values = self.declare_specs([*transport_specs(defaults), *own_units, AUTOSTART_SPEC])
        self.autostart = bool(values["autostart"])
        units = [int(u) for u in (values["unit_ids"] if unit_ids is None else unit_ids())]
        if not units or len(set(units)) != len(units):
            raise ConfigurationError(f"unit_ids {units} must be distinct and not empty")
        for unit in units:
            if unit not in unit_id_range:
                raise ConfigurationError(
                    f"unit id {unit} outside {unit_id_range.start}-{unit_id_range.stop - 1}"
                )
        self.unit_ids = units
        self.settings = link_settings(values)
        self.link = ModbusLink(self.settings)

    def close(self) -> None:
        with self.link.lock.hold(Priority.COMMAND):
            self.link.close()


def _apply(
    guard: StreamGuard[T], key: T, value: float, convert: Callable[[T, float], float]
) -> bool:
    """One stream command: checked and converted, then through the guard."""
    return guard.command(key, convert(key, value))


def copy_fields(msg: Any, source: Any, names: Iterable[str]) -> Any:
    """Copy same-named fields from a snapshot into a message (tuples become lists)."""
    for name in names:
        value = getattr(source, name)
        setattr(msg, name, list(value) if isinstance(value, tuple) else value)
    return msg


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split())


def interrupt_on_signals() -> None:
    """SIGINT/SIGTERM raise KeyboardInterrupt in the main thread.

    Used instead of rclpy's handlers (rclpy.init with SignalHandlerOptions.NO), which shut
    the context down at once while the poll and publisher threads still publish; this way
    the nodes stop their motion and threads first and the context goes last.
    """

    def interrupt(_signum: int, _frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, interrupt)


def _close_all(nodes: Sequence[Node]) -> None:
    """Close every bridge at once (stops first), then the bus owners, then destroy."""
    bridges = [node for node in nodes if isinstance(node, BridgeNode)]
    closers = [threading.Thread(target=node.close) for node in bridges]
    for closer in closers:
        closer.start()
    for closer in closers:
        closer.join()
    for node in nodes:
        if isinstance(node, BusNode):
            node.close()
    for node in nodes:
        node.destroy_node()


def _refuse_unused_parameters(nodes: Sequence[Node]) -> None:
    """A ``-p`` or params-file value that no node of the process declares is a typo or a
    parameter of another node (``unit_id`` on the MOTEC bus, whose drives are
    ``unit_ids``): refused, since it would be silently ignored. A params file's ``/**``
    block reaches every node, so a value counts as used when any node declares it."""
    given: dict[str, Any] = {}
    for node in nodes:
        for name, parameter in getattr(node, "_parameter_overrides", {}).items():
            given.setdefault(name, parameter.value)
    unused = [name for name in given if not any(node.has_parameter(name) for node in nodes)]
    if unused:
        listed = ", ".join(f"{name}:={given[name]!r}" for name in sorted(unused))
        names = ", ".join(node.get_name() for node in nodes)
        raise ConfigurationError(
            f"parameter {listed} is not one of this process's ({names}); check its name"
        )


def spin_nodes(
    build: Callable[[list[Node]], None],
    args: Sequence[str] | None = None,
    *,
    threads: Callable[[int], int] = lambda nodes: max(4, min(32, 2 + 4 * nodes)),
) -> int:
    """rclpy demo-style main for one process of bridge nodes; returns the exit code.

    ``build`` appends the nodes it creates to the list it is given (so a node that fails
    half-way still has the earlier ones closed). A configuration error (bad parameter
    type or range) is one line on stderr and exit code 2, never a traceback.
    """
    rclpy.init(
        args=list(args) if args is not None else None,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    interrupt_on_signals()
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    nodes: list[Node] = []
    executor: MultiThreadedExecutor | None = None
    code = 0
    try:
        build(nodes)
        _refuse_unused_parameters(nodes)
        for node in nodes:  # the bus owner first, then its devices
            if isinstance(node, LifecycleNode) and getattr(node, "autostart", False):
                node.trigger_configure()
                node.trigger_activate()
        # A running action goal holds an executor thread until it ends.
        goal_threads = sum(node.actions.threads for node in nodes if isinstance(node, BridgeNode))
        executor = MultiThreadedExecutor(num_threads=threads(len(nodes)) + goal_threads)
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ConfigurationError, ParameterException) as err:
        print(f"error: {_one_line(err)}", file=sys.stderr)
        code = EXIT_CONFIGURATION_ERROR
    except Exception as err:
        # An error no callback handled (a bug): every motion is stopped below before the
        # process ends, and the traceback is kept, since it is what a bug report needs.
        traceback.print_exc()
        print(
            f"fatal error: {_one_line(err)}; stopping every motion, then exiting",
            file=sys.stderr,
        )
        code = EXIT_FATAL_ERROR
    finally:
        if executor is not None:
            executor.shutdown()
        _close_all(nodes)
        try_shutdown()
    return code


def spin_node(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """``spin_nodes`` for a process of one node."""
    return spin_nodes(lambda nodes: nodes.append(make_node()), args)


__all__ = [
    "BridgeNode",
    "BusNode",
    "Level",
    "ParameterNode",
    "Report",
    "copy_fields",
    "interrupt_on_signals",
    "spin_node",
    "spin_nodes",
]
