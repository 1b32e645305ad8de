"""The one guard for jog / velocity command streams (the deadman).

A stream is a topic that sets a speed until told otherwise: stepper ``~/motor_<n>/jog``,
MOTEC ``~/cmd_velocity``. Each stream key (a motor number, a drive) has the same rules:

- only the newest command counts: commands are ``offer``ed as they arrive and coalesce (a
  newer value replaces one not yet written), and the writer ``take``s what is ``ready``;
  a repeat of the value being commanded writes nothing;
- non-zero values are written at most once per ``min_interval_s`` per stream (what the
  bus can carry); a 0 is ready at once;
- 0 stops (once: further 0s write nothing until something moves again; see
  ``stop_when_idle`` for a 0 to a stream that commanded nothing);
- after a halt (``stop_all``), a stop by a service or an e-stop the stream is *locked*;
  it moves again only on a value that cannot surprise (``settles``), never because it
  fell silent, nor because messages were refused meanwhile: a jog / velocity
  stream on a 0; a position stream on a target ``near`` where the joint stands (judged by
  the caller, ``joint_commands``: within its unlock tolerance of the newest published
  position) that the controller *holds* (it repeats the stream's previous arrival) or
  that comes after ``timeout_s`` of silence (a new trajectory, not one that ran on
  through the stop). Arrivals the node refused before the guard count as arrivals
  (``hear``): a controller that published through a deactivate was never silent. The
  unlock is decided on arrival and sticks until the writer takes a value (values that
  coalesce keep it); a lock that comes later voids it;
- a write that failed on the link leaves a *stop pending*: the motor may be running, so
  the deadman keeps sending the stop until one is acknowledged;
- the deadman stops any stream that was silent for ``timeout_s``, counted from the
  newest command's arrival (not from when it was handled);
- ``stop_all()`` (deactivate, exit, ``read_only``, a fatal error) drops every offered value,
  locks every stream (as a service stop does) and stops every stream that may be moving:
  a value that arrived before the halt can never restart the motor after it;
- ``permit()`` (set by the node) is asked under the guard's lock before every non-zero
  write: a write already queued when the node stopped accepting commands is refused.

A position stream (``joint_commands``, docs/ros2_control.md) is a guard with
``zero_stops=False``: every value is a target, 0 included; only the deadman, a halt or a
stop service stops it, and a target held where the joint stands (above) unlocks it. It
``follow``s the joint's velocity guard: one lock for both, and every takeover of the
velocity stream (a stop service, an e-stop, a mode change) is the position stream's too. A
``send`` that cannot go yet (the device still runs the stream's previous target) raises
``Deferred``: nothing was written and the value waits for the next pass.

The guard knows no device: ``send(key, value, previous)`` writes a non-zero speed (the
previous one commanded, or ``None`` when unknown, e.g. after a lost write or a
reconnect), ``stop(key)`` writes the stop. Both raise ``LinkError`` when the link fails.
Plain Python with an injectable clock. Every operation holds the guard's lock (a stop
from a parameter change or shutdown never interleaves with a command's writes).
"""

from __future__ import annotations

import functools
import math
import threading
import time
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from ..wire.errors import BridgeError, CommandRejected, LinkError

Key = TypeVar("Key", bound=Hashable)

# Least pause between two tries of a pending stop, from the end of one to the start of the
# next: a stop repeated over a dead line must leave the shared bus to the live devices.
STOP_RETRY_GAP_S = 0.05
# The range of a stream's deadman silence, the live parameter ``command_timeout_s`` (a
# modbus_bridge command topic's ``<name>_timeout_s``) of every bridge.
COMMAND_TIMEOUT_RANGE_S = (0.05, 60.0)
Result = TypeVar("Result")


class Deferred(Exception):
    """Raised by a guard's ``send`` that wrote nothing because the device is still busy
    with the stream's own previous value: the value is offered again (unless a newer one
    came) and tried at the next pass of the writer, never counted as a refusal."""


