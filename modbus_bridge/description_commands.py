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

from .description_schema import DEFAULT_MOTION_GROUP, DeviceFileSpec, WriteSpec
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
        if trigger.starts_motion and trigger.stop:
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
    for index, value_service in enumerate(commands.values):
        at = ("commands", "values", index)
        named(value_service.name, at)
        writable(register_map, value_service.register_name, check, at)
    for index, coil in enumerate(commands.coils):
        at = ("commands", "coils", index)
        named(coil.name, at)
        writable(register_map, coil.register_name, check, at, bool_only=True)
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


def build_keepalive(
    spec: DeviceFileSpec, register_map: RegisterMap, check: Checker
) -> Keepalive | None:
    keepalive = spec.keepalive
    if keepalive is None:
        return None
    at: Loc = ("keepalive",)
    register = writable(register_map, keepalive.register_name, check, at)
    if register is None:
        return None
    if register.value_type.label not in KEEPALIVE_TYPES:
        check.add(
            (*at, "register"),
            f"{register.name} is a {register.value_type.label} "
            f"(a keepalive register is one of {', '.join(KEEPALIVE_TYPES)})",
        )
        return None
    if keepalive.mode != "value" and keepalive.value is not None:
        check.add((*at, "value"), f"mode {keepalive.mode} writes its own values (no value)")
        return None
    if keepalive.value is not None:
        try:
            encode(register, keepalive.value)
        except CodecError as err:
            check.add((*at, "value"), f"{number_text(keepalive.value)} cannot be written: {err}")
            return None
    if (keepalive.period_s is None) == (keepalive.period_from is None):
        check.add(at, "give exactly one of period_s and period_from")
        return None
    period_to_s = 1.0
    if keepalive.period_from is not None:
        source = keepalive.period_from
        if source not in register_map or not register_map[source].access.readable:
            check.add((*at, "period_from"), f"{source!r} is not a readable register")
            return None
        unit = register_map[source].unit
        if unit not in PERIOD_UNITS_TO_S:
            check.add(
                (*at, "period_from"),
                f"{source}'s unit {unit!r} is not a time (allowed: {', '.join(PERIOD_UNITS_TO_S)})",
            )
            return None
        period_to_s = PERIOD_UNITS_TO_S[unit]
    return Keepalive(
        keepalive.register_name,
        keepalive.mode,
        keepalive.value,
        keepalive.period_s,
        keepalive.period_from,
        period_to_s,
    )
