"""Command streams of the bridge nodes: jog / velocity topics and their deadman.

Part of the node base (imports rclpy). ``StreamHost`` puts the ``bridge_core.runtime.stream_guard``
guards of one node behind its command topics, like ``node_actions.ActionHost`` does for
action goals: arrivals are recorded on the node's inbox thread (``inbox.py``), values are
written through the node's command guard (``BridgeNode.run_command``), and a timer stops
streams that fell silent (it runs only while a guard has something to watch). The node's
halts stop every stream through ``stop_all``.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

from rclpy.timer import Timer

from ..runtime.stream_guard import StreamGuard
from ..wire.errors import DeviceException, NotConfirmed

if TYPE_CHECKING:
    from .node_base import BridgeNode

T = TypeVar("T")
# The deadman looks every command_timeout_s / DEADMAN_CHECKS (within these bounds): its
# stop comes at most one period after the timeout (the goal: within command_timeout_s and
# one bus transaction of the last message; docs/behaviour.md, "Command streams").
DEADMAN_CHECKS = 20
DEADMAN_PERIOD_MIN_S = 0.01
DEADMAN_PERIOD_MAX_S = 0.05
STREAM_DEPTH = 1  # command streams: only the newest message matters
# What a 0 that found nothing to stop says while the node is inactive (it once said
# "refused", though a stop always goes and nothing needed writing).
NOTHING_MOVED = "nothing was moving, nothing written (the node is not active)"


class StreamHost:
    """The command streams of one bridge node: their topics, writers and deadman."""

    def __init__(self, node: BridgeNode[Any]) -> None:
        self.node = node
        self.guards: list[StreamGuard[Any]] = []
        self.refusals = 0  # stream commands refused (diagnostics)
        self._wakers: dict[int, Callable[[], None]] = {}  # id(guard) -> its writer's trigger
        # id(guard) -> its deadman timer, cancelled while the guard is idle (nothing offered,
        # nothing that may move): ~40 executor passes a second per guard saved, which on a
        # MOTEC bus of three drives (two guards each) were most of the idle bridge's CPU.
        # An arrival resets it; the lock orders "idle, so cancel" against "offered, so reset".
        self._timers: dict[int, Timer] = {}
        self._sleep_lock = threading.Lock()

    def topic(
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
        value per stream, the deadman counts from its arrival) on the node's inbox thread
        (``inbox.py``) with a depth-1 subscription, so a flood costs no bus time, never
        waits behind a write and never runs the executor's loop. The writer (``stream``)
        applies what the guard says is ``ready``.
        """
        self.stream(
            guard,
            what,
            convert=convert,
            timeout_parameter=timeout_parameter,
            rate_parameter=rate_parameter,
        )
        for key, topic in topics.items():
            self.node.inbox.subscribe(
                msg_type, topic, self._callback(guard, key, value_of), STREAM_DEPTH
            )

    def stream(
        self,
        guard: StreamGuard[T],
        what: Callable[[T, float], str],
        *,
        convert: Callable[[T, float], float] = lambda _key, value: value,
        timeout_parameter: str = "command_timeout_s",
        rate_parameter: str = "command_rate_hz",
        stop_what: Callable[[T], str] | None = None,
    ) -> None:
        """The writer and deadman of one guard, fed by ``offer`` (its topics, or
        ``~/joint_commands``: ``bridge_core.ros.joint_commands``).

        The writer runs in the command group, woken by an arrival that may be applied at
        once and by the deadman timer: it applies what the guard says is ``ready`` (a 0
        at once, other values at most ``rate_parameter`` times a second per stream)
        through the command guard (a refused value stops what the stream had started).
        The timer also stops streams that fell silent. Both parameters are live;
        ``stop_all()`` stops every stream. ``convert`` checks a value and turns it into
        the guard's units (inside the command guard: a bad value is a refusal, not an
        exception in a callback). ``stop_what(key)`` names the stream's stop in logs
        (default ``what(key, 0.0)``: a 0 is the stop of a jog or velocity stream).
        """
        node = self.node
        stopping: Callable[[T], str] = stop_what or (lambda key: what(key, 0.0))
        self.guards.append(guard)
        guard.permit = self._permit

        def write_ready() -> None:
            self._write_ready(guard, convert, what, stopping)

        writer = node.create_guard_condition(write_ready, callback_group=node.command_group)
        self._wakers[id(guard)] = writer.trigger

        def period() -> float:
            return min(
                DEADMAN_PERIOD_MAX_S, max(DEADMAN_PERIOD_MIN_S, guard.timeout_s / DEADMAN_CHECKS)
            )

        def tick() -> None:
            write_ready()  # values held back by the rate limit
            self._deadman(guard, stopping)
            with self._sleep_lock:
                if guard.idle():
                    timer.cancel()  # nothing to watch: ``offer`` wakes it

        timer = node.create_timer(period(), tick, callback_group=node.command_group)
        self._timers[id(guard)] = timer

        def set_timeout(value: float) -> None:
            guard.timeout_s = float(value)
            timer.timer_period_ns = int(period() * 1e9)
            timer.reset()

        def set_rate(rate_hz: float) -> None:
            guard.min_interval_s = 1.0 / float(rate_hz)

        node.on_parameter(timeout_parameter, set_timeout)
        node.on_parameter(rate_parameter, set_rate)
        set_timeout(node.param(timeout_parameter))
        set_rate(node.param(rate_parameter))

    def offer(self, guard: StreamGuard[T], key: T, value: float, near: bool = False) -> None:
        """A command arrived for ``guard``'s stream ``key``: recorded at once (any thread);
        the writer is woken when it may be applied now, else the deadman timer's pass
        applies it (a flood wakes the writer at most command_rate_hz times a second, not
        per message). ``near``: a position target where the joint stands
        (``StreamGuard.settles``)."""
        with self._sleep_lock:
            wake = guard.offer(key, value, near=near)
            timer = self._timers[id(guard)]
            if timer.is_canceled():
                timer.reset()
                wake = True  # the executor may wait without the timer: it takes it anew
        if wake:
            self._wakers[id(guard)]()

    def _permit(self) -> str | None:
        """Asked by a stream guard, under its lock, before every non-zero write."""
        if not self.node.active:
            return "the node is not active (lifecycle): nothing was written"
        if self.node.read_only:
            return "read_only is set, nothing was written"
        return None

    def _callback(
        self, guard: StreamGuard[T], key: T, value_of: Callable[[Any], float]
    ) -> Callable[[Any], None]:
        def arrived(msg: Any) -> None:
            self.offer(guard, key, value_of(msg))

        return arrived

    def _write_ready(
        self,
        guard: StreamGuard[T],
        convert: Callable[[T, float], float],
        what: Callable[[T, float], str],
        stopping: Callable[[T], str],
    ) -> None:
        for key in guard.ready():
            value = guard.take(key)
            if value is None:
                continue
            a_stop = guard.zero_stops and value == 0
            # A 0 is a stop: it always goes (inactive, link down), as the deadman's; under
            # read_only only when the stream may move (its own motion: read_only writes
            # nothing else, not even a stepper's stop coil for an idle stream).
            ok, message, wrote = self.node.run_command(
                what(key, value),
                functools.partial(_apply, guard, key, value, convert),
                stop=a_stop,
                own_motion=a_stop and guard[key].may_move,
            )
            if not ok:
                self._refused(guard, key, message, stopping)
            elif a_stop and not wrote and not self.node.active:
                # Not "refused": there was nothing to stop.
                self.node.get_logger().info(
                    f"{what(key, value)}: {NOTHING_MOVED}", throttle_duration_sec=2.0
                )

    def _refused(
        self, guard: StreamGuard[T], key: T, message: str, stopping: Callable[[T], str]
    ) -> None:
        self.refusals += 1
        self.node.get_logger().warn(message, throttle_duration_sec=2.0)
        stream = guard[key]
        if stream.may_move and not stream.stop_pending:
            # A refused value must not leave the motor running at the previous one. A stop
            # already pending is the deadman's: it retries at its own period, not per message.
            self.node.run_command(
                f"{stopping(key)} (stop after a refused command)",
                lambda: guard.stop(key),
                stop=True,
                own_motion=True,
            )

    def _deadman(self, guard: StreamGuard[T], stopping: Callable[[T], str]) -> None:
        for key in guard.due():
            was_moving = guard[key].may_move
            ok, message, _ = self.node.run_command(
                f"{stopping(key)} (deadman)",
                functools.partial(guard.expire, key),
                stop=True,
                own_motion=True,
            )
            if not was_moving:
                continue
            if ok:
                self.node.get_logger().info(
                    f"{stopping(key)}: no command for {guard.timeout_s} s, stopped"
                )
            else:
                self.node.get_logger().warn(message, throttle_duration_sec=2.0)

    def stop_all(self) -> None:
        """Stop every stream that may be moving (the node's ``stop_motion``); a bug in one
        guard does not skip the others."""
        logger = self.node.get_logger()
        for guard in self.guards:
            try:
                moving = guard.moving()
                failed = guard.stop_all()
            except Exception as bug:  # a bug in one part must not skip the others
                logger.error(f"stopping streams failed: {bug}")
                continue
            for key, err in failed:
                if isinstance(err, NotConfirmed):  # went out, the device does not show it
                    logger.error(f"stream {key}: its stop went out, not confirmed: {err}")
                else:
                    logger.error(f"stopping stream {key} failed: {err}")
            for key in set(moving) - {key for key, _ in failed}:
                logger.info(f"stream {key}: stopped")

    def send_pending_stops(self) -> None:
        """Before the first poll after a reconnect: the stops that failed while the link
        was down. A refusal is said and polls go on; a link error propagates (still down)."""
        for guard in self.guards:
            for key in guard.pending_stops():
                try:
                    guard.stop(key)
                except DeviceException as err:  # answered: not a link fault; polls go on
                    self.node.get_logger().error(
                        f"stream {key}: the device refused its stop: {err}"
                    )
                    continue
                except NotConfirmed as err:  # answered, not shown: the deadman tries again
                    self.node.get_logger().error(
                        f"stream {key}: its pending stop went out, not confirmed: {err}"
                    )
                    continue
                self.node.get_logger().info(f"stream {key}: the pending stop was sent on reconnect")


def _apply(
    guard: StreamGuard[T], key: T, value: float, convert: Callable[[T, float], float]
) -> bool:
    """One stream command: checked and converted, then through the guard."""
    return guard.command(key, convert(key, value))


__all__ = [
    "DEADMAN_CHECKS",
    "DEADMAN_PERIOD_MAX_S",
    "DEADMAN_PERIOD_MIN_S",
    "NOTHING_MOVED",
    "STREAM_DEPTH",
    "StreamHost",
]
