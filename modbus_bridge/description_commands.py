"""The commands of a description file (triggers, value and coil services, command
topics) and its keepalive: which registers they may write and with what values.

Whether a value fits a register is the codec's rule (``encode``): its refusal is the
message. Names, motion groups and the keepalive's modes are the description's rules.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from bridge_core.wire.codec import CodecError, encode, to_raw
from bridge_core.wire.registers import Register, RegisterMap, Table, ValueType

from .description_schema import (
    DEFAULT_MOTION_GROUP,
    CoilServiceSpec,
    DeviceFileSpec,
    ValueServiceSpec,
    WriteSpec,
)
from .description_yaml import Checker, Loc

# Names the node gives its own services and topics: a command may not take them.
RESERVED_NAMES = frozenset({"read", "write", "state", "connected", "joint_commands"})
# The parameters the node declares itself (rclpy, bridge_core.ros.node_base, ``device_file``): a
# command topic's generated parameters (<name>_timeout_s, <name>_rate_hz) may not be one
# (a topic ``poll`` would declare ``poll_rate_hz``). tests/modbus/test_modbus_ros.py checks
# this list against a running node's.
NODE_PARAMETERS = frozenset(
    {
        "host",
        "port",
        "max_in_flight",
        "serial_port",
        "baudrate",
        "parity",
        "stopbits",
        "frame_gap_s",
        "timeout_s",
        "unit_id",
        "retries",
        "reconnect_max_s",
        "record_wire",
        "poll_rate_hz",
        "slow_poll_period_s",
        "diagnostic_period_s",
        "joint_prefix",
        "frame_id",
        "read_only",
        "autostart",
        "device_file",
        # ~/joint_commands' deadman and rate (declared when a joint has a command)
        "command_timeout_s",
        "command_rate_hz",
        "joint_command_max_jump",
        "use_sim_time",  # rclpy's own
        "start_type_description_service",
    }
)
TOPIC_PARAMETER_SUFFIXES = ("_timeout_s", "_rate_hz")
# Units a keepalive's ``period_from`` register may have, as the factor to seconds.
PERIOD_UNITS_TO_S = {"s": 1.0, "ms": 1e-3}
# A keepalive register is one 16-bit register (fed with FC 06 at the link's top priority).
KEEPALIVE_TYPES = ("u16", "i16")
# Keepalive mode any_frame: the polls are the feeds, at least this many per watchdog time
# (as the bridge feeds a register keepalive: modbus_bridge.device.KEEPALIVE_FEEDS_PER_PERIOD).
ANY_FRAME_POLLS_PER_PERIOD = 3


@dataclass(frozen=True)
class Keepalive:
    """A built keepalive: the register fed, how, and the device's watchdog time (given, or
    read from ``period_register`` times ``period_to_s``)."""

    register: str
    mode: Literal["value", "toggle", "counter"]
    value: float | None
    period_s: float | None
    period_register: str | None
    period_to_s: float


def number_text(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def writable(
    register_map: RegisterMap,
    name: str,
    check: Checker,
    at: Loc,
    *,
    bool_only: bool = False,
    field: str = "register",
) -> Register | None:
    if name not in register_map:
        check.add((*at, field), f"no register named {name!r}")
        return None
    register = register_map[name]
    if not register.access.writable:
        check.add((*at, field), f"{name} is read only (a command needs access W or RW)")
        return None
    if bool_only and register.table is not Table.COIL:
        check.add((*at, field), f"{name} is not a coil (a coil service switches a coil)")
        return None
    if not bool_only and register.value_type in (ValueType.BOOL, ValueType.STRING):
        check.add(
            (*at, field),
            f"{name} is a {register.value_type.label} (allowed: a numeric register; "
            "coils go under commands.coils)",
        )
        return None
    return register


def allowed_values(spec: DeviceFileSpec) -> dict[str, tuple[float, ...]]:
    """Register name -> its ``values`` (the registers that have them)."""
    return {r.name: tuple(r.values) for r in spec.registers if r.values is not None}


def not_allowed(name: str, value: float, allowed: Sequence[float]) -> str:
    """The one-line refusal of a value outside a register's ``values``."""
    values = ", ".join(number_text(v) for v in allowed)
    return f"{name} takes one of {values}, not {number_text(value)}"


def _check_write(
    spec: DeviceFileSpec, register_map: RegisterMap, write: WriteSpec, check: Checker, where: Loc
) -> None:
    """One write of a trigger: a writable register and a value the codec can write (and one
    of the register's ``values``, if it has them)."""
    if write.register_name not in register_map:
        check.add((*where, "register"), f"no register named {write.register_name!r}")
        return
    register = register_map[write.register_name]
    if not register.access.writable:
        check.add((*where, "register"), f"{write.register_name} is read only (needs W or RW)")
        return
    value = write.value
    if isinstance(value, bool) != (register.value_type is ValueType.BOOL) or not (
        isinstance(value, int | float)
    ):
        allowed = "true or false" if register.value_type is ValueType.BOOL else "a number"
        check.add((*where, "value"), f"{value!r} for {write.register_name} (allowed: {allowed})")
        return
    try:
        encode(register, value)
    except CodecError as err:
        check.add((*where, "value"), str(err))
        return
    choices = allowed_values(spec).get(write.register_name)
    if choices is not None and float(value) not in choices:
        check.add((*where, "value"), not_allowed(write.register_name, value, choices))