@dataclass
class StreamState:
    """What the guard knows of one stream."""

    value: float | None = None  # last non-zero value written (None: unknown / not moving)
    active: bool = False  # a non-zero command is in force (or may be: see stop_pending)
    locked: bool = False  # stopped by a halt or a service: refuse motion until it settles
    # A value that settles the stream (``StreamGuard.settles``) arrived and no lock came
    # since: the writer's next ``command`` unlocks the stream (decided on arrival).
    settled: bool = False
    heard: float | None = None  # clock() of the last arrival, refused ones included
    arrived: float | None = None  # the value of the last arrival offered (None: refused)
    stop_pending: bool = False  # a stop is on the wire or was lost: until one is acknowledged
    stop_sent: bool = False  # a stop was acknowledged since the last motion
    last_seen: float | None = None  # clock() of the last command received
    offered: float | None = None  # the newest command received and not yet applied
    # The newest value taken for the writer, in the units offered (a topic's rad/s where
    # the guard holds rpm): what ``offer`` compares with to see a repeat. Comparing with
    # ``value`` (the guard's units) saw none, so a constant flood woke the writer, and
    # the executor, once per message.
    taken: float | None = None
    last_send: float = -math.inf  # clock() of the last non-zero value written
    last_stop_try: float = -math.inf  # clock() when the last stop attempt ended

    @property
    def may_move(self) -> bool:
        """The deadman's cue: moving under this stream, or possibly so."""
        return self.active or self.stop_pending

    def silent(self, now: float, timeout_s: float) -> bool:
        """No command for ``timeout_s`` (or none ever): the deadman's and the lock's rule."""
        return self.last_seen is None or now - self.last_seen > timeout_s

    def set_locked(self) -> None:
        """Refuse motion until a value settles it; a value that arrived before the lock
        cannot undo it (``settled`` is void)."""
        self.locked, self.settled = True, False


def _locked(method: Callable[..., Result]) -> Callable[..., Result]:
    @functools.wraps(method)
    def locked(self: StreamGuard[Any], *args: Any, **kwargs: Any) -> Result:
        with self.lock:
            return method(self, *args, **kwargs)

    return locked


