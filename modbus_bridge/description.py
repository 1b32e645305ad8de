"""Device description files: any Modbus device as a validated YAML register map.

One file drives the node (``modbus_bridge``), the simulator (``modbus_sim``) and the docs
(``modbus_doc``). Every problem is reported as ``FILE:LINE: key.path: what is wrong
(what is allowed)`` on one line, the line taken from the YAML node the key path leads to.

The work is split by job: ``description_yaml`` reads the file (plain data with line
marks), ``description_schema`` checks the keys (pydantic: types, choices, unknown keys),
this module builds bridge_core's own types (``Register``, ``RegisterMap``,
``DeviceLimits``), whose rules speak for the registers (their faults name the field; the
key and line are found here), and ``description_joints`` / ``description_commands``
check what only a description has. The planner, codec, poller and simulator base then
serve a described device exactly as they serve the four hand-written bridges.

This module is the import point: the names the rest of the package uses are here.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import yaml  # type: ignore[import-untyped]
from pydantic import BaseModel, ValidationError

from bridge_core.wire.channel import UNIT_ID_MAX
from bridge_core.wire.codec import CodecError, encode, to_raw
from bridge_core.wire.registers import (
    Access,
    DeviceLimits,
    Register,
    RegisterMap,
    RuleError,
    Table,
    ValueType,
    WordOrder,
)

from .description_commands import (
    NODE_PARAMETERS,
    TOPIC_PARAMETER_SUFFIXES,
    Keepalive,
    allowed_values,
    build_keepalive,
    check_commands,
    not_allowed,
    number_text,
)
from .description_joints import Joint, JointSource, build_joints
from .description_schema import (
    COMMAND_RATE_RANGE_HZ,
    BusFileSpec,
    CommandsSpec,
    DeviceFileSpec,
    RegisterSpec,
    RtuLinkSpec,
    TcpLinkSpec,
    TopicSpec,
    key_problems,
)
from .description_yaml import Checker, DescriptionError, Loc, Problem, compose, node_at

# The exit status of a command-line tool given a description it cannot load.
EXIT_BAD_DESCRIPTION = 2

__all__ = [
    "COMMAND_RATE_RANGE_HZ",
    "EXIT_BAD_DESCRIPTION",
    "NODE_PARAMETERS",
    "TOPIC_PARAMETER_SUFFIXES",
    "Description",
    "DescriptionError",
    "Device",
    "Joint",
    "JointSource",
    "Keepalive",
    "Link",
    "TopicSpec",
    "load",
    "load_for_command",
    "not_allowed",
]

# Register fields written under another key in a description (the rest: the same name).
REGISTER_KEYS = {"value_type": "type", "doc": "manual", "minimum": "range", "maximum": "range"}


@dataclass(frozen=True)
class Link:
    """Default link of a device (or of a line): ``tcp`` or ``rtu`` settings."""

    transport: Literal["tcp", "rtu"]
    timeout_s: float
    tcp: TcpLinkSpec | None = None
    rtu: RtuLinkSpec | None = None


@dataclass(frozen=True)
class Device:
    """One described device: its spec as written and the runtime types built from it."""

    spec: DeviceFileSpec
    register_map: RegisterMap
    joints: tuple[Joint, ...]
    link: Link | None  # None: on the file's shared line
    state_names: tuple[str, ...]  # readable registers published in ~/state
    # Registers that take only some values (``values``): name -> the values, in its unit.
    allowed_values: dict[str, tuple[float, ...]] = field(default_factory=dict)
    # Register name -> its address as the file wrote it, where not in decimal (0x2100).
    address_texts: dict[str, str] = field(default_factory=dict)
    keepalive: Keepalive | None = None
    slow_names: tuple[str, ...] = ()  # registers polled every slow_poll_period_s
    # Register name -> its rate group as resolved (its own ``poll``, else the device's;
    # a joint's register: fast): fast, slow or never.
    polls: dict[str, str] = field(default_factory=dict)
    # A watchdog any request resets (keepalive mode any_frame): its time, s (None: none).
    frame_watchdog_s: float | None = None

    def exit_stops(self) -> dict[str, str]:
        """Motion group -> the trigger that stops it (the group's first stop trigger), for
        the groups a ``starts_motion`` trigger belongs to."""
        triggers = self.spec.commands.triggers
        groups = {t.group for t in triggers if t.starts_motion}
        stops: dict[str, str] = {}
        for trigger in triggers:
            if trigger.stop and trigger.group in groups:
                stops.setdefault(trigger.group, trigger.name)
        return stops

    def allows(self, name: str, value: float) -> bool:
        """Whether ``value`` is one of register ``name``'s ``values`` (any, if it has none),
        compared as written on the wire (raw), so a scaled value's rounding does not count."""
        allowed = self.allowed_values.get(name)
        if allowed is None:
            return True
        register = self.register_map[name]
        try:
            raw = to_raw(register, value)
        except CodecError:
            return False
        return raw in {to_raw(register, choice) for choice in allowed}

    @property
    def name(self) -> str:
        return self.spec.device.name

    @property
    def unit_id(self) -> int:
        return self.spec.device.unit_id

    @property
    def commands(self) -> CommandsSpec:
        return self.spec.commands


@dataclass(frozen=True)
class Description:
    path: Path
    devices: tuple[Device, ...]
    line: Link | None  # several devices on one RTU line

    @property
    def device(self) -> Device:
        """The only device of a single-device file."""
        return self.devices[0]


def _value_type(spec: RegisterSpec) -> ValueType:
    return next(kind for kind in ValueType if kind.label == spec.type)


def _build_registers(device: DeviceFileSpec, check: Checker) -> RegisterMap | None:
    """The file's registers as a ``RegisterMap``: the rulebook (``Register``,
    ``RegisterMap``, ``DeviceLimits``) judges them, each fault at its key."""
    d = device.device
    try:
        limits: DeviceLimits | None = DeviceLimits(
            max_read_registers=d.max_read_registers,
            max_write_registers=d.max_write_registers,
            max_read_bits=d.max_read_bits,
            read_undefined_ok=d.read_undefined,
            max_gap=d.max_gap,
            function_codes=frozenset(d.function_codes),
            reply_delay_s=d.reply_delay_s,
        )
    except RuleError as err:
        check.faults(("device",), err.faults, {})
        limits = None
    # Each register's problems apart, listed in the file's order at the end.
    checks = [Checker(check.root, check.prefix) for _ in device.registers]
    built: list[tuple[int, Register]] = []
    for index, spec in enumerate(device.registers):
        at: Loc = ("registers", index)
        values_ok = _check_values_key(spec, checks[index], at)
        try:
            register = _register(spec, WordOrder(d.word_order))
        except RuleError as err:
            checks[index].faults(at, err.faults, REGISTER_KEYS)
            continue
        if values_ok and _writes_fit(spec, register, checks[index], at):
            built.append((index, register))
    register_map = None
    if limits is not None:
        try:
            register_map = RegisterMap(d.name, tuple(r for _, r in built), limits)
        except RuleError as err:
            for fault in err.faults:
                assert fault.index is not None
                index = built[fault.index][0]
                checks[index].faults(("registers", index), [fault], REGISTER_KEYS)
    for one in checks:
        check.problems += one.problems
    return None if check.problems else register_map


def _register(spec: RegisterSpec, default_order: WordOrder) -> Register:
    """The ``Register`` a register entry describes (raises the rulebook's ``RuleError``)."""
    return Register(
        name=spec.name,
        address=spec.address,
        value_type=_value_type(spec),
        doc=spec.manual,
        table=Table(spec.table),
        access=Access(spec.access.lower()),
        word_order=WordOrder(spec.word_order) if spec.word_order else default_order,
        scale=spec.scale,
        offset=spec.offset,
        unit=spec.unit,
        minimum=spec.range[0] if spec.range else None,
        maximum=spec.range[1] if spec.range else None,
        length=spec.length or 0,
        description=spec.description,
    )


def _check_values_key(spec: RegisterSpec, check: Checker, at: Loc) -> bool:
    """``values`` (the writes allowed) is the description's own key: for a writable number."""
    if spec.values is not None and spec.type in ("bool", "string"):
        check.add((*at, "values"), f"a {spec.type} has no values (a number register has)")
    elif spec.values is not None and spec.access == "R":
        check.add((*at, "values"), "values are the writes allowed: for access W or RW")
    else:
        return True
    return False


def _writes_fit(spec: RegisterSpec, register: Register, check: Checker, at: Loc) -> bool:
    """Whether the ends of ``range`` and every one of ``values`` can be written (the
    codec's rule: its refusal is the message)."""
    writes = [((*at, "range"), end, f"{end} does not fit the register") for end in spec.range or ()]
    writes += [
        ((*at, "values"), value, f"{number_text(value)} cannot be written")
        for value in spec.values or ()
    ]
    for where, value, what in writes:
        try:
            encode(register, value)
        except CodecError as err:
            check.add(where, f"{what}: {err}")
            return False
    return True


def _build_device(
    spec: DeviceFileSpec, check: Checker, *, on_line: bool, line_timeout_s: float | None = None
) -> Device | None:
    link = spec.device.link
    timeout_s = link.timeout_s if link is not None else line_timeout_s
    if timeout_s is not None and spec.device.reply_delay_s >= timeout_s:
        check.add(
            ("device", "reply_delay_s"),
            f"{spec.device.reply_delay_s} s is not below the link's timeout_s {timeout_s} s "
            "(every reply would time out)",
        )
    if on_line and link is not None:
        check.add(("device", "link"), "a device on the file's line has no link of its own")
    if not on_line:
        if link is None:
            check.add(("device", "link"), "missing (required: tcp or rtu)")
        elif (link.tcp is None) == (link.rtu is None):
            check.add(("device", "link"), "give exactly one of tcp and rtu")
    rtu_alone = link is not None and link.rtu is not None and link.tcp is None
    if (on_line or rtu_alone) and spec.device.unit_id == 0:
        broadcast = f"0 is the RTU broadcast: nobody answers (1-{UNIT_ID_MAX})"
        check.add(("device", "unit_id"), broadcast)
    register_map = _build_registers(spec, check)
    if register_map is None:
        return None
    joints = build_joints(spec, register_map, check)
    check_commands(spec, register_map, check)
    keepalive, frame_watchdog_s = build_keepalive(spec, register_map, check)
    if spec.device.require_keepalive and spec.keepalive is None:
        check.add(("device", "require_keepalive"), "true, but the file has no keepalive")
    polls = _check_poll_groups(spec, register_map, joints, check)
    readable = [r.name for r in register_map if r.access.readable and polls[r.name] != "never"]
    state = spec.device.state
    if state is not None:
        for index, name in enumerate(state):
            if name not in register_map or not register_map[name].access.readable:
                check.add(("device", "state", index), f"{name!r} is not a readable register")
            elif polls[name] == "never":
                check.add(("device", "state", index), f"{name!r} has poll: never (not polled)")
    if check.problems:
        return None
    built_link = None
    if link is not None:
        built_link = Link(
            "tcp" if link.tcp is not None else "rtu", link.timeout_s, link.tcp, link.rtu
        )
    return Device(
        spec,
        register_map,
        joints,
        built_link,
        tuple(state if state is not None else readable),
        allowed_values(spec),
        _address_texts(spec, check),
        keepalive,
        tuple(name for name, group in polls.items() if group == "slow"),
        polls,
        frame_watchdog_s,
    )


def _check_poll_groups(
    spec: DeviceFileSpec, register_map: RegisterMap, joints: Sequence[Joint], check: Checker
) -> dict[str, str]:
    """Each register's rate group: its own ``poll``, else the device's; a joint's registers
    are fast (joint_states is read every poll), and only a readable register is polled
    (a ``poll`` a register gives itself against these is refused)."""
    joint_registers = {
        source.register: joint.name
        for joint in joints
        for source in (joint.position, joint.velocity, joint.effort)
        if source is not None
    }
    polls: dict[str, str] = {}
    for index, register in enumerate(spec.registers):
        readable = register.name in register_map and register_map[register.name].access.readable
        if register.poll is None:
            fixed = register.name in joint_registers or not readable
            polls[register.name] = "fast" if fixed else spec.device.poll
            continue
        polls[register.name] = register.poll
        where = ("registers", index, "poll")
        if register.poll == "fast" or register.name not in register_map:
            continue
        if not readable:
            check.add(where, f"{register.poll}: a write-only register is never polled")
        elif register.name in joint_registers:
            joint = joint_registers[register.name]
            check.add(where, f"{register.poll}, but joint {joint!r} reads it (joints are fast)")
    return polls


def _address_texts(spec: DeviceFileSpec, check: Checker) -> dict[str, str]:
    """The addresses the file wrote in another notation than decimal (``0x2100``)."""
    texts: dict[str, str] = {}
    for index, register in enumerate(spec.registers):
        node = node_at(check.root, (*check.prefix, "registers", index, "address"))
        if isinstance(node, yaml.ScalarNode) and str(node.value) != str(register.address):
            texts[register.name] = str(node.value)
    return texts


def load_for_command(path: str | Path) -> Description | None:
    """``load`` for a command-line tool (``modbus_doc``, ``modbus_sim``): the refusal
    printed on stderr and None returned, the tool then exits ``EXIT_BAD_DESCRIPTION``."""
    try:
        return load(path)
    except DescriptionError as err:
        print(f"error: {err}", file=sys.stderr)
        return None


def load(path: str | Path) -> Description:
    """Read and validate a description file; raises ``DescriptionError`` (one line)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise DescriptionError(path, [Problem(0, "", f"cannot read: {err.strerror}")]) from None
    root, data = compose(path, raw)
    bus = "devices" in data or "line" in data
    model: type[BaseModel] = BusFileSpec if bus else DeviceFileSpec
    try:
        # Validated as JSON data in strict mode: a number is a number and text is text
        # everywhere (``scale: "100"`` is refused as ``address: "100"`` is), and a list
        # may fill a fixed-length pair (``range``). YAML's .inf/.nan survive the trip.
        parsed = model.model_validate_json(json.dumps(data), strict=True)
    except ValidationError as err:
        raise DescriptionError(path, key_problems(root, model, err)) from None
    problems: list[Problem] = []
    devices: list[Device] = []
    if isinstance(parsed, BusFileSpec):
        units: dict[int, int] = {}
        names: dict[str, int] = {}
        for index, device_spec in enumerate(parsed.devices):
            check = Checker(root, ("devices", index))
            unit, name = device_spec.device.unit_id, device_spec.device.name
            if unit in units:
                check.add(("device", "unit_id"), f"unit {unit} is devices[{units[unit]}]'s too")
            if name in names:
                check.add(("device", "name"), f"name {name!r} is devices[{names[name]}]'s too")
            units.setdefault(unit, index)
            names.setdefault(name, index)
            device = _build_device(
                device_spec, check, on_line=True, line_timeout_s=parsed.line.timeout_s
            )
            problems += check.problems
            if device is not None:
                devices.append(device)
        line = Link("rtu", parsed.line.timeout_s, rtu=parsed.line.rtu)
    else:
        assert isinstance(parsed, DeviceFileSpec)
        check = Checker(root, ())
        device = _build_device(parsed, check, on_line=False)
        problems += check.problems
        if device is not None:
            devices.append(device)
        line = None
    if problems:
        raise DescriptionError(path, problems)
    return Description(path, tuple(devices), line)