def _stopped_registers(spec: DeviceFileSpec) -> dict[str, str]:
    """The registers the file's stops write (stop triggers, stop coils, command topics):
    register -> the stop, as its refusal names it. Another value of one may start motion."""
    commands = spec.commands
    stops: dict[str, str] = {}
    for trigger in commands.triggers:
        if trigger.stop:
            for write in trigger.writes:
                stops.setdefault(write.register_name, f"stop trigger {trigger.name!r}")
    for coil in commands.coils:
        if coil.stop_on is not None:
            stops.setdefault(coil.register_name, f"stop coil {coil.name!r}")
    for topic in commands.topics:
        stops.setdefault(topic.register_name, f"command topic {topic.name!r}")
    return stops


def check_commands(spec: DeviceFileSpec, register_map: RegisterMap, check: Checker) -> None:
    commands = spec.commands
    seen: set[str] = set()

    def named(name: str, at: Loc) -> None:
        if name in RESERVED_NAMES:
            reserved = ", ".join(sorted(RESERVED_NAMES))
            check.add((*at, "name"), f"{name!r} is the node's own (reserved: {reserved})")
        elif name in seen:
            check.add((*at, "name"), f"command {name!r} given twice (names are unique)")
        seen.add(name)

    stop_groups = {t.group for t in commands.triggers if t.stop}
    for index, trigger in enumerate(commands.triggers):
        at: Loc = ("commands", "triggers", index)
        named(trigger.name, at)
        if trigger.starts_motion is None and not trigger.stop:
            check.add(
                at,
                f"trigger {trigger.name!r} does not say whether it starts motion: add "
                "starts_motion: true (the bridge then sends its group's stop on every way "
                "out) or starts_motion: false",
            )
        elif trigger.starts_motion and trigger.stop:
            check.add((*at, "starts_motion"), "a trigger starts motion or stops it, not both")
        elif trigger.starts_motion and trigger.group not in stop_groups:
            check.add(
                (*at, "starts_motion"),
                f"nothing stops group {trigger.group!r}: add a trigger with stop: true"
                + ("" if trigger.group == DEFAULT_MOTION_GROUP else f" and group: {trigger.group}")
                + " (the bridge sends it on every way out)",
            )
        for k, write in enumerate(trigger.writes):
            _check_write(spec, register_map, write, check, (*at, "writes", k))
    stopped_by = _stopped_registers(spec)
    services: list[tuple[str, ValueServiceSpec | CoilServiceSpec, str, bool | None]] = [
        ("values", v, v.register_name, v.starts_motion) for v in commands.values
    ]
    services += [("coils", c, c.register_name, c.starts_motion) for c in commands.coils]
    for index, value_service in enumerate(commands.values):
        at = ("commands", "values", index)
        named(value_service.name, at)
        writable(register_map, value_service.register_name, check, at)
    for index, coil in enumerate(commands.coils):
        at = ("commands", "coils", index)
        named(coil.name, at)
        writable(register_map, coil.register_name, check, at, bool_only=True)
    counts = {"values": 0, "coils": 0}
    for kind, service, register, starts in services:
        at = ("commands", kind, counts[kind])
        counts[kind] += 1
        if starts:
            check.add(
                (*at, "starts_motion"),
                f"{service.name}: a service's start is never stopped on the way out (allowed: "
                "false; write a start as a trigger with starts_motion: true and a stop trigger)",
            )
        elif starts is None and register in stopped_by:
            check.add(
                at,
                f"{service.name} writes {register}, which {stopped_by[register]} writes to stop "
                "motion: say starts_motion: false (a start belongs in a trigger with "
                "starts_motion: true, which the bridge stops on every way out)",
            )
    for index, topic in enumerate(commands.topics):
        at = ("commands", "topics", index)
        named(topic.name, at)
        for suffix in TOPIC_PARAMETER_SUFFIXES:
            if f"{topic.name}{suffix}" in NODE_PARAMETERS:
                check.add(
                    (*at, "name"),
                    f"{topic.name!r} would declare {topic.name}{suffix}, a parameter of the "
                    "node's own (give the topic another name)",
                )
        target = writable(register_map, topic.register_name, check, at)
        if topic.stop_value != 0:
            # The stream guard's stop is a 0 message (register value 0 x scale = 0): a
            # different stop value would make a 0 command and the deadman disagree.
            check.add(
                (*at, "stop_value"),
                f"{number_text(topic.stop_value)}: a command topic stops at 0 (allowed: 0)",
            )
        elif target is not None:
            try:
                to_raw(target, topic.stop_value)
            except CodecError as err:
                check.add((*at, "stop_value"), f"the stop value does not fit: {err}")
                continue
            choices = allowed_values(spec).get(topic.register_name)
            if choices is not None and topic.stop_value not in choices:
                check.add(
                    (*at, "stop_value"), not_allowed(topic.register_name, topic.stop_value, choices)
                )


