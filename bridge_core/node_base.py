"""The rclpy node base every bridge shares.

What it gives a bridge (DESIGN §2): the common parameters with descriptors and ranges, the
link and its channel, a poll timer, ``joint_states`` / ``~/connected`` / ``/diagnostics``
publishers, the stale-data policy (no fresh stamps while the link is down), and the
command guard that refuses, writing nothing, when the link is down or ``read_only`` is
set, and turns device errors into a clear ``message``.

Threading: polling runs on a thread of its own, paced by the poll rate, and hands each
snapshot to a publisher thread, so building and publishing the messages overlaps the
device's time to answer the next request; a MultiThreadedExecutor runs the services and
the diagnostics timer in two mutually exclusive callback groups. Threads rather than an
executor timer, because bench/r6_bench.py measured the executor's wait-set rebuilds at
~1 ms of CPU per poll cycle. Modbus traffic never interleaves because every transaction
holds the link's PriorityLock, which also lets a waiting command go before the next poll
request.
"""

from __future__ import annotations

import contextlib
import math
import queue
import signal
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.time import Time
from rclpy.utilities import try_shutdown
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from .channel import DeviceChannel, Priority
from .diagnostics import Level, RateTracker, Report, link_report
from .errors import CommandRejected, DeviceException, LinkError, PollIncomplete
from .transport import ModbusLink, SerialSettings, TcpSettings

T = TypeVar("T")
DIAGNOSTICS_PERIOD_S = 1.0
PUBLISH_BACKLOG = 8  # snapshots waiting for the publisher thread before the oldest is dropped
JOINT_STATES_DEPTH = 10


def _descriptor(
    text: str, kind: int, low: float | None = None, high: float | None = None, step: float = 0.0
) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(description=text, type=kind)
    if low is not None and high is not None:
        if kind == ParameterType.PARAMETER_INTEGER:
            descriptor.integer_range = [
                IntegerRange(from_value=int(low), to_value=int(high), step=int(step))
            ]
        else:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(low), to_value=float(high), step=step)
            ]
    return descriptor


INT = ParameterType.PARAMETER_INTEGER
DOUBLE = ParameterType.PARAMETER_DOUBLE
STRING = ParameterType.PARAMETER_STRING
BOOL = ParameterType.PARAMETER_BOOL
DOUBLE_ARRAY = ParameterType.PARAMETER_DOUBLE_ARRAY


