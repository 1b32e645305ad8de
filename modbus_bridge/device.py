"""A described device behind one Modbus channel: polls into snapshots, commands into
checked writes (no ROS).

Every command checks all of its values against the description (register known and
writable, value a number or bool as the register wants, inside its range, fitting its
type) before its first write, so a refused command writes nothing. Writes use the function
codes the file lists: FC 05 (else 0F) for one coil, FC 06 (else 10) for one register, FC
10 for a multi-register value.

Every write is read back (decision 19, docs/decisions/modbus.md): a command reports
success only when the register, read back at once, holds what was written; otherwise it
raises ``NotConfirmed`` saying what was written and what was read ("sent, not
confirmed"), also for a write-only register, which nothing can read back.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Sequence
from contextlib import ExitStack
from dataclasses import dataclass

from bridge_core.runtime.checks import check_finite
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S, PollGroups, plan_groups
from bridge_core.runtime.reads import read_named
from bridge_core.runtime.stream_guard import StreamGuard
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value, decode, encode
from bridge_core.wire.errors import CommandRejected, LinkError, NotConfirmed
from bridge_core.wire.planner import ReadRequest
from bridge_core.wire.registers import Register, Table, ValueType

from .description import Device, Joint, JointSource, Keepalive, TopicSpec, not_allowed

# The bridge feeds a keepalive at least this many times per watchdog time (as the MOTEC
# lifeguard): one late or lost feed never trips the device.
KEEPALIVE_FEEDS_PER_PERIOD = 3
# A keepalive whose arming failed (the device refused a read or the write) tries again
# after this long, not at every look of the keepalive thread.
KEEPALIVE_ARM_RETRY_S = 1.0


@dataclass(frozen=True)
class DeviceSnapshot:
    """One poll: the values of ``state_names`` (register units) and the joints in SI."""

    read_time: float  # wall clock when the block holding the first joint's position was read
    slow_read_time: float  # wall clock when the slow group was read (0.0: none)
    names: tuple[str, ...]
    values: tuple[Value, ...]
    # One entry per joint, NaN for a joint without that register (a velocity-only
    # drive's position); empty when no joint has one (JointState's rule).
    positions: tuple[float, ...]
    velocities: tuple[float, ...]
    efforts: tuple[float, ...]


def _joint_registers(device: Device) -> list[str]:
    names: list[str] = []
    for joint in device.joints:
        for source in (joint.position, joint.velocity, joint.effort):
            if source is not None:
                names.append(source.register)
    return names


def _per_joint(sources: list[JointSource | None]) -> list[JointSource | None]:
    """One source per joint (None: NaN) if any joint has one, else none: JointState's
    arrays are empty or as long as ``name``."""
    return sources if any(s is not None for s in sources) else []


def _stamp_source(joint: Joint) -> JointSource:
    source = joint.position or joint.velocity
    assert source is not None  # the loader refuses a joint with neither
    return source


def poll_plan(device: Device) -> tuple[list[ReadRequest], list[ReadRequest], str | None]:
    """The requests of every poll (the fast group), those of the slow group (registers
    with ``poll: slow``), and the register that stamps a poll (the first joint's position;
    its block is read last, so a joint change reaches joint_states soonest)."""
    register_map = device.register_map
    slow = set(device.slow_names)
    names = list(dict.fromkeys([*device.state_names, *_joint_registers(device)]))
    fast_plan, slow_plan = plan_groups(
        register_map, [n for n in names if n not in slow], [n for n in names if n in slow]
    )
    stamp = _stamp_source(device.joints[0]).register if device.joints else None
    if stamp is not None:
        fast_plan.sort(key=lambda request: stamp in request.names)
    return fast_plan, slow_plan, stamp


class DescribedDevice:
    """Poll and command one described device through ``io`` (a ``DeviceChannel``)."""

    def __init__(
        self,
        io: RegisterIO,
        device: Device,
        clock: Callable[[], float] = time.time,
        slow_period_s: float = SLOW_POLL_PERIOD_DEFAULT_S,
    ) -> None:
        self.io = io
        self.device = device
        self.map = device.register_map
        fast, slow, self.stamp_register = poll_plan(device)
        self.groups = PollGroups(fast, slow, period_s=slow_period_s, wall_clock=clock).follow(io)
        self.functions = self.map.limits.function_codes
        self._clock = clock
        self.triggers = {t.name: t for t in device.commands.triggers}
        self.values = {v.name: v for v in device.commands.values}
        self.coils = {c.name: c for c in device.commands.coils}
        self.topics = {t.name: t for t in device.commands.topics}
        # The stream guard of each command topic (the node attaches them): a stop service
        # locks every stream.
        self.guards: dict[str, StreamGuard[str]] = {}
        # ~/joint_commands' own streams (modbus_bridge/joint_commands.py): guard, key and
        # the register each writes; locked by a stop service like the topics'.
        self.joint_guards: list[tuple[StreamGuard[str], str, str]] = []
        joints = device.joints
        # JointState: each array is empty or has one entry per name. A field some joint
        # has is published for all, NaN for a joint without it (a velocity-only drive's
        # position, a position-only joint's velocity); a field no joint has is empty.
        self._positions = _per_joint([j.position for j in joints])
        self._velocities = _per_joint([j.velocity for j in joints])
        self._efforts = _per_joint([j.effort for j in joints])
        # The trigger that stops each motion group a starts_motion trigger belongs to: the
        # node's motion ledger sends it on every way out (``BridgeNode.stop_motion``).
        self.exit_stops = device.exit_stops()
        self.keepalive = KeepaliveFeeder(io, device) if device.keepalive is not None else None

    # ------------------------------------------------------------------ polling
    def poll(self) -> DeviceSnapshot:
        read = self.groups.read(self.io, self.stamp_register)
        values = read.values

        def si(sources: Sequence[JointSource | None]) -> tuple[float, ...]:
            return tuple(
                math.nan if s is None else float(values[s.register]) * s.to_si for s in sources
            )

        names = self.device.state_names
        return DeviceSnapshot(
            read_time=read.read_time,
            slow_read_time=read.slow_read_time,
            names=names,
            values=tuple(values[name] for name in names),
            positions=si(self._positions),
            velocities=si(self._velocities),
            efforts=si(self._efforts),
        )

    def read(self, names: Sequence[str]) -> dict[str, Value]:
        """Registers by name, read now (command priority), in as few requests as allowed;
        in the order asked (each once)."""
        if not names:
            raise CommandRejected("no register names given")
        for name in names:
            register = self._register(name)
            if not register.access.readable:
                raise CommandRejected(f"{name} is write only")
        unique = list(dict.fromkeys(names))
        values = read_named(self.io, self.map, unique)
        return {name: values[name] for name in unique}  # in the order asked

    # ------------------------------------------------------------------ commands
    def _register(self, name: str) -> Register:
        if name not in self.map:
            raise CommandRejected(f"no register named {name!r}")
        return self.map[name]

    def words_for(self, name: str, value: Value) -> tuple[Register, list[int]]:
        """The checked words of one write (CommandRejected: nothing may be written)."""
        register = self._register(name)
        if not register.access.writable:
            raise CommandRejected(f"{name} is read only")
        kind = register.value_type
        if kind is ValueType.BOOL:
            if not isinstance(value, bool):
                raise CommandRejected(f"{name} takes true or false, not {value!r}")
        elif kind is ValueType.STRING:
            if not isinstance(value, str):
                raise CommandRejected(f"{name} takes a string")
        else:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise CommandRejected(f"{name} takes a number, not {value!r}")
            check_finite(name, value)
            if not kind.is_float and register.scale == 1.0 and register.offset == 0.0:
                if isinstance(value, float) and not value.is_integer():
                    raise CommandRejected(f"{name} takes a whole number, not {value}")
                value = int(value)
            if not self.device.allows(name, value):
                allowed = self.device.allowed_values[name]
                raise CommandRejected(not_allowed(name, value, allowed))
        words = encode(register, value)
        if register.table is Table.COIL:
            if not self.functions & {5, 15}:
                raise CommandRejected(f"{name}: the device lists neither FC 05 nor FC 15")
        elif not (16 in self.functions or (len(words) == 1 and 6 in self.functions)):
            needs = "FC 16" if len(words) > 1 else "FC 06 or FC 16"
            raise CommandRejected(f"{name}: needs {needs}, which the device does not list")
        return register, words

    def _send(self, register: Register, words: Sequence[int]) -> None:
        self._write_words(register, words)
        if self.keepalive is not None:
            self.keepalive.note_write(register, words)

    def _write_words(self, register: Register, words: Sequence[int]) -> None:
        if register.table is Table.COIL:
            on = bool(words[0])
            if 5 in self.functions:
                self.io.write_coil(register.address, on)
            else:
                self.io.write_coils(register.address, [on])
        elif len(words) == 1 and 6 in self.functions:
            self.io.write_register(register.address, words[0], priority=Priority.COMMAND)
        else:
            self.io.write_registers(register.address, list(words))

    def confirm(self, register: Register, words: Sequence[int], written: str) -> None:
        """Read ``register`` back now: ``NotConfirmed`` unless it holds ``words``
        (``written``: what the write said it wrote)."""
        if not register.access.readable:
            raise NotConfirmed(
                f"wrote {written}; {register.name} is write only, nothing reads it back "
                "(sent, not confirmed)"
            )
        seen = read_named(self.io, self.map, [register.name])[register.name]
        wanted = decode(register, words)
        if register.value_type is ValueType.BOOL:
            same = bool(seen) == bool(wanted)
        else:
            same = seen == wanted
        if not same:
            raise NotConfirmed(
                f"wrote {written}, read back {register.name} = {_shown(register, seen)} "
                "(sent, not confirmed)"
            )

    def _send_confirmed(self, register: Register, words: Sequence[int], value: Value) -> str:
        self._send(register, words)
        written = written_text(register, value, words)
        self.confirm(register, words, written)
        return written

    def write(self, name: str, value: Value) -> str:
        """One register or coil, checked, then read back; returns what was written
        (``written_text``). ``NotConfirmed``: the read-back does not show it."""
        register, words = self.words_for(name, value)
        return self._send_confirmed(register, words, value)

    def attach_stream(self, topic_name: str, guard: StreamGuard[str]) -> None:
        """The guard of command topic ``topic_name`` (keyed by the topic's name)."""
        if topic_name not in self.topics:
            raise CommandRejected(f"no command topic named {topic_name!r}")
        self.guards[topic_name] = guard

    def attach_joint_stream(self, guard: StreamGuard[str], key: str, register: str) -> None:
        """A ``~/joint_commands`` stream writing ``register`` (locked by stops as well)."""
        self.joint_guards.append((guard, key, register))

    def _streams(self) -> list[tuple[StreamGuard[str], str, str]]:
        """Every command stream: (guard, key, the register it writes)."""
        topics = [(g, n, self.topics[n].register_name) for n, g in self.guards.items()]
        return topics + self.joint_guards

    def _as_stop(self, registers: Collection[str], action: Callable[[], str]) -> str:
        """Run a stop service's writes with every command stream's lock held (no stream
        write between the stop and the lock). Done: every stream is locked (a joystick
        still held cannot restart the motion; a 0 or silence unlocks); the streams of
        ``registers`` are known stopped (``taken_over``), the others keep what they
        commanded (``hold``: their own stop is still sent by a 0, the deadman or a refused
        value). Lost on the link: every stream is locked and, if it may move, its own stop
        stays pending (``stop_failed``)."""
        streams = self._streams()
        with ExitStack() as held:
            for guard, _, _ in streams:
                held.enter_context(guard.lock)
            try:
                done = action()
            except (LinkError, NotConfirmed):  # the device may still move
                for guard, key, _ in streams:
                    guard.stop_failed(key)
                raise
            for guard, key, register in streams:
                if register in registers:
                    guard.taken_over(key, locked=True)
                else:
                    guard.hold(key)
            return done

    def trigger(self, name: str) -> str:
        """A named Trigger: its writes, in the file's order, all checked first. A stop
        trigger locks the command streams (``_as_stop``)."""
        if name not in self.triggers:
            raise CommandRejected(f"no trigger named {name!r}")
        spec = self.triggers[name]
        values = [_written_value(w.value) for w in spec.writes]
        checked = [
            self.words_for(w.register_name, value)
            for w, value in zip(spec.writes, values, strict=True)
        ]

        def send() -> str:
            """Each write read back at once. A start stops at the first not confirmed; a
            stop sends all of its writes, then says which were not confirmed."""
            done: list[str] = []
            unconfirmed: list[str] = []
            for (register, words), value in zip(checked, values, strict=True):
                try:
                    done.append(self._send_confirmed(register, words, value))  # as ~/write
                except NotConfirmed as err:
                    if not spec.stop:
                        raise NotConfirmed(_after(done, str(err))) from None
                    unconfirmed.append(str(err))
            if unconfirmed:
                raise NotConfirmed(_after(done, "; ".join(unconfirmed)))
            return ", ".join(done)

        if spec.stop:
            return self._as_stop({w.register_name for w in spec.writes}, send)
        if spec.starts_motion:
            self.check_keepalive(name)
        return send()

    def check_keepalive(self, what: str) -> None:
        """A motion command is refused while a required keepalive is not armed."""
        keepalive = self.keepalive
        if not self.device.spec.device.require_keepalive:
            return
        if self.device.frame_watchdog_s is not None:  # mode any_frame: the polls feed it
            if not getattr(self.io, "connected", True):
                raise CommandRejected(
                    f"{what}: the link is down, so the device's watchdog is not fed "
                    "(keepalive mode any_frame; require_keepalive)"
                )
            return
        if keepalive is not None and keepalive.armed:
            return
        spec = self.device.keepalive
        if (
            keepalive is not None
            and spec is not None
            and spec.period_register is not None
            and not keepalive.stale
            and keepalive.period_s is None
        ):
            # The device's watchdog time reads 0: its watchdog is off, nothing to feed.
            register = self.map[spec.period_register]
            unit = f" {register.unit}" if register.unit else ""
            raise CommandRejected(
                f"{what}: the device's watchdog is off: {register.name} reads 0; write its "
                f"watchdog time there first (~/write name: {register.name}, value: a time in"
                f"{unit or ' its unit'} above 0), then the keepalive arms (require_keepalive)"
            )
        raise CommandRejected(
            f"{what}: the device's keepalive is not armed yet (require_keepalive)"
        )

    def stream_allowed(self, topic: TopicSpec, register_value: float) -> None:
        if register_value != 0:
            self.check_keepalive(topic.name)

    def set_value(self, name: str, value: float) -> str:
        if name not in self.values:
            raise CommandRejected(f"no value service named {name!r}")
        return self.write(self.values[name].register_name, value)

    def set_coil(self, name: str, on: bool) -> str:
        """A coil service; its ``stop_on`` value is a stop (locks the command streams)."""
        if name not in self.coils:
            raise CommandRejected(f"no coil service named {name!r}")
        coil = self.coils[name]
        if coil.stop_on is not None and bool(on) == coil.stop_on:
            register = coil.register_name
            return self._as_stop({register}, lambda: self.write(register, bool(on)))
        return self.write(coil.register_name, bool(on))

    def stream_value(self, topic: TopicSpec, value: float) -> float:
        """A command topic's message value as its register's value (checked, not sent)."""
        register_value = check_finite(topic.name, value) * topic.scale
        self.words_for(topic.register_name, register_value)
        self.stream_allowed(topic, register_value)
        return register_value

    def send_stream(self, topic: TopicSpec, register_value: float) -> None:
        register, words = self.words_for(topic.register_name, register_value)
        self._send_confirmed(register, words, register_value)

    def stop_stream(self, topic: TopicSpec) -> None:
        register, words = self.words_for(topic.register_name, topic.stop_value)
        self._send_confirmed(register, words, topic.stop_value)


def written_text(register: Register, value: Value, words: Sequence[int]) -> str:
    """What a write put on the wire: ``name = value`` as asked when the register holds it
    exactly, else ``name = 12.3 s written (12.34 rounded to the register's 0.1 s)``."""
    if register.value_type.is_float:  # a float holds the value (to its precision)
        return f"{register.name} = {value}"
    written = decode(register, words)
    numbers = (value, written)
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in numbers):
        assert isinstance(written, int | float) and isinstance(value, int | float)
        if float(written) != float(value):
            unit = f" {register.unit}" if register.unit else ""
            step = _number(1.0 / register.scale)
            return (
                f"{register.name} = {_number(float(written))}{unit} written "
                f"({_number(float(value))} rounded to the register's {step}{unit})"
            )
    return f"{register.name} = {value}"


