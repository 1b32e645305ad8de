"""``modbus_sim --device-file FILE``: a described device served on a real pymodbus server.

As strict as the file says the device is (the simulator base does the rest):

- function codes outside ``device.function_codes`` answer ILLEGAL FUNCTION;
- reads over rows no register defines answer ILLEGAL DATA ADDRESS, unless
  ``read_undefined`` is true (they read 0); write-only registers are never read, read-only
  ones never written; a request that cuts a multi-register value in two is refused;
- more than ``max_read_registers`` / ``max_write_registers`` / ``max_read_bits`` /
  ``max_write_bits`` per request: ILLEGAL DATA ADDRESS, as the simulator base answers an
  oversized read;
- a written value outside its register's ``range``, or not one of its ``values``:
  ILLEGAL DATA VALUE, nothing written;
- every reply waits ``reply_delay_s``;
- joints with a ``sim`` rule move: a velocity command is integrated into the position
  (and shown in the velocity register), a target position is approached at ``speed``;
  a position (or velocity) past what its register can hold stops at the register's end
  (clamped, as at a hard stop: no wrap, also for a revolute joint). A velocity follows
  its command as a first-order lag of ``time_constant_s`` (a drive's ramp), and only
  while ``run_register`` holds one of ``run_values`` (a drive's control word); a
  velocity-only joint shows it in its velocity (monitor) register;
- a ``keepalive`` is the device's watchdog: armed by its first feed (a write to its
  register; modes toggle and counter: a write that changes it), it trips when no feed
  came for its period (``period_s``, or the ``period_from`` register's value): the device
  stops itself as the file's stop triggers and command topics' stops would (those
  registers take the stop values), and waits for the next feed to arm again. Each trip
  is recorded in the simulator's own time (``keepalive_trip_log``: the last feed, the
  tick before and the tick that tripped), so a test can judge the trip by the device's
  clock, not its own.

A bus file serves every device on one line, each under its unit id (silent for others).

Personalities (docs/tools.md "Device personalities"): ``--reply-delay-ms MIN[:MAX]``
(RTU: the device's reply delay, default the file's ``reply_delay_s``; TCP: a network round
trip) and ``--ignore NAME[,NAME...]``, whose names are the file's motion writes
(``motion_writes``: its ``starts_motion`` and stop triggers, command topics, stop coils,
and the registers its joints are moved and commanded by), checked once the file is
loaded. The other readings ``bridge_commission modbus`` tells apart (each an attribute of
the device): ``--swap-word-order`` (``swap_word_order``: every 32/64-bit value in the
other word order than the file's, both ways), ``--refuse-undefined`` (``refuse_undefined``:
reads over rows no register defines refused although the file says ``read_undefined``),
``--address-shift N`` (``address_shift``: every row served N addresses lower, as a
manual that counts from 1 would have it for N = 1) and ``--no-watchdog``
(``watchdog_off``: a keepalive is accepted and never trips).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from bridge_core.sim.command_line import (
    add_network_arguments,
    serve_serial_until_signalled,
    serve_tcp_until_signalled,
)
from bridge_core.sim.logs import WriteRecord, add_log_arguments
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import (
    FUNCTION_TABLES,
    ILLEGAL_ADDRESS,
    ILLEGAL_VALUE,
    SimulatedDevice,
)
from bridge_core.wire.codec import decode, encode
from bridge_core.wire.registers import Register, Table, ValueType

from .description import (
    EXIT_BAD_DESCRIPTION,
    Description,
    Device,
    Joint,
    load_for_command,
)
from .description_joints import RUNNING_MIN_SI, Follow

DEFAULT_TCP_PORT = 5020
# Largest finite value of each float type (IEEE 754 binary32 / binary64).
FLOAT_LIMITS = {ValueType.F32: 3.4028234663852886e38, ValueType.F64: sys.float_info.max}


def holdable(register: Register, value: float) -> float:
    """``value`` clamped to what ``register`` can hold (its raw type's range, in its
    unit): an integrated joint position must never fail to encode."""
    kind = register.value_type
    if kind.is_float:
        low_raw, high_raw = -FLOAT_LIMITS[kind], FLOAT_LIMITS[kind]
    else:
        low_raw, high_raw = kind.raw_min, kind.raw_max
    ends = (low_raw / register.scale + register.offset, high_raw / register.scale + register.offset)
    return min(max(value, min(ends)), max(ends))


class _UndefinedReadable:
    """The readable addresses of a device whose reads may span undefined rows: every
    address no register defines, and the defined ones that are readable."""

    def __init__(self, readable: set[tuple[Table, int]], defined: set[tuple[Table, int]]) -> None:
        self.readable = readable
        self.defined = defined

    def __contains__(self, key: object) -> bool:
        return key in self.readable or key not in self.defined


@dataclass(frozen=True)
class KeepaliveTrip:
    """One trip of the simulated watchdog, in the simulator's own (monotonic) time: it
    tripped at the first tick that found ``period_s`` passed since the last feed."""

    fed_at: float  # the last feed
    checked_at: float  # the tick before, which found the watchdog still fed
    tripped_at: float  # the tick that found it expired and stopped the device
    period_s: float

    @property
    def tick_s(self) -> float:
        """The tick that found the trip: how late after the period it may come."""
        return self.tripped_at - self.checked_at


# Which of a file's motion writes a write is: name -> (what it is, the test of a write).
WriteTest = Callable[[WriteRecord], bool]


def _touches(register: Register) -> WriteTest:
    """Any write that covers a word of ``register``."""

    def test(record: WriteRecord) -> bool:
        end = record.address + len(record.values)
        return record.table is register.table and (
            record.address < register.address + register.count and register.address < end
        )

    return test


def _writes_value(register: Register, value: object) -> WriteTest:
    """A write that puts ``value`` (as a trigger's write encodes it) in ``register``."""
    words = tuple(encode(register, value))  # type: ignore[arg-type]

    def test(record: WriteRecord) -> bool:
        start = register.address - record.address
        if record.table is not register.table or start < 0:
            return False
        return tuple(record.values[start : start + len(words)]) == words

    return test


def motion_writes(device: Device) -> dict[str, tuple[str, WriteTest]]:
    """The motion writes of a described device, by the names ``--ignore`` takes:

    - its motion registers, any write of them: the registers its joints are moved by
      (``sim`` command and run register) or commanded by (``command``), and those of
      its stop and ``starts_motion`` triggers' writes;
    - its triggers that stop motion, start it or write a motion register (a write of one
      of the trigger's values), its command topics and stop coils (any write of their
      register)."""
    register_map = device.register_map
    commands = device.commands
    registers: dict[str, str] = {}
    for joint in device.joints:
        if joint.motion is not None:
            registers.setdefault(joint.motion.command, f"joint {joint.name}'s motion command")
            if joint.motion.run_register is not None:
                registers.setdefault(
                    joint.motion.run_register, f"joint {joint.name}'s run register"
                )
        if joint.command is not None:
            for source in (joint.command.position, joint.command.velocity):
                if source is not None:
                    registers.setdefault(source.register, f"joint {joint.name}'s command")
    for trigger in commands.triggers:
        if trigger.starts_motion or trigger.stop:
            for write in trigger.writes:
                registers.setdefault(write.register_name, f"written by trigger {trigger.name}")
    found: dict[str, tuple[str, WriteTest]] = {}

    def add(name: str, what: str, test: WriteTest) -> None:
        if name in found:  # a trigger and a register of one name: either write is it
            said, other = found[name]
            found[name] = (
                f"{said}; {what}",
                lambda record, a=other, b=test: a(record) or b(record),  # type: ignore[misc]
            )
        else:
            found[name] = (what, test)

    for name, what in registers.items():
        add(name, f"motion register, {what} (any write of it)", _touches(register_map[name]))
    for trigger in commands.triggers:
        if not (trigger.starts_motion or trigger.stop) and not any(
            w.register_name in registers for w in trigger.writes
        ):
            continue
        kind = (
            "stop trigger"
            if trigger.stop
            else "starts_motion trigger"
            if trigger.starts_motion
            else "trigger"
        )
        written = ", ".join(f"{w.register_name} = {w.value}" for w in trigger.writes)
        tests = [_writes_value(register_map[w.register_name], w.value) for w in trigger.writes]
        add(
            trigger.name,
            f"{kind} ({written})",
            lambda record, tests=tests: any(t(record) for t in tests),  # type: ignore[misc]
        )
    for topic in commands.topics:
        register = register_map[topic.register_name]
        add(topic.name, f"command topic (any write of {register.name})", _touches(register))
    for coil in commands.coils:
        if coil.stop_on is not None:
            register = register_map[coil.register_name]
            add(coil.name, f"stop coil (any write of {register.name})", _touches(register))
    return found


class DescribedSimDevice(SimulatedDevice):
    """One described device: its map, limits, ranges and joint motion.

    ``IGNORABLE`` is the instance's own (``motion_writes`` of the file; on a line, the
    names of every device of the file, so that ``--ignore`` takes any of them), and
    ``write_names`` says which of its own device's motion writes a write is."""

    def __init__(self, device: Device, ignorable: Mapping[str, str] | None = None) -> None:
        super().__init__(device.register_map, device.unit_id)
        self.device = device
        self._motion_writes = motion_writes(device)
        own = {name: what for name, (what, _) in self._motion_writes.items()}
        self.IGNORABLE = dict(own if ignorable is None else ignorable)  # type: ignore[misc]
        self.max_write_bits = device.spec.device.max_write_bits
        if self.limits.read_undefined_ok:
            defined = set(self.words)
            self.words = defaultdict(int, self.words)
            self.readable = _UndefinedReadable(self.readable, defined)  # type: ignore[assignment]
        self.positions_si = {joint.name: 0.0 for joint in device.joints}
        self.velocities_si = {joint.name: 0.0 for joint in device.joints}
        self.write_guards.append(self._guard)
        # The keepalive watchdog: when it was last fed (monotonic; None: not armed), when
        # it was last looked at (each tick), and every trip (the simulator's own times).
        self.keepalive = device.keepalive
        self.keepalive_fed_at: float | None = None
        self._keepalive_checked_at: float | None = None
        self.keepalive_trip_log: list[KeepaliveTrip] = []
        if self.keepalive is not None:
            self.write_hooks.append(self._keepalive_write)
        # keepalive mode any_frame: every request to this unit feeds the watchdog.
        self.frame_watchdog_s = device.frame_watchdog_s
        # Personalities (the other reading of a check of bridge_commission modbus).
        self.swap_word_order = False
        self.refuse_undefined = False
        self.address_shift = 0
        self.watchdog_off = False
        self._defined = {(r.table, a) for r in self.map for a in r.addresses()}

    def read(self, function_code: int, address: int, count: int) -> list[int] | int:
        self._frame()
        address += self.address_shift
        table = FUNCTION_TABLES[function_code]
        if self.refuse_undefined and any(
            (table, a) not in self._defined for a in range(address, address + count)
        ):
            return ILLEGAL_ADDRESS
        words = super().read(function_code, address, count)
        if self.swap_word_order and isinstance(words, list):
            return self._swapped(table, address, words)
        return words

    def write(self, function_code: int, address: int, values: Sequence[int]) -> int | None:
        self._frame()
        address += self.address_shift
        if self.swap_word_order:
            values = self._swapped(FUNCTION_TABLES[function_code], address, values)
        return super().write(function_code, address, values)

    def _swapped(self, table: Table, address: int, words: Sequence[int]) -> list[int]:
        """``words`` with every whole multi-register value in them in the other word order
        (``swap_word_order``: the device's order is not the file's)."""
        swapped = list(words)
        if table.is_bit:
            return swapped
        for register in self.map.in_table(table):
            start = register.address - address
            if (
                register.count > 1
                and register.value_type is not ValueType.STRING
                and start >= 0
                and start + register.count <= len(words)
            ):
                swapped[start : start + register.count] = reversed(
                    words[start : start + register.count]
                )
        return swapped

    def _frame(self) -> None:
        """A request reached this unit: it feeds a watchdog of mode any_frame."""
        if self.frame_watchdog_s is not None:
            with self.lock:
                self.keepalive_fed_at = time.monotonic()

    def _keepalive_write(self, record: WriteRecord) -> None:
        keepalive = self.keepalive
        assert keepalive is not None
        register = self.map[keepalive.register]
        if record.table is not register.table or not (
            record.address <= register.address < record.address + len(record.values)
        ):
            return
        word = record.values[register.address - record.address]
        previous = self._keepalive_word
        self._keepalive_word = word
        if keepalive.mode == "value" or word != previous:
            self.keepalive_fed_at = time.monotonic()

    _keepalive_word: int | None = None

    def write_names(self, record: WriteRecord) -> frozenset[str]:
        return frozenset(name for name, (_, test) in self._motion_writes.items() if test(record))

    def keepalive_period_s(self) -> float | None:
        keepalive = self.keepalive
        if keepalive is None:
            return self.frame_watchdog_s
        if keepalive.period_register is None:
            return keepalive.period_s
        period = float(self.get(keepalive.period_register)) * keepalive.period_to_s
        return period if period > 0 else None

    @property
    def keepalive_trips(self) -> int:
        return len(self.keepalive_trip_log)

    def _check_keepalive(self) -> None:
        now = time.monotonic()
        checked_at, self._keepalive_checked_at = self._keepalive_checked_at, now
        fed_at, period = self.keepalive_fed_at, self.keepalive_period_s()
        if self.watchdog_off or fed_at is None or period is None or now - fed_at <= period:
            return
        self.keepalive_fed_at = None  # disarmed until the next feed
        self.stop_all()
        self.keepalive_trip_log.append(
            KeepaliveTrip(fed_at, fed_at if checked_at is None else checked_at, now, period)
        )

    def stop_all(self) -> None:
        """The device stops itself: every stop trigger's writes and every command topic's
        stop value, as the device's own values (no write log)."""
        commands = self.device.commands
        for trigger in commands.triggers:
            if trigger.stop:
                for write in trigger.writes:
                    self.set(write.register_name, write.value)
        for topic in commands.topics:
            self.set(topic.register_name, topic.stop_value)

    def _guard(self, record: WriteRecord) -> int | None:
        """Bit writes past ``max_write_bits``, and values outside their register's range."""
        if record.table.is_bit:
            return ILLEGAL_ADDRESS if len(record.values) > self.max_write_bits else None
        written = dict(enumerate(record.values, record.address))
        for register in self.map.in_table(record.table):
            if register.minimum is None and register.maximum is None:
                continue
            if register.address not in written or register.value_type is ValueType.STRING:
                continue  # whole-value writes only (checked before the guards)
            value = decode(register, [written[a] for a in register.addresses()])
            assert isinstance(value, int | float)
            low = -math.inf if register.minimum is None else register.minimum
            high = math.inf if register.maximum is None else register.maximum
            if not low <= value <= high:
                return ILLEGAL_VALUE
        for register in self.map.in_table(record.table):
            if register.address in written and register.name in self.device.allowed_values:
                value = decode(register, [written[a] for a in register.addresses()])
                assert isinstance(value, int | float)
                if not self.device.allows(register.name, value):
                    return ILLEGAL_VALUE  # not one of the register's values
        return None

    def tick(self, dt: float) -> None:
        with self.lock:
            if self.keepalive is not None or self.frame_watchdog_s is not None:
                self._check_keepalive()
            for joint in self.device.joints:
                if joint.motion is not None:
                    self._move(joint, dt)

    def _move(self, joint: Joint, dt: float) -> None:
        motion = joint.motion
        assert motion is not None
        command = float(self.get(motion.command)) * motion.to_si
        runs = command != 0.0  # the command counts (no run register: when not 0)
        if motion.run_register is not None:
            run = float(self.get(motion.run_register))
            runs = run in motion.run_values
            if not runs:
                command = 0.0
        position = self.positions_si[joint.name]
        if motion.mode == "velocity":
            velocity = command
            if motion.time_constant_s is not None and dt > 0:
                previous = self.velocities_si[joint.name]
                velocity = command + (previous - command) * math.exp(-dt / motion.time_constant_s)
        else:
            error = command - position
            step = abs(error) if motion.speed is None else min(abs(error), motion.speed * dt)
            velocity = math.copysign(step / dt, error) if dt > 0 and step else 0.0
        if joint.position is not None:
            position_register = self.map[joint.position.register]
            held = holdable(position_register, (position + velocity * dt) / joint.position.to_si)
            if dt > 0:  # at a register end the joint stops there
                velocity = (held * joint.position.to_si - position) / dt
            self.positions_si[joint.name] = held * joint.position.to_si
            self.set(joint.position.register, held)
        self.velocities_si[joint.name] = velocity
        if joint.velocity is not None and joint.velocity.register != motion.command:
            velocity_register = self.map[joint.velocity.register]
            self.set(
                joint.velocity.register,
                holdable(velocity_register, velocity / joint.velocity.to_si),
            )
        running = runs or abs(velocity) > RUNNING_MIN_SI
        for follow in motion.follows:
            self._follow(follow, running, velocity / motion.to_si, command / motion.to_si)

    def _follow(self, follow: Follow, running: bool, velocity: float, command: float) -> None:
        """A monitor register set from the joint's motion (``sim.follows``): velocity and
        command in the sim command register's unit; held within the register's type and
        range."""
        if follow.rule == "running":
            value = follow.running if running else follow.stopped
        else:
            moved = {"velocity": velocity, "speed": abs(velocity), "command": command}
            value = moved[follow.rule] * follow.factor
        register = self.map[follow.register]
        value = holdable(register, value)
        if register.minimum is not None:
            value = max(value, register.minimum)
        if register.maximum is not None:
            value = min(value, register.maximum)
        self.set(follow.register, value)


def file_motion_writes(description: Description) -> dict[str, str]:
    """Every motion write of a file (``--ignore``'s names): name -> what it is (on a
    line, prefixed by the devices that have it when not all do)."""
    per_device = [
        (device.name, {name: what for name, (what, _) in motion_writes(device).items()})
        for device in description.devices
    ]
    names: dict[str, str] = {}
    for _, writes in per_device:
        for name, what in writes.items():
            names.setdefault(name, what)
    if len(per_device) > 1:
        for name in names:
            owners = [device for device, writes in per_device if name in writes]
            if len(owners) < len(per_device):
                names[name] = f"{', '.join(owners)}: {names[name]}"
    return names


def make_simulator(description: Description) -> Simulator:
    ignorable = file_motion_writes(description)
    return Simulator([DescribedSimDevice(device, ignorable) for device in description.devices])


def _names(text: str) -> frozenset[str]:
    return frozenset(n.strip() for n in text.split(",") if n.strip())


def unknown_ignore(path: Path, description: Description, names: frozenset[str]) -> str | None:
    """The one error line of ``--ignore`` names that are not the file's motion writes
    (None: all are)."""
    known = file_motion_writes(description)
    unknown = sorted(names - set(known))
    if not unknown and names:
        return None
    given = ", ".join(unknown) if unknown else "(no name)"
    listing = ", ".join(sorted(known)) if known else "none (the file declares no motion)"
    return f"error: --ignore {given}: not a motion write of {path}; its motion writes: {listing}"


def add_personality_arguments(parser: argparse.ArgumentParser) -> None:
    """The other readings of bridge_commission modbus's checks (docs/tools.md)."""
    parser.add_argument(
        "--swap-word-order",
        action="store_true",
        help="serve every 32/64-bit value in the other word order than the file's",
    )
    parser.add_argument(
        "--refuse-undefined",
        action="store_true",
        help="refuse reads over rows no register defines, although the file's "
        "read_undefined is true",
    )
    parser.add_argument(
        "--address-shift",
        type=int,
        default=0,
        metavar="N",
        help="serve every row N addresses lower than the file says (1: a manual that "
        "counts from 1)",
    )
    parser.add_argument(
        "--no-watchdog", action="store_true", help="a keepalive is accepted and never trips"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="serve a device description (Modbus TCP or RTU)")
    parser.add_argument("--device-file", type=Path, required=True, help="device description YAML")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument(
        "--port", type=int, help="TCP port (default: the file's, else 5020; 0 picks a free one)"
    )
    parser.add_argument("--port-file", type=Path, help="write the bound port here once listening")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--serial", help="serve RTU on this serial port or pty path")
    where.add_argument(
        "--pty",
        type=Path,
        help="serve RTU on a new socat pty pair; the bridge's end is linked here",
    )
    parser.add_argument("--baudrate", type=int, help="default: the file's, else 9600")
    parser.add_argument("--parity", choices=("N", "E", "O"), help="default: the file's, else N")
    parser.add_argument("--stopbits", type=int, choices=(1, 2), help="default: the file's, else 1")
    add_log_arguments(parser)
    add_network_arguments(parser, delay_default_ms=None)
    for action in parser._actions:
        if action.dest == "reply_delay_ms":  # here it is the device's delay on RTU too
            action.help = (
                "each reply's delay, drawn per reply in [MIN, MAX] ms: on --serial / --pty "
                "the device's (after the request's last byte; default the file's "
                "reply_delay_s), over TCP a network round trip, half each way (default 0)"
            )
    parser.add_argument(
        "--ignore",
        type=_names,
        default=None,
        metavar="NAME[,NAME...]",
        help="acknowledge these motion writes of the file as the manual says and change "
        "nothing (a device that does not obey): its starts_motion and stop triggers, "
        "command topics, stop coils and its joints' command and run registers (an unknown "
        "name: the error lists the file's)",
    )
    add_personality_arguments(parser)
    args = parser.parse_args(argv)
    description = load_for_command(args.device_file)
    if description is None:
        return EXIT_BAD_DESCRIPTION
    if args.ignore is not None:
        problem = unknown_ignore(args.device_file, description, args.ignore)
        if problem is not None:
            print(problem, file=sys.stderr)
            return EXIT_BAD_DESCRIPTION
    if args.pty is not None and not args.pty.parent.is_dir():
        print(f"error: --pty {args.pty}: no directory {args.pty.parent}", file=sys.stderr)
        return EXIT_BAD_DESCRIPTION
    link = description.line or description.device.link
    rtu = link.rtu if link is not None else None
    sim = make_simulator(description)
    for device in sim.devices.values():
        assert isinstance(device, DescribedSimDevice)
        device.swap_word_order = args.swap_word_order
        device.refuse_undefined = args.refuse_undefined
        device.address_shift = args.address_shift
        device.watchdog_off = args.no_watchdog
    names = ", ".join(f"{d.name} (unit {d.unit_id})" for d in description.devices)
    if args.serial or args.pty:
        if args.one_request_at_a_time or args.nagle:
            parser.error(
                "--one-request-at-a-time and --nagle simulate a TCP network; "
                "they do not apply to --serial / --pty"
            )
        args.baudrate = args.baudrate or (rtu.baudrate if rtu else 9600)
        args.parity = args.parity or (rtu.parity if rtu else "N")
        args.stopbits = args.stopbits or (rtu.stopbits if rtu else 1)
        framing = f"{args.baudrate} 8{args.parity}{args.stopbits}"
        serve_serial_until_signalled(
            sim, args, lambda where: f"modbus_sim {names} listening on {where} ({framing})"
        )
        return 0
    if args.port is None:
        tcp = link.tcp if link is not None else None
        args.port = tcp.port if tcp is not None else DEFAULT_TCP_PORT
    serve_tcp_until_signalled(sim, args, f"modbus_sim {names}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