class BridgeNode(Node):
    """Base of the four bridge nodes; subclasses poll, publish and add services."""

    def __init__(
        self,
        node_name: str,
        *,
        transport: str,
        device_name: str,
        default_poll_rate_hz: float = 20.0,
        default_port: int = 502,
        default_baudrate: int = 9600,
        link: ModbusLink | None = None,
        **node_kwargs: Any,
    ) -> None:
        super().__init__(node_name, **node_kwargs)
        self.device_name = device_name
        self.poll_group = MutuallyExclusiveCallbackGroup()
        self.command_group = MutuallyExclusiveCallbackGroup()
        self.diagnostics_group = MutuallyExclusiveCallbackGroup()

        p = self.declare_parameter
        if transport == "tcp":
            p("host", "127.0.0.1", _descriptor("device IP address or host name", STRING))
            p("port", default_port, _descriptor("Modbus TCP port", INT, 1, 65535))
        else:
            p(
                "serial_port",
                "/dev/ttyUSB0",
                _descriptor("serial device path or pyserial URL (e.g. socket://host:port)", STRING),
            )
            p("baudrate", default_baudrate, _descriptor("serial baud rate", INT, 300, 4_000_000))
            p("parity", "N", _descriptor("N, E or O", STRING))
            p("stopbits", 1, _descriptor("1 or 2", INT, 1, 2))
        p("unit_id", 1, _descriptor("Modbus unit (slave) id", INT, 0, 247))
        p(
            "poll_rate_hz",
            default_poll_rate_hz,
            _descriptor("full-state polls per second", DOUBLE, 0.1, 1000.0),
        )
        p("timeout_s", 0.5, _descriptor("reply timeout per transaction", DOUBLE, 0.01, 10.0))
        p(
            "retries",
            1,
            _descriptor("extra attempts for a failed read; writes are never retried", INT, 0, 10),
        )
        p(
            "reconnect_max_s",
            5.0,
            _descriptor("cap of the exponential reconnect backoff", DOUBLE, 0.1, 300.0),
        )
        p("joint_prefix", "", _descriptor("prefix of every joint name", STRING))
        p("frame_id", "base_link", _descriptor("frame of published poses", STRING))
        p("read_only", False, _descriptor("refuse every command that writes to the device", BOOL))

        self.poll_rate_hz = float(self.param("poll_rate_hz"))
        self.joint_prefix = str(self.param("joint_prefix"))
        self.frame_id = str(self.param("frame_id"))
        self.read_only = bool(self.param("read_only"))
        timeout_s = float(self.param("timeout_s"))
        settings: TcpSettings | SerialSettings
        if link is not None:
            self.link = link
        else:
            if transport == "tcp":
                settings = TcpSettings(str(self.param("host")), int(self.param("port")), timeout_s)
            else:
                parity = str(self.param("parity")).upper()
                if parity not in ("N", "E", "O"):
                    raise ValueError(f"parity {parity!r} is not N, E or O")
                settings = SerialSettings(
                    str(self.param("serial_port")),
                    int(self.param("baudrate")),
                    parity,
                    int(self.param("stopbits")),
                    timeout_s=timeout_s,
                )
            self.link = ModbusLink(settings)
        self.channel = DeviceChannel(
            self.link,
            int(self.param("unit_id")),
            retries=int(self.param("retries")),
            reconnect_max_s=float(self.param("reconnect_max_s")),
        )
        self.hardware_id = f"{device_name}@{self.channel.describe()}"

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
        self.poll_rate = RateTracker()
        self.poll_failures = 0
        self.last_poll_error: str | None = None
        self._publish_connected(False)
        self._stop_polling = threading.Event()
        self._poll_thread = threading.Thread(
            target=self._poll_loop, name=f"{node_name}-poll", daemon=True
        )
        self._snapshots: queue.Queue[Any] = queue.Queue(maxsize=PUBLISH_BACKLOG)
        self.snapshots_dropped = 0
        self._publish_thread = threading.Thread(
            target=self._publish_loop, name=f"{node_name}-publish", daemon=True
        )
        # Start polling once the executor runs, i.e. after the subclass finished __init__.
        self._poll_starter = self.create_timer(
            0.0, self._start_polling, callback_group=self.poll_group
        )
        self.diagnostics_timer = self.create_timer(
            DIAGNOSTICS_PERIOD_S, self.publish_diagnostics, callback_group=self.diagnostics_group
        )

    # ------------------------------------------------------------ for subclasses
    def param(self, name: str) -> Any:
        return self.get_parameter(name).value

    def poll_device(self) -> Any:
        """Read the device's state; raise LinkError on failure."""
        raise NotImplementedError

    def publish_snapshot(self, snapshot: Any) -> None:
        raise NotImplementedError

    def on_link_up(self) -> None:
        """Called before the first poll after (re)connecting, e.g. to read a version."""

    def device_report(self) -> Report | None:
        """The device's own status (alarm code and its meaning) for diagnostics."""
        return None

    def stamp(self, wall_time: float) -> Any:
        return Time(nanoseconds=int(wall_time * 1e9)).to_msg()

    def joint_state(
        self,
        wall_time: float,
        names: Sequence[str],
        position: Sequence[float],
        velocity: Sequence[float] = (),
        effort: Sequence[float] = (),
    ) -> JointState:
        msg = JointState()
        msg.header.stamp = self.stamp(wall_time)
        msg.name = list(names)
        msg.position = [float(v) for v in position]
        msg.velocity = [float(v) for v in velocity]
        msg.effort = [float(v) for v in effort]
        return msg

    # ------------------------------------------------------------ polling
    def _start_polling(self) -> None:
        self._poll_starter.cancel()
        if not self._poll_thread.is_alive() and not self._stop_polling.is_set():
            self._publish_thread.start()
            self._poll_thread.start()

    def _poll_loop(self) -> None:
        period = 1.0 / self.poll_rate_hz
        next_time = time.monotonic()
        while not self._stop_polling.is_set():
            self._poll_tick()
            next_time += period
            now = time.monotonic()
            if next_time <= now:
                next_time = now  # overrun: carry on, never burst to catch up
            else:
                self._stop_polling.wait(next_time - now)

    def _poll_tick(self) -> None:
        if not self.channel.may_attempt():
            return
        try:
            if not self.channel.connected:
                self.on_link_up()
            snapshot = self.poll_device()
        except PollIncomplete as err:
            self.get_logger().info(str(err))
            return
        except DeviceException as err:
            # The device answered but refused part of the poll: report, publish nothing.
            self.poll_failures += 1
            self.last_poll_error = f"poll refused by the device: {err}"
            self.get_logger().warn(self.last_poll_error, throttle_duration_sec=5.0)
            return
        except LinkError as err:
            self.poll_failures += 1
            self.last_poll_error = str(err)
            if self._connected_published:
                self.get_logger().error(f"link to {self.channel.describe()} lost: {err}")
            self._publish_connected(False)
            return
        except Exception as err:  # a device fault must never kill the node
            self.poll_failures += 1
            self.last_poll_error = f"poll failed: {err}"
            self.get_logger().error(f"poll failed: {err}\n{traceback.format_exc()}")
            return
        if not self._connected_published:
            self.get_logger().info(f"connected to {self.channel.describe()}")
        self._publish_connected(True)
        self.last_poll_error = None
        self.poll_rate.tick()
        try:
            self._snapshots.put_nowait(snapshot)
        except queue.Full:  # the publisher fell behind: drop the oldest, keep the newest
            with contextlib.suppress(queue.Empty):
                self._snapshots.get_nowait()
                self.snapshots_dropped += 1
            with contextlib.suppress(queue.Full):
                self._snapshots.put_nowait(snapshot)

    def _publish_loop(self) -> None:
        while not self._stop_polling.is_set():
            try:
                snapshot = self._snapshots.get(timeout=0.1)
            except queue.Empty:
                continue
            try:
                self.publish_snapshot(snapshot)
            except Exception as err:  # a value the message cannot hold must not kill the node
                self.last_poll_error = f"publishing failed: {err}"
                self.get_logger().error(f"{self.last_poll_error}\n{traceback.format_exc()}")

    def _publish_connected(self, connected: bool) -> None:
        if connected != self._connected_published:
            self._connected_published = connected
            self.connected_pub.publish(Bool(data=connected))

    # ------------------------------------------------------------ commands
    def run_command(
        self, what: str, action: Callable[[], T], *, writes: bool = True
    ) -> tuple[bool, str, T | None]:
        """Guard and run one command: (success, message, result). Never raises."""
        if writes and self.read_only:
            return False, f"{what} refused: read_only is set, nothing was written", None
        if not self.channel.connected:
            return False, f"{what} refused: not connected to {self.channel.describe()}", None
        try:
            with self.channel.command_session():
                result = action()
        except CommandRejected as err:
            return False, f"{what} refused: {err}", None
        except DeviceException as err:
            return False, f"{what}: the device answered {err}", None
        except LinkError as err:
            self._publish_connected(self.channel.connected)
            hint = " (it may or may not have been executed)" if writes else ""
            return False, f"{what} failed: {err}{hint}", None
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
        fill: Callable[[Any, T], None] | None = None,
    ) -> None:
        """A service that runs one guarded command per request.

        ``describe(request)`` names the command in the reply message, ``action(request)``
        does it through the device layer, ``fill(response, result)`` copies a result into
        the response on success.
        """

        def handle(request: Any, response: Any) -> Any:
            ok, message, result = self.run_command(
                describe(request), lambda: action(request), writes=writes
            )
            response.success, response.message = ok, message
            if ok and fill is not None:
                fill(response, result)  # type: ignore[arg-type]
            return response

        self.create_service(srv_type, name, handle, callback_group=self.command_group)

    def trigger_service(self, name: str, what: str, action: Callable[[], object]) -> None:
        """A std_srvs/Trigger service that runs one guarded command."""
        from std_srvs.srv import Trigger

        self.command_service(Trigger, name, lambda _request: what, lambda _request: action())

    # ------------------------------------------------------------ diagnostics
    def publish_diagnostics(self) -> None:
        try:
            self._publish_diagnostics()
        except Exception as err:  # diagnostics must never take the node down
            self.get_logger().error(f"diagnostics failed: {err}\n{traceback.format_exc()}")

    def _publish_diagnostics(self) -> None:
        link = link_report(
            self.channel,
            poll_rate=self.poll_rate,
            target_rate_hz=self.poll_rate_hz,
            poll_failures=self.poll_failures,
        )
        device = self.device_report() if self.channel.connected else None
        level, message, values = link.level, link.message, list(link.values)
        values.append(("snapshots dropped (publisher behind)", str(self.snapshots_dropped)))
        if self.channel.connected and self.last_poll_error:
            # Connected but no fresh state: as bad as a lost link for a consumer.
            level, message = Level.ERROR, self.last_poll_error
        if device is not None:
            values += device.values
            if device.level > level:
                level, message = device.level, device.message
        status = DiagnosticStatus(
            level=bytes([int(level)]),
            name=f"{self.get_name()}: {self.device_name} Modbus bridge",
            message=message,
            hardware_id=self.hardware_id,
            values=[KeyValue(key=k, value=v) for k, v in values],
        )
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self.diagnostics_pub.publish(array)

    def close(self) -> None:
        self._stop_polling.set()
        for thread in (self._poll_thread, self._publish_thread):
            if thread.is_alive():
                thread.join(5.0)
        with self.link.lock.hold(Priority.COMMAND):  # never under a running transaction
            self.link.close()