class StreamGuard(Generic[Key]):
    def __init__(
        self,
        keys: Iterable[Key],
        send: Callable[[Key, float, float | None], None],
        stop: Callable[[Key], None],
        *,
        timeout_s: float,
        stop_when_idle: bool = True,
        min_interval_s: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
        after_stop: Callable[[list[Key]], None] | None = None,
        permit: Callable[[], str | None] | None = None,
        zero_stops: bool = True,
    ) -> None:
        # after_stop(keys): called (under the lock) once the stops of ``stop`` or
        # ``stop_all`` were acknowledged, with the keys stopped (``stop_all``: after every
        # stop, so follow-up writes never delay another stream's stop). It must not raise:
        # the stops already happened (the stepper restores speeds its jogs changed).
        self._after_stop = after_stop
        # stop_when_idle: the first 0 of a stream that commanded nothing still sends the
        # stop (the stepper: the motor may run from a service); False: a 0 only ends the
        # stream's own motion (MOTEC: 0xAE is also a position move's speed limit).
        self.stop_when_idle = stop_when_idle
        # zero_stops: a 0 command is the stream's stop (jog, velocity); False: a 0 is a
        # value like any other (a position target).
        self.zero_stops = zero_stops
        # Guards that mirror this one's takeovers (``follow``: a joint's position stream).
        self._followers: list[StreamGuard[Key]] = []
        self._send = send
        self._stop = stop
        # permit(): None while non-zero values may be written, else the reason they may
        # not (the node: inactive, read_only). Asked under ``lock``, so a halt that holds
        # the lock (``stop_all``) and a write never interleave.
        self.permit = permit
        self.timeout_s = timeout_s
        self._clock = clock
        self.streams: dict[Key, StreamState] = {key: StreamState() for key in keys}
        self.lock = threading.RLock()
        self.min_interval_s = min_interval_s
        # Arrivals take only this lock, never ``lock`` (held through a write on the wire):
        # a command arriving while another is written is recorded at once.
        self._inbox_lock = threading.Lock()

    def follow(self, leader: StreamGuard[Key]) -> None:
        """Share ``leader``'s lock and mirror its ``taken_over`` / ``hold`` /
        ``stop_failed`` for the same key, where this guard has it (call before the guards
        are used): a stop service or a mode change that takes the leader's stream over
        takes this one's too, and no write of one interleaves with a stop of the other."""
        self.lock = leader.lock
        leader._followers.append(self)

    def _following(self, key: Key) -> list[StreamGuard[Key]]:
        """The followers that have a stream ``key`` (a takeover of it is theirs too)."""
        return [follower for follower in self._followers if key in follower.streams]

    def _is_stop(self, value: float | None) -> bool:
        return self.zero_stops and value == 0

    def __getitem__(self, key: Key) -> StreamState:
        try:
            return self.streams[key]
        except KeyError:
            raise CommandRejected(f"no stream {key!r}") from None

    # ------------------------------------------------------------ commands
    def settles(self, stream: StreamState, value: float, near: bool, now: float) -> bool:
        """The one rule of a locked stream (call under ``_inbox_lock``, before the arrival
        is recorded): ``value`` cannot surprise. A jog / velocity stream: a 0. A position
        stream: a target ``near`` where the joint stands that the controller holds (the
        same as the stream's previous arrival) or that starts anew after ``timeout_s``
        of silence (arrivals refused before the guard count: ``hear``)."""
        if self.zero_stops:
            return value == 0
        held = stream.arrived is not None and value == stream.arrived
        quiet = stream.heard is None or now - stream.heard > self.timeout_s
        return near and (held or quiet)

    def hear(self, key: Key) -> None:
        """A command for the stream arrived and was refused before the guard (the node
        inactive, read_only, the link down, a bad message): not silence, and not a value
        the next one repeats."""
        stream = self[key]
        now = self._clock()
        with self._inbox_lock:
            stream.heard, stream.arrived = now, None

    def offer(self, key: Key, value: float, *, near: bool = False) -> bool:
        """A command arrived: it replaces any value of the stream not yet applied, and the
        deadman counts from now. ``near``: a position target within the unlock tolerance
        of where the joint stands (``settles``). True when it may be applied at once (wake
        the writer); False when it waits for the rate limit or repeats the value in force
        (the writer's periodic pass takes it)."""
        stream = self[key]
        now = self._clock()
        with self._inbox_lock:
            settles = self.settles(stream, value, near, now)
            # Values that coalesce keep an unlock that came before them (not yet taken).
            stream.settled = settles or (stream.offered is not None and stream.settled)
            stream.offered = value
            stream.last_seen = stream.heard = now
            stream.arrived = value
            repeat = (
                stream.active
                and not stream.stop_pending
                and stream.value is not None
                and value in (stream.value, stream.taken)
            )
            return self._may_write(stream, now) and not repeat

    def ready(self) -> list[Key]:
        """Streams with an offered value that may be applied now: a 0 at once, any other
        value once ``min_interval_s`` passed since the stream's last write."""
        now = self._clock()
        with self._inbox_lock:
            return [key for key, stream in self.streams.items() if self._may_write(stream, now)]

    def _may_write(self, stream: StreamState, now: float) -> bool:
        """The rate rule for the stream's offered value (call under ``_inbox_lock``)."""
        if stream.offered is None:
            return False
        return self._is_stop(stream.offered) or now - stream.last_send >= self.min_interval_s

    def take(self, key: Key) -> float | None:
        """The stream's newest offered value (None if there is none), now no longer offered."""
        stream = self[key]
        with self._inbox_lock:
            value, stream.offered = stream.offered, None
            if value is not None:
                stream.taken = value
        return value

    @_locked
    def command(self, key: Key, value: float, *, refuse_reason: str = "") -> bool:
        """Apply the newest command of a stream; True if anything was written."""
        stream = self[key]
        settled, stream.settled = stream.settled, False
        if self._is_stop(value):
            stream.locked = False
            if not stream.may_move and (stream.stop_sent or not self.stop_when_idle):
                return False
            self.stop(key)
            return True
        if stream.locked and settled:
            stream.locked = False  # a value that cannot surprise arrived (``settles``)
        if stream.locked:
            unlock = (
                "send 0"
                if self.zero_stops
                else "hold a target where the joint stands (or send one after "
                "command_timeout_s of silence)"
            )
            raise CommandRejected(
                refuse_reason or f"the motion was stopped: {unlock} before commanding it again"
            )
        refusal = self.permit() if self.permit is not None else None
        if refusal:
            raise CommandRejected(refusal)
        if stream.active and not stream.stop_pending and stream.value == value:
            return False
        previous = stream.value if stream.active else None
        stream.last_send = self._clock()  # an attempt counts: a dead link is not flooded
        try:
            self._send(key, value, previous)
        except Deferred:
            with self._inbox_lock:
                if stream.offered is None:
                    stream.offered = value  # the newest still: tried at the next pass
            return False
        except LinkError:
            # The write may or may not have landed: the motor may be turning.
            stream.value, stream.active, stream.stop_pending = None, True, True
            raise
        stream.value, stream.active = value, True
        stream.stop_pending, stream.stop_sent = False, False
        return True

    @_locked
    def stop(self, key: Key) -> bool:
        """Send the stream's stop now (a 0 command, the deadman, shutdown)."""
        self._stop_one(key)
        self._stopped([key])
        return True

    def _stopped(self, keys: list[Key]) -> None:
        if self._after_stop is not None:
            self._after_stop(keys)

    def _stop_one(self, key: Key) -> None:
        # The lock is left as it is: a stop sent again after a stop service failed keeps
        # the stream locked (only a value that settles it unlocks it, in ``command``).
        stream = self[key]
        # Pending from the first attempt on (not only once it failed): a reconnect that
        # looks for pending stops while this one is on the wire waits for it, then tries.
        stream.stop_pending = True  # until a stop is acknowledged: the deadman keeps on it
        try:
            self._stop(key)
        finally:
            stream.last_stop_try = self._clock()
        stream.value, stream.active = None, False
        stream.stop_pending, stream.stop_sent = False, True

    @_locked
    def taken_over(self, key: Key, *, locked: bool) -> None:
        """Another command (a service, an e-stop, a mode change) now owns the motion.

        The stream forgets what it commanded, so its next command is sent whole; with
        ``locked`` (a stop) motion commands are refused until a value settles it.
        """
        stream = self[key]
        stream.value, stream.active, stream.stop_sent = None, False, False
        stream.stop_pending = False
        if locked:
            stream.set_locked()
        else:
            stream.locked = False
        for follower in self._following(key):
            follower.taken_over(key, locked=locked)

    @_locked
    def hold(self, key: Key) -> None:
        """Another command stopped the device without writing this stream's own register
        (a stop coil, a stop of other registers): motion commands are refused until a value
        settles it, and what the stream commanded is kept (it may still be moving: a 0, the
        deadman or the stop after a refused command still sends its own stop)."""
        self[key].set_locked()
        for follower in self._following(key):
            follower.hold(key)

    @_locked
    def stop_failed(self, key: Key) -> None:
        """Another command's stop (a stop service, an e-stop) failed on the link: the
        stream is locked, and if it may be moving its own stop is pending (sent before any
        poll when the link is back, and by the deadman meanwhile), as after a lost
        deadman stop. Never ``taken_over``: that would forget a motor still running."""
        stream = self[key]
        stream.set_locked()
        if stream.may_move:
            stream.stop_pending = True
        for follower in self._following(key):
            follower.stop_failed(key)

    @_locked
    def forget_values(self) -> None:
        """The device may hold other speeds (reconnect): send the next command whole.

        A stream that was moving stays ``active``, so the deadman stops it once the link
        is back.
        """
        for stream in self.streams.values():
            stream.value = None

    # ------------------------------------------------------------ deadman
    @_locked
    def due(self) -> list[Key]:
        """Streams the deadman must act on: a stop pending (again once ``STOP_RETRY_GAP_S``
        passed since the last try ended, until one is acknowledged), or moving and silent
        for timeout_s."""
        now = self._clock()
        due: list[Key] = []
        for key, stream in self.streams.items():
            if not stream.may_move:
                continue
            if stream.stop_pending:
                if now - stream.last_stop_try >= STOP_RETRY_GAP_S:
                    due.append(key)
            elif stream.silent(now, self.timeout_s):
                due.append(key)
        return due

    def pending_stops(self) -> list[Key]:
        """Streams whose stop is on the wire or was lost, and not acknowledged since."""
        return [key for key, stream in self.streams.items() if stream.stop_pending]

    @_locked
    def expire(self, key: Key) -> bool:
        """The deadman for one stream ``due``: stop it if it may move. A lock is kept:
        silence never unlocks a stream (messages the node refused while inactive once
        looked like silence, and a controller that kept publishing restarted the motor).
        A stop only pending (commands still coming) is sent again.

        A silent stream's value still offered (held back by the rate limit, or ``Deferred``)
        is dropped: it is older than ``timeout_s`` and must not restart the motor after the
        deadman's stop. An offered stop is kept.

        True if a stop was sent (and acknowledged).
        """
        stream = self[key]
        if stream.silent(self._clock(), self.timeout_s):
            with self._inbox_lock:
                if not self._is_stop(stream.offered):
                    stream.offered = None
        if not stream.may_move:
            return False
        return self.stop(key)

    def idle(self) -> bool:
        """Nothing for the writer or the deadman: no value offered, no stream that may
        move (a stop pending counts). A stream that is only locked is idle: only an
        arrival unlocks it (``offer``)."""
        with self._inbox_lock:
            return all(s.offered is None and not s.may_move for s in self.streams.values())

    def moving(self) -> list[Key]:
        return [key for key, stream in self.streams.items() if stream.may_move]

    @_locked
    def halt(self) -> None:
        """Every stream locked (until a value settles it) and every offered non-zero value
        dropped; an offered 0 is kept (it is a stop someone asked for)."""
        with self._inbox_lock:
            for stream in self.streams.values():
                if not self._is_stop(stream.offered):
                    stream.offered = None
                stream.set_locked()

    @_locked
    def stop_all(self) -> list[tuple[Key, BridgeError]]:
        """Stop every stream that may move; every stop is tried. Returns the failures.

        First every offered non-zero value is dropped and every stream locked
        (``halt``: until a value settles it, as after a service stop): a value
        offered before the halt is never written after it, and a joystick still held when
        the node comes back cannot restart the motor. ``after_stop`` runs once, after all
        of them (also when none was moving).
        """
        self.halt()
        failures: list[tuple[Key, BridgeError]] = []
        stopped: list[Key] = []
        for key in self.moving():
            try:
                self._stop_one(key)
                stopped.append(key)
            except BridgeError as err:
                failures.append((key, err))
        self._stopped(stopped)
        return failures


__all__ = ["Deferred", "StreamGuard", "StreamState"]