def _shown(register: Register, value: Value) -> str:
    """A value read back, as ``written_text`` shows one."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    unit = f" {register.unit}" if register.unit else ""
    return f"{_number(float(value))}{unit}"


def _after(done: Sequence[str], problem: str) -> str:
    """A trigger's not confirmed write, after the writes it confirmed first."""
    return f"{', '.join(done)} confirmed; {problem}" if done else problem


def _number(value: float) -> str:
    """A value as a person writes it: 12.3, not 12.299999999999999."""
    return f"{value:.10g}"


def _written_value(value: object) -> Value:
    if isinstance(value, bool | int | float | str):
        return value
    raise CommandRejected(f"{value!r} is not a value")


class KeepaliveFeeder:
    """The file's keepalive (no ROS): arms on each link-up (reads the watchdog time and,
    mode value without a value, the value to write back), then writes the register every
    watchdog time / ``KEEPALIVE_FEEDS_PER_PERIOD`` at the link's top priority."""

    def __init__(
        self, io: RegisterIO, device: Device, clock: Callable[[], float] = time.monotonic
    ) -> None:
        spec = device.keepalive
        assert spec is not None
        self.spec: Keepalive = spec
        self.io = io
        self._map = device.register_map
        self.register = device.register_map[spec.register]
        self.functions = device.register_map.limits.function_codes
        self._clock = clock
        self.period_s: float | None = spec.period_s
        self.armed = False
        self.stale = True  # read the device again (``arm``) before the next feed
        self._arm_after = -math.inf
        self.last_feed = -math.inf
        self._value: float | None = spec.value
        self._count = 0

    def disarm(self) -> None:
        """The link was lost: arm again (read again) before the next feed."""
        self.armed = False
        self.stale = True
        self._arm_after = -math.inf

    def arm(self) -> None:
        """Read what a feed needs, then feed once (``armed`` after it was written)."""
        spec = self.spec
        self.stale = False
        self._arm_after = self._clock() + KEEPALIVE_ARM_RETRY_S  # if this one fails
        if spec.period_register is not None:
            period = float(self._read(self._map[spec.period_register])) * spec.period_to_s
            self.period_s = period if period > 0 else None
        if self.period_s is None:
            self.armed = False  # the device's watchdog is off: nothing to feed
            return
        if spec.mode == "value" and spec.value is None:
            self._value = float(self._read(self.register))
        elif spec.mode != "value":
            self._count = int(self._read(self.register)) if self.register.access.readable else 0
        self.feed()

    def note_write(self, register: Register, words: Sequence[int]) -> None:
        """A command wrote ``register``: a new watchdog time (``period_from``), or the
        value mode's value (its feeds must not write an older one back)."""
        spec = self.spec
        if register.name == spec.period_register:
            period = float(decode(register, words)) * spec.period_to_s
            self.period_s = period if period > 0 else None
            if self.period_s is None:
                self.armed = False
        if register.name == spec.register and spec.mode == "value" and spec.value is None:
            self._value = float(decode(register, words))

    def next_feed(self) -> float | None:
        """When the next feed (or arming: ``due``) is due (``clock()`` time; None: nothing
        to feed, the device's watchdog is off)."""
        if self.stale or (not self.armed and self.period_s is not None):
            return self._arm_after
        if self.period_s is None:
            return None
        return self.last_feed + self.period_s / KEEPALIVE_FEEDS_PER_PERIOD

    def due(self) -> None:
        """The keepalive thread's work: arm if not armed, else feed."""
        if self.armed:
            self.feed()
        else:
            self.arm()

    def feed(self) -> None:
        spec = self.spec
        if spec.mode == "value":
            value: float = self._value if self._value is not None else 0.0
        elif spec.mode == "toggle":
            self._count = 0 if self._count else 1
            value = self._count
        else:
            self._count = (self._count + 1) % (self.register.value_type.raw_max + 1)
            value = self._count
        words = encode(self.register, value)
        if 6 in self.functions:
            self.io.write_register(self.register.address, words[0], priority=Priority.KEEPALIVE)
        else:
            self.io.write_registers(self.register.address, words)
        self.last_feed = self._clock()
        self.armed = self.period_s is not None

    def _read(self, register: Register) -> Value:
        return read_named(self.io, self._map, [register.name])[register.name]