def float_list(values: Sequence[float], count: int, default: float, name: str) -> list[float]:
    """A per-joint parameter padded with ``default``; refuses NaN and non-positive values."""
    out = [float(v) for v in values][:count]
    out += [default] * (count - len(out))
    for v in out:
        if not math.isfinite(v) or v <= 0:
            raise ValueError(f"{name} must be positive and finite, got {v}")
    return out


def interrupt_on_signals() -> None:
    """SIGINT/SIGTERM raise KeyboardInterrupt in the main thread.

    Used instead of rclpy's handlers (rclpy.init with SignalHandlerOptions.NO), which shut
    the context down at once while the poll and publisher threads still publish; this way
    the node stops its threads first and the context goes last.
    """

    def interrupt(_signum: int, _frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, interrupt)


def spin_node(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> None:
    """rclpy demo-style main: init, spin with a multi-threaded executor, clean shutdown."""
    rclpy.init(
        args=list(args) if args is not None else None,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    interrupt_on_signals()
    node: Node | None = None
    executor = MultiThreadedExecutor(num_threads=3)
    try:
        node = make_node()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        if node is not None:
            if isinstance(node, BridgeNode):
                node.close()
            node.destroy_node()
        try_shutdown()


__all__ = ["BridgeNode", "Level", "Report", "float_list", "interrupt_on_signals", "spin_node"]
