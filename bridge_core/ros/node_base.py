"""The rclpy node base every bridge shares: ``BridgeNode``.

What it gives a bridge: the common parameters (``node_parameters``), the link and its
channel (or a channel on a bus someone else owns), the poller (``bridge_core.runtime.poller``: its
own thread, pacing, re-plan on device exceptions, a publisher thread), ``joint_states`` /
``~/connected`` / ``/diagnostics``, the stale-data policy (no fresh stamps while the link
is down), the lifecycle, and the command guard that refuses, writing nothing, when the
link is down or ``read_only`` is set, and turns device errors into a clear ``message``.
Its command services (``node_services``), command streams (``node_streams``) and action
goals (``node_actions``) go through that guard, each a host on the node (``command_services``,
``streams``, ``actions``); ``process`` spins the nodes.

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
import threading
import time
import traceback
from collections.abc import Callable, Hashable, Iterable, Sequence
from typing import Any, Generic, TypeVar

from rclpy.callback_groups import (
    MutuallyExclusiveCallbackGroup,
)
from rclpy.lifecycle import LifecycleState, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from ..runtime.checks import bounded_text
from ..runtime.diagnostics import Report
from ..runtime.joint_commands import Gate, RefusalCounts, gate_of
from ..runtime.keepalive import Keepalive
from ..runtime.motion_ledger import MotionLedger
from ..runtime.parameters import DeviceDefaults, bridge_specs
from ..runtime.poller import Poller, PollOutcome
from ..runtime.rate_groups import PollGroups
from ..runtime.wire_budget import WireBudget
from ..wire.channel import DeviceChannel, Priority
from ..wire.errors import CommandRejected, DeviceException, LinkError, NotConfirmed, NotSent
from ..wire.link_state import LinkEvent
from ..wire.transport import ModbusLink
from .node_actions import ActionHost
from .node_diagnostics import DiagnosticsPublisher
from .node_parameters import ParameterNode, link_settings
from .node_services import ServiceHost
from .node_streams import StreamHost
from .node_wire import WirePublisher, wire_publisher

T = TypeVar("T")
SnapshotT = TypeVar("SnapshotT")
LINK_DOWN_LOG_PERIOD_S = 10.0  # while a device stays down, say so this often on the console
# How long a halt waits for a command that was past its guards (on the wire) to finish.
HALT_COMMAND_WAIT_S = 30.0
JOINT_STATES_DEPTH = 10
# What a poll reports of a link that failed: said as INFO once the process is exiting.
EXIT_LINK_OUTCOMES = (PollOutcome.LINK_LOST, PollOutcome.UNREACHABLE, PollOutcome.STILL_DOWN)


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
        self.streams = StreamHost(self)  # command topics with a deadman (streams.topic)
        # ~/joint_commands refusals by kind (diagnostics), of this node's topic or of the
        # topic of the bus owner that commands its joints (MOTEC).
        self.joint_command_refusals: RefusalCounts | None = None
        # Motions services started (fire-and-forget): stopped by a halt like the streams'.
        self.service_motions = MotionLedger()
        # Services made from the interface rows (command_services.create).
        self.command_services = ServiceHost(self, LINK_DOWN_LOG_PERIOD_S)
        self._command_mutex = threading.RLock()  # one command (not stop) at a time
        # Set before a halt (deactivate, shutdown, error, exit) stops anything, cleared on
        # activate: a command or stream value that waited for its turn while the halt ran
        # is refused instead of restarting what the halt stopped.
        self._halted = False
        # The process is leaving (its signal came, or ``close``): a link lost from now on
        # was most likely closed by the same exit (the cell's simulators get the same
        # Ctrl-C), not an error; ``_poll_report`` says it as INFO. ``exit_signalled``
        # (set by ``process``): a signal to exit reached the process and its handler has
        # not run yet (a simulator may close the link before it does).
        self.exiting = False
        self.exit_signalled: Callable[[], bool] = lambda: False
        self._exit_link_said = False

        values = self.declare_specs(bridge_specs(defaults, owns_link=link is None))
        self.joint_prefix = str(values["joint_prefix"])
        self.autostart = bool(values["autostart"])
        self.frame_id = str(values["frame_id"])
        self.read_only = bool(values["read_only"])
        self.channel = self._open_channel(defaults, values, link, unit_id)
        self.hardware_id = f"{self.device_name}@{self.channel.describe()}"

        self._create_link_publishers()
        self.actions = ActionHost(self)
        self._create_poller(float(values["poll_rate_hz"]), node_name)
        self.on_parameter("read_only", self._set_read_only)
        # What the polls ask of the wire: said once at start and after a rate change.
        self.wire_budget = WireBudget(self.channel, self.poll_groups, lambda: self.poller.rate_hz)
        self._budget_subject = f"{self.device_name} on {self.channel.describe()}"  # its WARN
        self.line_load: Callable[[], str] | None = None  # set by the owner of a shared line
        self.on_parameter("poll_rate_hz", self._set_poll_rate)
        self.slow_poll_period_s = float(values["slow_poll_period_s"])  # the device's start value
        self.on_parameter("slow_poll_period_s", self._set_slow_poll_period)
        # Start polling once the executor runs, i.e. after the subclass finished __init__.
        self._poll_starter = self.create_timer(0.0, self._start_polling)
        self.diagnostics = DiagnosticsPublisher(self, float(values["diagnostic_period_s"]))
        self.on_parameter("diagnostic_period_s", self.diagnostics.set_period)

    def _open_channel(
        self,
        defaults: DeviceDefaults,
        values: dict[str, Any],
        link: ModbusLink | None,
        unit_id: int | None,
    ) -> DeviceChannel:
        """The device's channel: on a link of its own, opened from its transport
        parameters, or on the ``link`` it was given (a bus's, never closed here)."""
        self._owned_link: ModbusLink | None = None
        # ~/wire (record_wire): of the link's owner; a bus owner lends it (watch_line).
        self.wire: WirePublisher | None = None
        if link is None:
            self.wire = wire_publisher(self, values)
            tap = self.wire.callback if self.wire is not None else None
            link = self._owned_link = ModbusLink(link_settings(values), wire=tap)
            unit_id = int(values["unit_id"])
        if unit_id is None:
            raise ValueError("a node on a shared link needs its unit_id")
        self.link = link
        stop_timeout_s = defaults.stop_timeout_s
        if stop_timeout_s is not None:
            stop_timeout_s = min(stop_timeout_s, link.settings.timeout_s)
        return DeviceChannel(
            link,
            unit_id,
            retries=int(values["retries"]),
            reconnect_max_s=float(values["reconnect_max_s"]),
            down_write_timeout_s=stop_timeout_s,
            max_in_flight=int(values.get("max_in_flight", 1)),
        )

    def _create_link_publishers(self) -> None:
        """``joint_states`` and the latched ``~/connected`` (false until a poll answers)."""
        self.joint_states_pub = self.create_publisher(
            JointState, "joint_states", JOINT_STATES_DEPTH
        )
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self.connected_pub = self.create_publisher(Bool, "~/connected", latched)
        self._connected_published: bool | None = None
        self._connected_lock = threading.Lock()
        self._down_said_at = 0.0  # monotonic time the console last said the link is down
        self._publish_connected(False)

    def _create_poller(self, rate_hz: float, node_name: str) -> None:
        """The poller, paused until the node is active, and told of the link's edges."""
        self.poller: Poller[tuple[float, SnapshotT]] = Poller(
            self.channel,
            self._poll,
            self._publish,
            rate_hz=rate_hz,
            link_up=self._link_up,
            replan=self.replan,
            report=self._poll_report,
            name=node_name,
        )
        # After the poller's: a loss is said on the console before ~/connected goes false.
        self._unlisten = self.channel.link_state.add_listener(self._link_changed)
        self.poller.pause()  # polls and publishes only while the node is active (lifecycle)

    # ------------------------------------------------------------ for subclasses
    def param(self, name: str) -> Any:
        return self.get_parameter(name).value

    def command_gate(self) -> Gate:
        """``~/joint_commands``' view of this node's command guard: whether it is active,
        under ``read_only``, connected (``bridge_core.runtime.joint_commands.gate_of``)."""
        return gate_of(
            lambda: self.active,
            lambda: self.read_only,
            lambda: self.channel.connected,
            self.get_name(),
        )

    def start_keepalive(
        self, what: str, next_feed: Callable[[], float | None], feed: Callable[[], None]
    ) -> Keepalive:
        """A device watchdog (``what``: its name in the manual) fed from a thread of its
        own, not an executor timer (``bridge_core.runtime.keepalive``); the caller closes it."""
        keepalive = Keepalive(
            f"{self.get_name()}-{what}",
            next_feed,
            feed,
            lambda err: self.get_logger().error(f"{what} feed failed: {err}"),
        )
        keepalive.start()
        return keepalive

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
        self.streams.send_pending_stops()
        self.command_services.send_pending_stops()
        self.on_link_up()

    def poll_groups(self) -> PollGroups:
        """The device's rate groups (``slow_poll_period_s`` sets their period)."""
        raise NotImplementedError

    def _set_poll_rate(self, rate_hz: float) -> None:
        self.poller.rate_hz = rate_hz
        self.wire_budget.rearm()

    def _set_slow_poll_period(self, period_s: float) -> None:
        self.slow_poll_period_s = period_s
        self.poll_groups().period_s = period_s
        self.wire_budget.rearm()

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
        snapshot = self.wire_budget.around(self.poll_device)
        warning = self.wire_budget.warning(self._budget_subject)
        if warning is not None:
            self.get_logger().warning(warning)
        for news in self.channel.pipelining.news():  # a fallback, said once
            self.get_logger().warning(news)
        return began, snapshot

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
        if outcome in EXIT_LINK_OUTCOMES and (self.exiting or self.exit_signalled()):
            if not self._exit_link_said:  # once: the polls that follow fail alike
                self._exit_link_said = True
                logger.info(f"link to {self.channel.describe()} closed while exiting: {text}")
            return
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

    def _link_changed(self, event: LinkEvent, _text: str) -> None:
        """The channel's link went up (a good poll after a (re)connect) or down (whatever
        lost it): ``~/connected`` follows."""
        self.actions.wake_all()  # a goal ends at once when its link is lost
        if event is LinkEvent.UP:
            self.get_logger().info(f"connected to {self.channel.describe()}")
        self._publish_connected(event is LinkEvent.UP)

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
            # must go out on whatever link there is now. A link it loses is announced by
            # the channel, named after the command.
            with (
                self.channel.labelled(what),
                contextlib.nullcontext() if stop else self.channel.command_session(),
            ):
                result = action()
        except CommandRejected as err:
            return False, f"{what} refused: {bounded_text(str(err))}", None
        except NotConfirmed as err:
            return False, f"{what}: not confirmed: {bounded_text(str(err))}", None
        except DeviceException as err:
            return False, f"{what}: the device answered {bounded_text(str(err))}", None
        except LinkError as err:
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
            text = bounded_text(str(err))
            self.get_logger().error(f"{what} failed: {text}\n{traceback.format_exc()}")
            return False, f"{what} failed: internal error: {text}", None
        return True, f"{what}: done", result

    def stop_motion(self, reason: str = "the node stops") -> None:
        """Stop everything this node's streams, services and action goals started; tried on
        the wire even while the link is marked down (no connected guard, no command
        session). Each part is tried whatever another raised; the streams' and services'
        stops go before the goals' (whose stop may wait for a start on the wire)."""
        self.streams.stop_all()
        self.command_services.stop_all(reason)
        try:
            self.actions.stop_all(reason)
        except Exception as err:
            self.get_logger().error(f"stopping action goals failed: {err}")

    def close(self) -> None:
        """Stop motion, then polling, then close the link if this node opened it."""
        self.exiting = True
        self._halted = True  # nothing but stops from here on
        try:
            self.stop_motion("the node is exiting")
            self._wait_for_command_on_the_wire()
        finally:
            self.poller.stop()
            self._unlisten()
            self._close_owned_link()
            if self._owned_link is not None and self.wire is not None:
                self.wire.close()  # not on cleanup: a configure after it polls again


def copy_fields(msg: Any, source: Any, names: Iterable[str]) -> Any:
    """Copy same-named fields from a snapshot into a message (tuples become lists)."""
    for name in names:
        value = getattr(source, name)
        setattr(msg, name, list(value) if isinstance(value, tuple) else value)
    return msg


__all__ = ["BridgeNode", "copy_fields"]
