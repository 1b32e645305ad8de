"""The keys of a description file: their types, choices and single-key ranges (pydantic),
and pydantic's refusals as problems at their key and line (unknown keys first, with the
key a typo probably meant).

The rules of a register and a device's limits are not repeated here: the built
``Register``, ``RegisterMap`` and ``DeviceLimits`` (bridge_core.wire.registers) state them.
"""

from __future__ import annotations

import difflib
from typing import Annotated, Any, Literal, get_args, get_origin

import yaml  # type: ignore[import-untyped]
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic_core import PydanticCustomError

from bridge_core.runtime.parameters import (
    BAUDRATE_RANGE,
    POLL_RATE_RANGE_HZ,
    TIMEOUT_MAX_S,
    DeviceDefaults,
)
from bridge_core.runtime.stream_guard import COMMAND_TIMEOUT_RANGE_S
from bridge_core.wire.batches import MAX_IN_FLIGHT_RANGE
from bridge_core.wire.channel import UNIT_ID_MAX
from bridge_core.wire.registers import (
    MAX_READ_BITS,
    MAX_READ_REGISTERS,
    MAX_WRITE_BITS,
    MAX_WRITE_REGISTERS,
)

from .description_yaml import Loc, Problem, format_loc, line_of

# Function codes a description may list: the reads and writes of the four tables, and
# mask write (0x16) / read-write multiple (0x17), which the simulator base serves.
KNOWN_FUNCTION_CODES = (1, 2, 3, 4, 5, 6, 15, 16, 22, 23)
FunctionCode = Literal[1, 2, 3, 4, 5, 6, 15, 16, 22, 23]
DEFAULT_FUNCTION_CODES: tuple[FunctionCode, ...] = (1, 2, 3, 4, 5, 6, 15, 16)
TIMEOUT_RANGE_S = (DeviceDefaults.timeout_min_s, TIMEOUT_MAX_S)
COMMAND_RATE_RANGE_HZ = (0.1, 100.0)
NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_]*$"
PARITY_WORDS = {"none": "N", "even": "E", "odd": "O", "n": "N", "e": "E", "o": "O"}
# What a file may write for parity, as its refusal says it. Mark and space (pyserial's M
# and S) are not offered: no Modbus RTU framing uses them (the spec: even, odd or none).
PARITY_ALLOWED = "N, E or O (or none, even, odd; any case)"
# The baud rates a file may give: the standard serial rates Modbus devices offer (a rate
# like 19201 is a typo, and a UART would run it at some nearby rate or refuse it).
STANDARD_BAUDRATES = (
    300,
    600,
    1200,
    2400,
    4800,
    9600,
    14400,
    19200,
    38400,
    57600,
    115200,
    230400,
    460800,
    921600,
)
# How often a register is read: fast (every poll), slow (every slow_poll_period_s), never
# (on request only: ~/read).
PollGroup = Literal["fast", "slow", "never"]
# The motion group a trigger belongs to when the file names none.
DEFAULT_MOTION_GROUP = "motion"
KEEPALIVE_PERIOD_RANGE_S = (0.01, 3600.0)


Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=64)]
Text = Annotated[str, Field(min_length=1)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class _Strict(BaseModel):
    """Unknown keys are errors (a typo must not be ignored); no type coercion from text."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class _Lenient(_Strict):
    """Numbers where a float is wanted may be written as integers (``scale: 10``)."""

    model_config = ConfigDict(extra="forbid", strict=False, frozen=True)


class TcpLinkSpec(_Strict):
    host: Text = "127.0.0.1"
    port: int = Field(502, ge=1, le=65535)
    # Reads of a poll in flight before the first reply; the node parameter of the same
    # name overrides it (docs/architecture.md, "Pipelined Modbus TCP").
    max_in_flight: int = Field(1, ge=MAX_IN_FLIGHT_RANGE[0], le=MAX_IN_FLIGHT_RANGE[1])


class RtuLinkSpec(_Lenient):
    serial_port: Text = "/dev/ttyUSB0"
    baudrate: int = Field(9600, ge=BAUDRATE_RANGE[0], le=BAUDRATE_RANGE[1], strict=True)
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    frame_gap_s: Finite = Field(0.0, ge=0.0, le=1.0)

    @field_validator("baudrate")
    @classmethod
    def _standard_rate(cls, value: int) -> int:
        if value not in STANDARD_BAUDRATES:
            rates = ", ".join(str(rate) for rate in STANDARD_BAUDRATES)
            raise PydanticCustomError(
                "baudrate", "not a standard baud rate (allowed: {rates})", {"rates": rates}
            )
        return value

    @field_validator("parity", mode="before")
    @classmethod
    def _parity_word(cls, value: Any) -> Any:
        """``none | even | odd`` (any case) and ``n | e | o`` are the letters N, E, O."""
        if isinstance(value, str):
            letter = PARITY_WORDS.get(value.lower())
            if letter is None:
                raise PydanticCustomError("parity", f"parity is {PARITY_ALLOWED}")
            return letter
        return value


class LinkSpec(_Lenient):
    """Where the device is by default; ``-p host:=`` etc. override it."""

    tcp: TcpLinkSpec | None = None
    rtu: RtuLinkSpec | None = None
    timeout_s: Finite = Field(0.5, ge=TIMEOUT_RANGE_S[0], le=TIMEOUT_RANGE_S[1])


class DeviceSpec(_Lenient):
    name: Name
    manual: Text
    title: str = ""
    link: LinkSpec | None = None
    unit_id: int = Field(1, ge=0, le=UNIT_ID_MAX, strict=True)
    word_order: Literal["high_first", "low_first"] = "high_first"
    # The bounds of these and of max_gap are DeviceLimits' rules.
    max_read_registers: int = Field(MAX_READ_REGISTERS, strict=True)
    max_write_registers: int = Field(MAX_WRITE_REGISTERS, strict=True)
    max_read_bits: int = Field(MAX_READ_BITS, strict=True)
    max_write_bits: int = Field(MAX_WRITE_BITS, ge=1, le=MAX_WRITE_BITS, strict=True)
    function_codes: list[FunctionCode] = Field(
        default_factory=lambda: list(DEFAULT_FUNCTION_CODES), min_length=1
    )
    read_undefined: bool = False
    max_gap: int | None = Field(None, strict=True)  # a cap
    reply_delay_s: Finite = Field(0.0, ge=0.0, le=10.0)
    poll_rate_hz: Finite = Field(10.0, ge=POLL_RATE_RANGE_HZ[0], le=POLL_RATE_RANGE_HZ[1])
    state: list[Name] | None = None
    # Motion commands (starts_motion triggers, command topic values) are refused until the
    # keepalive is armed (its first feed written; mode any_frame: the link is up).
    require_keepalive: bool = False
    # The rate group of every register that does not give its own ``poll`` (a joint's
    # registers are always fast).
    poll: PollGroup = "fast"


class RegisterSpec(_Lenient):
    name: Name
    table: Literal["coil", "discrete_input", "holding", "input"]
    # What a register may be (address range, type per table, scale, ...) is Register's
    # and RegisterMap's rules; only the types of the keys are checked here.
    address: int = Field(strict=True)
    type: Literal["bool", "u16", "i16", "u32", "i32", "u64", "i64", "f32", "f64", "string"]
    manual: str
    # Any length given is 1..125 (no request carries more), whatever the register's access.
    length: int | None = Field(None, ge=1, le=MAX_READ_REGISTERS, strict=True)
    word_order: Literal["high_first", "low_first"] | None = None
    scale: Finite = 1.0
    offset: Finite = 0.0
    unit: str = ""
    access: Literal["R", "RW", "W"] = "R"
    range: tuple[Finite, Finite] | None = None
    values: list[Finite] | None = Field(None, min_length=1, description="the allowed writes")
    # Its rate group (PollGroup); None: the device's ``poll`` (a joint's register: fast).
    poll: PollGroup | None = None
    description: str = ""


class JointValueSpec(_Lenient):
    register_name: Name = Field(alias="register")
    factor: Finite = Field(1.0, description="extra factor, e.g. 1 / gear ratio")
    per_revolution: Finite | None = Field(None, gt=0.0, description="Hz registers: cycles per rev")


class FollowSpec(_Lenient):
    """A monitor register ``modbus_sim`` sets from a joint's motion, by one rule: a value
    while running and one while stopped, or the joint's velocity (``velocity``), its
    magnitude (``speed``) or the command that counts (``command``), each in the sim
    command register's unit (per second in mode position) times the factor given."""

    running: Finite | None = None
    stopped: Finite | None = None
    velocity: Finite | None = None
    speed: Finite | None = None
    command: Finite | None = None


class JointSimSpec(_Lenient):
    """How ``modbus_sim`` moves the joint: after a command register, in its SI units."""

    command: Name  # a writable register: a velocity (mode velocity) or a target position
    mode: Literal["velocity", "position"] = "velocity"
    speed: Finite | None = Field(None, gt=0.0)  # position mode: SI units per second
    per_revolution: Finite | None = Field(None, gt=0.0)  # a Hz command: cycles per revolution
    # mode velocity: the velocity follows the command as a first-order lag (a drive's
    # ramp; None: at once).
    time_constant_s: Finite | None = Field(None, gt=0.0, le=3600.0)
    # The command counts only while this register holds one of these values (a drive's
    # control word: run forward / run reverse); any other value: the target is 0.
    run_register: Name | None = None
    run_values: list[Finite] | None = Field(None, min_length=1)
    # Registers the simulated device sets from the joint's motion (a drive's status word,
    # its output current, its frequency reference): register name -> the rule.
    follows: dict[Name, FollowSpec] | None = None


class JointCommandSpec(_Lenient):
    """What ``~/joint_commands`` writes for the joint: a target position register, a
    velocity register, or both (a message gives one kind at a time)."""

    position: JointValueSpec | None = None
    velocity: JointValueSpec | None = None


class JointSpec(_Lenient):
    name: Name
    kind: Literal["revolute", "prismatic"] = "revolute"
    position: JointValueSpec | None = None  # a drive may give only a velocity
    velocity: JointValueSpec | None = None
    effort: JointValueSpec | None = None
    sim: JointSimSpec | None = None
    command: JointCommandSpec | None = None


class WriteSpec(_Lenient):
    register_name: Name = Field(alias="register")
    value: Any  # a number or true/false: checked against the register (_check_commands)


class TriggerSpec(_Lenient):
    name: Name
    writes: list[WriteSpec] = Field(min_length=1)
    stop: bool = False
    # A trigger that starts motion: the bridge sends its group's (first) stop trigger on
    # every way out (Ctrl-C, SIGTERM, deactivate, shutdown, a fatal error) if it ran since
    # that group's last stop. Every trigger that is not a stop must say true or false
    # (None: not said, refused at load).
    starts_motion: bool | None = None
    group: Name = DEFAULT_MOTION_GROUP
    description: str = ""


class ValueServiceSpec(_Lenient):
    name: Name
    register_name: Name = Field(alias="register")
    # Required (false) on a service writing a register one of the file's stops writes: a
    # service's start is never stopped on the way out (only a trigger's is).
    starts_motion: bool | None = None
    description: str = ""


class CoilServiceSpec(_Lenient):
    name: Name
    register_name: Name = Field(alias="register")
    stop_on: bool | None = None  # the coil value that stops motion (tried at once)
    starts_motion: bool | None = None  # as a value service's
    description: str = ""


class TopicSpec(_Lenient):
    name: Name
    register_name: Name = Field(alias="register")
    scale: Finite = Field(1.0, description="register value per message unit")
    stop_value: Finite = Field(0.0, description="register value written to stop: must be 0")
    timeout_s: Finite = Field(0.5, ge=COMMAND_TIMEOUT_RANGE_S[0], le=COMMAND_TIMEOUT_RANGE_S[1])
    rate_hz: Finite = Field(10.0, ge=COMMAND_RATE_RANGE_HZ[0], le=COMMAND_RATE_RANGE_HZ[1])
    description: str = ""


class KeepaliveSpec(_Lenient):
    """A device watchdog the bridge feeds (from a thread at the link's top priority), or,
    mode ``any_frame``, one that every request resets (the polls feed it; no register)."""

    register_name: Name | None = Field(None, alias="register")
    mode: Literal["value", "toggle", "counter", "any_frame"] = "value"
    # mode value: what each feed writes (None: the register's value, read when arming)
    value: Finite | None = None
    # The device's watchdog time (it stops when no feed came for this long): given, or
    # read from a register (unit s or ms) when arming.
    period_s: Finite | None = Field(
        None, ge=KEEPALIVE_PERIOD_RANGE_S[0], le=KEEPALIVE_PERIOD_RANGE_S[1]
    )
    period_from: Name | None = None


class CommandsSpec(_Lenient):
    triggers: list[TriggerSpec] = []
    values: list[ValueServiceSpec] = []
    coils: list[CoilServiceSpec] = []
    topics: list[TopicSpec] = []


class DeviceFileSpec(_Lenient):
    """One device (the usual file), or one entry of ``devices`` on a shared RTU line."""

    device: DeviceSpec
    registers: list[RegisterSpec] = Field(min_length=1)
    joints: list[JointSpec] = []
    commands: CommandsSpec = CommandsSpec()
    keepalive: KeepaliveSpec | None = None


class LineSpec(_Lenient):
    rtu: RtuLinkSpec
    timeout_s: Finite = Field(0.5, ge=TIMEOUT_RANGE_S[0], le=TIMEOUT_RANGE_S[1])


class BusFileSpec(_Lenient):
    """Several devices on one RTU line: one bus owner, one node per device."""

    line: LineSpec
    devices: list[DeviceFileSpec] = Field(min_length=1)


# pydantic error types of a number field given something else (text is never a number).
_NUMBER_ERRORS = frozenset(
    {"int_type", "int_parsing", "float_type", "float_parsing", "int_from_float"}
)


def _model_at(model: Any, loc: Loc) -> Any:
    """The model class a key path leads to (for the keys an unknown key could have been)."""
    for part in loc:
        if isinstance(part, int):
            continue
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            return None
        field = next(
            (f for name, f in model.model_fields.items() if (f.alias or name) == part), None
        )
        if field is None:
            return None
        model = _unwrap(field.annotation)
    return model


def _unwrap(annotation: Any) -> Any:
    """``list[X]``, ``X | None`` -> ``X`` (the model inside)."""
    while True:
        args = [a for a in get_args(annotation) if a is not type(None)]
        if get_origin(annotation) is Annotated:
            annotation = args[0]
        elif args and any(isinstance(a, type) and issubclass(a, BaseModel) for a in args):
            annotation = next(a for a in args if isinstance(a, type) and issubclass(a, BaseModel))
        elif get_origin(annotation) in (list, tuple) and args:
            annotation = args[0]
        else:
            return annotation


def _allowed_keys(model: type[BaseModel], loc: Loc) -> list[str]:
    parent = _model_at(model, loc)
    if parent is None:
        return []
    return [f.alias or name for name, f in parent.model_fields.items()]


def key_problems(root: yaml.Node, model: type[BaseModel], err: ValidationError) -> list[Problem]:
    """One problem per pydantic error, unknown keys first: a misspelt key also makes
    the key it should have been "missing", and the typo is what the user must see."""
    errors = err.errors(include_url=False)
    unknown: list[Problem] = []
    problems: list[Problem] = []
    guessed: set[Loc] = set()  # missing keys an unknown key was probably meant to be
    for item in errors:
        loc: Loc = tuple(item["loc"])
        if item["type"] != "extra_forbidden":
            continue
        allowed = _allowed_keys(model, loc[:-1])
        close = difflib.get_close_matches(str(loc[-1]), allowed, n=1, cutoff=0.6)
        message = f"unknown key (allowed: {', '.join(allowed) or 'none'})"
        if close:
            message = f"unknown key: did you mean `{close[0]}`? " + message[len("unknown key ") :]
            guessed.add((*loc[:-1], close[0]))
        unknown.append(Problem(line_of(root, loc), format_loc(loc), message))
    for item in errors:
        loc = tuple(item["loc"])
        kind = item["type"]
        if kind == "extra_forbidden" or (kind == "missing" and loc in guessed):
            continue
        given = item.get("input")
        if kind == "missing":
            message = "missing (required)"
        elif isinstance(given, str) and kind in _NUMBER_ERRORS:
            message = (
                f"{given!r} is text, not a number (write numbers unquoted: decimal, "
                "or 0x... for hex)"
            )
        elif isinstance(given, bool) and kind in ("literal_error", "string_type"):
            message = (
                f"{item['msg']}, not the boolean {str(given).lower()} "
                "(quote it if you meant a letter or word)"
            )
        else:
            message = item["msg"]
            if "input" in item and not isinstance(given, dict | list):
                message += f", not {given!r}"
        problems.append(Problem(line_of(root, loc), format_loc(loc), message))
    return unknown + problems