def _feed_problem(spec: DeviceFileSpec, register: Register, value: float) -> str | None:
    """Why a feed of ``value`` would be refused, as ``~/write`` refuses a write (a whole
    number for an unscaled integer, the type and ``range``, one of ``values``)."""
    if register.scale == 1.0 and register.offset == 0.0 and not float(value).is_integer():
        return f"{register.name} takes a whole number, not {value}"
    try:
        raw = to_raw(register, value)
        encode(register, value)
    except CodecError as err:
        return str(err)
    choices = allowed_values(spec).get(register.name)
    if choices is not None and raw not in {to_raw(register, choice) for choice in choices}:
        return not_allowed(register.name, value, choices)
    return None


def build_keepalive(
    spec: DeviceFileSpec, register_map: RegisterMap, check: Checker
) -> tuple[Keepalive | None, float | None]:
    """The file's keepalive, and the watchdog time of mode any_frame (which feeds no
    register: the polls reset it)."""
    keepalive = spec.keepalive
    if keepalive is None:
        return None, None
    at: Loc = ("keepalive",)
    if keepalive.mode == "any_frame":
        return None, _any_frame(spec, check)
    if keepalive.register_name is None:
        check.add(at, f"mode {keepalive.mode} needs register: (the register fed)")
        return None, None
    register = writable(register_map, keepalive.register_name, check, at)
    if register is None:
        return None, None
    if register.value_type.label not in KEEPALIVE_TYPES:
        check.add(
            (*at, "register"),
            f"{register.name} is a {register.value_type.label} "
            f"(a keepalive register is one of {', '.join(KEEPALIVE_TYPES)})",
        )
        return None, None
    if keepalive.mode != "value" and keepalive.value is not None:
        check.add((*at, "value"), f"mode {keepalive.mode} writes its own values (no value)")
        return None, None
    if keepalive.mode == "value" and keepalive.value is None and not register.access.readable:
        check.add(
            at,
            f"mode value without value: reads {register.name} back when arming, and it is "
            "write-only (give value: the number each feed writes)",
        )
        return None, None
    # What the feeds write, each checked as ~/write checks a write.
    feeds = {"toggle": (0.0, 1.0), "counter": (0.0, float(register.value_type.raw_max))}
    for fed in [keepalive.value] if keepalive.value is not None else feeds.get(keepalive.mode, ()):
        problem = _feed_problem(spec, register, fed)
        if problem is not None:
            where: Loc = (*at, "value") if keepalive.mode == "value" else (*at, "mode")
            what = "a feed" if keepalive.mode == "value" else f"mode {keepalive.mode} writes"
            check.add(where, f"{what} {number_text(fed)} would be refused: {problem}")
            return None, None
    if (keepalive.period_s is None) == (keepalive.period_from is None):
        check.add(at, "give exactly one of period_s and period_from")
        return None, None
    period_to_s = 1.0
    if keepalive.period_from is not None:
        source = keepalive.period_from
        if source not in register_map or not register_map[source].access.readable:
            check.add((*at, "period_from"), f"{source!r} is not a readable register")
            return None, None
        unit = register_map[source].unit
        if unit not in PERIOD_UNITS_TO_S:
            check.add(
                (*at, "period_from"),
                f"{source}'s unit {unit!r} is not a time (allowed: {', '.join(PERIOD_UNITS_TO_S)})",
            )
            return None, None
        period_to_s = PERIOD_UNITS_TO_S[unit]
    built = Keepalive(
        keepalive.register_name,
        keepalive.mode,
        keepalive.value,
        keepalive.period_s,
        keepalive.period_from,
        period_to_s,
    )
    return built, None


def _any_frame(spec: DeviceFileSpec, check: Checker) -> float | None:
    """Mode any_frame: a watchdog every request resets (a drive's communication time-out,
    e.g. a VFD's "time-out detection"): no register, its time given as ``period_s``, and
    the polls must come ``ANY_FRAME_POLLS_PER_PERIOD`` times within it."""
    keepalive = spec.keepalive
    assert keepalive is not None
    at: Loc = ("keepalive",)
    for key, given in (
        ("register", keepalive.register_name),
        ("value", keepalive.value),
        ("period_from", keepalive.period_from),
    ):
        if given is not None:
            check.add((*at, key), "mode any_frame feeds no register (allowed: mode, period_s)")
            return None
    if keepalive.period_s is None:
        check.add(at, "mode any_frame needs period_s (the device's watchdog time)")
        return None
    rate_hz = spec.device.poll_rate_hz
    needed_hz = ANY_FRAME_POLLS_PER_PERIOD / keepalive.period_s
    if rate_hz < needed_hz:
        check.add(
            (*at, "period_s"),
            f"{number_text(keepalive.period_s)} s: the polls feed it, and poll_rate_hz "
            f"{number_text(rate_hz)} sends one every {number_text(1 / rate_hz)} s (allowed: "
            f"poll_rate_hz >= {needed_hz:.3g}, {ANY_FRAME_POLLS_PER_PERIOD} polls a period)",
        )
        return None
    return keepalive.period_s
