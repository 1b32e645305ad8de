"""Device description files: any Modbus device as a validated YAML register map.

One file drives the node (``modbus_bridge``), the simulator (``modbus_sim``) and the docs
(``modbus_doc``). pydantic checks the shape of the file (types, ranges, choices, unknown
keys); the checks that need several keys at once (a register's type against its table, a
joint's register and unit, a command's register and value) run after it. Every problem
is reported as ``FILE:LINE: key.path: what is wrong (what is allowed)`` on one line, the
line taken from the YAML node the key path leads to (PyYAML's composer keeps the marks).

The result is built from bridge_core's own types (``Register``, ``RegisterMap``,
``DeviceLimits``), so the planner, codec, poller and simulator base serve a described
device exactly as they serve the four hand-written bridges.
"""

from __future__ import annotations

import difflib
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, get_args, get_origin

import yaml  # type: ignore[import-untyped]
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from bridge_core.codec import CodecError, encode, to_raw
from bridge_core.errors import ConfigurationError
from bridge_core.registers import (
    MAX_ADDRESS,
    MAX_READ_BITS,
    MAX_READ_REGISTERS,
    MAX_WRITE_BITS,
    MAX_WRITE_REGISTERS,
    Access,
    DeviceLimits,
    Register,
    RegisterMap,
    Table,
    ValueType,
    WordOrder,
)
from bridge_core.stream_guard import COMMAND_TIMEOUT_RANGE_S
from bridge_core.units import DEG, MM, RPM_TO_RAD_S

# Function codes a description may list: the reads and writes of the four tables, and
# mask write (0x16) / read-write multiple (0x17), which the simulator base serves.
KNOWN_FUNCTION_CODES = (1, 2, 3, 4, 5, 6, 15, 16, 22, 23)
FunctionCode = Literal[1, 2, 3, 4, 5, 6, 15, 16, 22, 23]
DEFAULT_FUNCTION_CODES: tuple[FunctionCode, ...] = (1, 2, 3, 4, 5, 6, 15, 16)
READ_FUNCTION = {Table.COIL: 1, Table.DISCRETE_INPUT: 2, Table.HOLDING: 3, Table.INPUT: 4}
WRITE_FUNCTIONS = {Table.COIL: (5, 15), Table.HOLDING: (6, 16)}
UNIT_ID_MAX = 247
BAUDRATE_RANGE = (300, 4_000_000)
TIMEOUT_RANGE_S = (0.01, 10.0)
POLL_RATE_RANGE_HZ = (0.1, 1000.0)
COMMAND_RATE_RANGE_HZ = (0.1, 100.0)
# Names the node gives its own services and topics: a command may not take them.
RESERVED_NAMES = frozenset({"read", "write", "state", "connected"})
# The parameters the node declares itself (rclpy, bridge_core.node_base, ``device_file``): a
# command topic's generated parameters (<name>_timeout_s, <name>_rate_hz) may not be one
# (a topic ``poll`` would declare ``poll_rate_hz``). tests/modbus/test_modbus_ros.py checks
# this list against a running node's.
NODE_PARAMETERS = frozenset(
    {
        "host",
        "port",
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
        "joint_prefix",
        "frame_id",
        "read_only",
        "autostart",
        "device_file",
        "use_sim_time",  # rclpy's own
        "start_type_description_service",
    }
)
TOPIC_PARAMETER_SUFFIXES = ("_timeout_s", "_rate_hz")
NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_]*$"
PARITY_WORDS = {"none": "N", "even": "E", "odd": "O", "n": "N", "e": "E", "o": "O"}
# The motion group a trigger belongs to when the file names none.
DEFAULT_MOTION_GROUP = "motion"
# Units a keepalive's ``period_from`` register may have, as the factor to seconds.
PERIOD_UNITS_TO_S = {"s": 1.0, "ms": 1e-3}
KEEPALIVE_PERIOD_RANGE_S = (0.01, 3600.0)
# A keepalive register is one 16-bit register (fed with FC 06 at the link's top priority).
KEEPALIVE_TYPES = ("u16", "i16")

# Register units a joint value may have, as (SI unit, factor to it). REP 103: positions in
# rad or m, velocities in rad/s or m/s, efforts in N·m or N.
UNITS_TO_SI: dict[str, tuple[str, float]] = {
    "rad": ("rad", 1.0),
    "mrad": ("rad", 1e-3),
    "deg": ("rad", DEG),
    "rev": ("rad", 2.0 * math.pi),
    "m": ("m", 1.0),
    "mm": ("m", MM),
    "um": ("m", 1e-6),
    "rad/s": ("rad/s", 1.0),
    "deg/s": ("rad/s", DEG),
    "rpm": ("rad/s", RPM_TO_RAD_S),
    # A drive's frequency: one revolution per cycle, or ``per_revolution`` cycles (Hz) per
    # revolution (e.g. a motor's pole pairs); the factor is 2 pi / per_revolution.
    "Hz": ("rad/s", 2.0 * math.pi),
    "m/s": ("m/s", 1.0),
    "mm/s": ("m/s", MM),
    "N.m": ("N.m", 1.0),
    "mN.m": ("N.m", 1e-3),
    "N": ("N", 1.0),
    "kN": ("N", 1e3),
}
SI_UNITS = {
    ("revolute", "position"): "rad",
    ("revolute", "velocity"): "rad/s",
    ("revolute", "effort"): "N.m",
    ("prismatic", "position"): "m",
    ("prismatic", "velocity"): "m/s",
    ("prismatic", "effort"): "N",
}

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


class RtuLinkSpec(_Lenient):
    serial_port: Text = "/dev/ttyUSB0"
    baudrate: int = Field(9600, ge=BAUDRATE_RANGE[0], le=BAUDRATE_RANGE[1], strict=True)
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    frame_gap_s: Finite = Field(0.0, ge=0.0, le=1.0)

    @field_validator("parity", mode="before")
    @classmethod
    def _parity_word(cls, value: Any) -> Any:
        """``none | even | odd`` (any case) and ``n | e | o`` are the letters N, E, O."""
        if isinstance(value, str):
            return PARITY_WORDS.get(value.lower(), value)
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
    max_read_registers: int = Field(MAX_READ_REGISTERS, ge=1, le=MAX_READ_REGISTERS, strict=True)
    max_write_registers: int = Field(MAX_WRITE_REGISTERS, ge=1, le=MAX_WRITE_REGISTERS, strict=True)
    max_read_bits: int = Field(MAX_READ_BITS, ge=1, le=MAX_READ_BITS, strict=True)
    max_write_bits: int = Field(MAX_WRITE_BITS, ge=1, le=MAX_WRITE_BITS, strict=True)
    function_codes: list[FunctionCode] = Field(
        default_factory=lambda: list(DEFAULT_FUNCTION_CODES), min_length=1
    )
    read_undefined: bool = False
    max_gap: int | None = Field(None, ge=0, le=MAX_READ_REGISTERS, strict=True)  # a cap
    reply_delay_s: Finite = Field(0.0, ge=0.0, le=10.0)
    poll_rate_hz: Finite = Field(10.0, ge=POLL_RATE_RANGE_HZ[0], le=POLL_RATE_RANGE_HZ[1])
    state: list[Name] | None = None
    # Motion commands (starts_motion triggers, command topic values) are refused until the
    # keepalive is armed (its first feed written).
    require_keepalive: bool = False


class RegisterSpec(_Lenient):
    name: Name
    table: Literal["coil", "discrete_input", "holding", "input"]
    address: int = Field(ge=0, le=MAX_ADDRESS, strict=True)
    type: Literal["bool", "u16", "i16", "u32", "i32", "u64", "i64", "f32", "f64", "string"]
    manual: Text
    length: int | None = Field(None, ge=1, le=MAX_READ_REGISTERS, strict=True)
    word_order: Literal["high_first", "low_first"] | None = None
    scale: Finite = Field(1.0, gt=0.0)
    offset: Finite = 0.0
    unit: str = ""
    access: Literal["R", "RW", "W"] = "R"
    range: tuple[Finite, Finite] | None = None
    values: list[Finite] | None = Field(None, min_length=1, description="the allowed writes")
    description: str = ""


class JointValueSpec(_Lenient):
    register_name: Name = Field(alias="register")
    factor: Finite = Field(1.0, description="extra factor, e.g. 1 / gear ratio")
    per_revolution: Finite | None = Field(None, gt=0.0, description="Hz registers: cycles per rev")


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


class JointSpec(_Lenient):
    name: Name
    kind: Literal["revolute", "prismatic"] = "revolute"
    position: JointValueSpec | None = None  # a drive may give only a velocity
    velocity: JointValueSpec | None = None
    effort: JointValueSpec | None = None
    sim: JointSimSpec | None = None


class WriteSpec(_Lenient):
    register_name: Name = Field(alias="register")
    value: Any  # a number or true/false: checked against the register (_check_commands)


class TriggerSpec(_Lenient):
    name: Name
    writes: list[WriteSpec] = Field(min_length=1)
    stop: bool = False
    # A trigger that starts motion: the bridge sends its group's (first) stop trigger on
    # every way out (Ctrl-C, SIGTERM, deactivate, shutdown, a fatal error) if it ran since
    # that group's last stop.
    starts_motion: bool = False
    group: Name = DEFAULT_MOTION_GROUP
    description: str = ""


class ValueServiceSpec(_Lenient):
    name: Name
    register_name: Name = Field(alias="register")
    description: str = ""


class CoilServiceSpec(_Lenient):
    name: Name
    register_name: Name = Field(alias="register")
    stop_on: bool | None = None  # the coil value that stops motion (tried at once)
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
    """A device watchdog the bridge feeds (from a thread at the link's top priority)."""

    register_name: Name = Field(alias="register")
    mode: Literal["value", "toggle", "counter"] = "value"
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


# ---------------------------------------------------------------- built description
@dataclass(frozen=True)
class JointSource:
    """A register and the factor that turns its engineering value into SI."""

    register: str
    to_si: float


@dataclass(frozen=True)
class JointMotion:
    """The simulator's rule for a joint: ``command`` (to SI by ``to_si``) is a velocity or
    a target position; a target is approached at ``speed`` (SI/s; None: at once); a
    velocity follows its command with ``time_constant_s`` (None: at once), and only while
    ``run_register`` holds one of ``run_values``."""

    command: str
    to_si: float
    mode: Literal["velocity", "position"]
    speed: float | None
    time_constant_s: float | None = None
    run_register: str | None = None
    run_values: tuple[float, ...] = ()


@dataclass(frozen=True)
class Joint:
    name: str
    position: JointSource | None  # None: a velocity-only joint (NaN in joint_states)
    velocity: JointSource | None
    effort: JointSource | None
    motion: JointMotion | None = None


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


@dataclass(frozen=True)
class Problem:
    line: int
    path: str
    message: str


class DescriptionError(ConfigurationError):
    """A description file is not valid: the first problem as one line, all in ``problems``."""

    def __init__(self, path: Path, problems: Sequence[Problem]) -> None:
        self.path = path
        self.problems = list(problems)
        first = self.lines()[0]
        more = len(self.problems) - 1
        super().__init__(first + (f" (and {more} more problem(s))" if more else ""))

    def lines(self) -> list[str]:
        return [
            f"{self.path}:{p.line}: {p.path + ': ' if p.path else ''}{p.message}"
            for p in self.problems
        ]


# ---------------------------------------------------------------- YAML with line marks
Loc = tuple[str | int, ...]

# The tags a description may carry (YAML 1.2 core schema); any other tag (``!foo``,
# ``!!python/object``, ``!!binary``, ``!!timestamp``) is refused: a description is data.
STR_TAG = "tag:yaml.org,2002:str"
INT_TAG = "tag:yaml.org,2002:int"
FLOAT_TAG = "tag:yaml.org,2002:float"
BOOL_TAG = "tag:yaml.org,2002:bool"
NULL_TAG = "tag:yaml.org,2002:null"
MAP_TAG = "tag:yaml.org,2002:map"
SEQ_TAG = "tag:yaml.org,2002:seq"
# Nodes one file may expand to (aliases copy what they name): a few nested aliases must
# not make a file of a few lines take all memory ("billion laughs").
MAX_NODES = 200_000
# pydantic error types of a number field given something else (text is never a number).
_NUMBER_ERRORS = frozenset(
    {"int_type", "int_parsing", "float_type", "float_parsing", "int_from_float"}
)
_DECIMAL = re.compile(r"^[-+]?[0-9]+$")
_OCTAL = re.compile(r"^0o[0-7]+$")
_HEX = re.compile(r"^0x[0-9a-fA-F]+$")
_LEADING_ZERO = re.compile(r"^[-+]?0[0-9]+$")
_FLOAT = re.compile(r"^[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?$")
_INF = re.compile(r"^[-+]?\.(inf|Inf|INF)$")
_NAN = re.compile(r"^\.(nan|NaN|NAN)$")


class _Resolver(yaml.resolver.Resolver):  # type: ignore[misc]
    """YAML 1.2 core schema: ``0100`` is not octal (it is refused, see ``_int``), ``1:30``
    is not base 60, ``yes``/``no``/``on``/``off`` are text, ``0x2100`` is hex."""

    yaml_implicit_resolvers: ClassVar[dict[str | None, list[tuple[str, re.Pattern[str]]]]] = {}


for _tag, _pattern, _first in (
    (BOOL_TAG, r"^(?:true|True|TRUE|false|False|FALSE)$", "tTfF"),
    (NULL_TAG, r"^(?:~|null|Null|NULL|)$", ["~", "n", "N", ""]),
    (INT_TAG, r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$", "-+0123456789"),
    (
        FLOAT_TAG,
        r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
        r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$",
        "-+0123456789.",
    ),
):
    _Resolver.add_implicit_resolver(_tag, re.compile(_pattern), list(_first))


class _Loader(
    yaml.reader.Reader,  # type: ignore[misc]
    yaml.scanner.Scanner,  # type: ignore[misc]
    yaml.parser.Parser,  # type: ignore[misc]
    yaml.composer.Composer,  # type: ignore[misc]
    _Resolver,
):
    """PyYAML's reader, scanner, parser and composer (nodes keep their line) with the
    YAML 1.2 resolver; the nodes are turned into data by ``_Builder``, not by PyYAML."""

    def __init__(self, stream: str) -> None:
        yaml.reader.Reader.__init__(self, stream)
        yaml.scanner.Scanner.__init__(self)
        yaml.parser.Parser.__init__(self)
        yaml.composer.Composer.__init__(self)
        _Resolver.__init__(self)


class _Refused(Exception):
    """A node the builder cannot turn into data: its line and what is wrong."""

    def __init__(self, node: yaml.Node, loc: Loc, message: str, line: int | None = None) -> None:
        super().__init__(message)
        line = int(node.start_mark.line) + 1 if line is None else line
        self.problem = Problem(line, format_loc(loc), message)


class _Builder:
    """Plain data (dict, list, str, int, float, bool, None) from composed YAML nodes.

    Written here rather than taken from PyYAML's constructor so that every refusal has
    the node's line and key path: a key that is not text (``? [a, b]``), an alias that
    contains itself, a tag that is not plain data, a key given twice, an integer with a
    leading zero (YAML 1.1 read ``0100`` as octal 64, a user padding addresses means 100:
    neither reading is safe, so the file must say which).
    """

    def __init__(self, root: yaml.Node) -> None:
        self.root = root
        self.nodes = 0

    def build(self, node: yaml.Node, loc: Loc, path: tuple[int, ...] = ()) -> Any:
        self.nodes += 1
        if self.nodes > MAX_NODES:
            # the line of the key whose aliases expand so far, not of the anchor's node
            line = line_of(self.root, loc[:1])
            raise _Refused(node, loc[:1], f"more than {MAX_NODES} values (aliases expanded)", line)
        if id(node) in path:
            raise _Refused(node, loc, "a recursive alias (an anchor used inside itself)")
        if isinstance(node, yaml.ScalarNode):
            return self._scalar(node, loc)
        inner = (*path, id(node))
        if isinstance(node, yaml.SequenceNode):
            if node.tag != SEQ_TAG:
                raise _Refused(node, loc, _tag_text(node.tag))
            return [self.build(item, (*loc, i), inner) for i, item in enumerate(node.value)]
        assert isinstance(node, yaml.MappingNode)
        if node.tag != MAP_TAG:
            raise _Refused(node, loc, _tag_text(node.tag))
        data: dict[str, Any] = {}
        merged: dict[str, Any] = {}
        for key, value in node.value:
            if not isinstance(key, yaml.ScalarNode):
                raise _Refused(key, loc, "a key must be a plain name, not a list or mapping")
            if key.tag not in (STR_TAG, INT_TAG, FLOAT_TAG, BOOL_TAG, NULL_TAG):
                raise _Refused(key, loc, _tag_text(key.tag))
            name = str(key.value)
            if name == "<<" and key.style is None:
                # A merge key: the keys of the mapping(s) it names, unless given here.
                sources = value.value if isinstance(value, yaml.SequenceNode) else [value]
                for source in sources:
                    built = self.build(source, (*loc, name), inner)
                    if not isinstance(built, dict):
                        raise _Refused(source, (*loc, name), "a merge key (<<) takes a mapping")
                    merged = {**built, **merged}
                continue
            if name in data:
                raise _Refused(key, (*loc, name), "key given twice (each key once)")
            data[name] = self.build(value, (*loc, name), inner)
        return {**merged, **data}

    def _scalar(self, node: yaml.ScalarNode, loc: Loc) -> Any:
        text, tag = str(node.value), node.tag
        if tag == STR_TAG:
            return text
        if tag == NULL_TAG and text in ("~", "null", "Null", "NULL", ""):
            return None
        if tag == BOOL_TAG and text.lower() in ("true", "false"):
            return text.lower() == "true"
        if tag == INT_TAG:
            return self._int(node, text, loc)
        if tag == FLOAT_TAG:
            if _INF.match(text):
                return -math.inf if text.startswith("-") else math.inf
            if _NAN.match(text):
                return math.nan
            if _FLOAT.match(text):
                return float(text)
        if tag in (NULL_TAG, BOOL_TAG, FLOAT_TAG):
            raise _Refused(node, loc, f"{text!r} is not a {tag.rsplit(':', 1)[1]}")
        raise _Refused(node, loc, _tag_text(tag))

    def _int(self, node: yaml.ScalarNode, text: str, loc: Loc) -> int:
        if _LEADING_ZERO.match(text):
            digits = text.lstrip("+-").lstrip("0") or "0"
            raise _Refused(
                node,
                loc,
                f"{text}: a leading zero is not read (YAML 1.1 took it as octal); write "
                f"{text[0] if text[0] in '+-' else ''}{digits} for decimal, or 0x... for hex",
            )
        if _DECIMAL.match(text):
            return int(text)
        if _HEX.match(text):
            return int(text[2:], 16)
        if _OCTAL.match(text):
            return int(text[2:], 8)
        raise _Refused(node, loc, f"{text!r} is not an integer (decimal, or 0x... for hex)")


def _tag_text(tag: str) -> str:
    return (
        f"tag {tag.replace('tag:yaml.org,2002:', '!!')} is not allowed "
        "(a description is plain data: text, numbers, true/false, lists, mappings)"
    )


def _compose(path: Path, raw: bytes) -> tuple[yaml.Node, dict[str, Any]]:
    """The file's root node (for line numbers) and its data; ``DescriptionError`` (one
    line with the line number) for anything that is not a YAML mapping of plain data."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise DescriptionError(
            path,
            [
                Problem(
                    line,
                    "",
                    f"byte 0x{raw[err.start]:02X} is not UTF-8 text "
                    "(a description is a UTF-8 YAML file, not a binary one)",
                )
            ],
        ) from None
    loader: _Loader | None = None
    try:
        loader = _Loader(text)  # its reader refuses non-printable characters at once
        node = loader.get_single_node()
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        line = mark.line + 1 if mark is not None else 1
        raise DescriptionError(
            path, [Problem(line, "", f"not valid YAML: {err.problem or err.context}")]
        ) from None
    except yaml.reader.ReaderError as err:
        line = text[: err.position].count("\n") + 1
        raise DescriptionError(
            path,
            [
                Problem(
                    line,
                    "",
                    f"character {err.character!r} is not allowed in YAML "
                    "(a description is a text file, not a binary one)",
                )
            ],
        ) from None
    except RecursionError:
        raise DescriptionError(path, [Problem(1, "", "nested too deeply")]) from None
    finally:
        if loader is not None:
            loader.dispose()
    if not isinstance(node, yaml.MappingNode):
        line = node.start_mark.line + 1 if node is not None else 1
        raise DescriptionError(path, [Problem(line, "", "the file must be a mapping of keys")])
    try:
        data = _Builder(node).build(node, ())
    except _Refused as err:
        raise DescriptionError(path, [err.problem]) from None
    except RecursionError:
        raise DescriptionError(path, [Problem(1, "", "nested too deeply")]) from None
    return node, data


def node_at(root: yaml.Node, loc: Loc) -> yaml.Node | None:
    """The node a key path leads to, or None."""
    node = root
    for part in loc:
        if isinstance(node, yaml.MappingNode):
            node = next((v for k, v in node.value if k.value == str(part)), None)
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
            node = node.value[part] if 0 <= part < len(node.value) else None
        else:
            return None
        if node is None:
            return None
    return node


def line_of(root: yaml.Node, loc: Loc) -> int:
    """The line of the deepest key (or list item) ``loc`` reaches: a missing key's line is
    its mapping's."""
    node = root
    line = int(root.start_mark.line) + 1
    for part in loc:
        if isinstance(node, yaml.MappingNode):
            pair = next(((k, v) for k, v in node.value if k.value == str(part)), None)
            if pair is None:
                break
            key, node = pair
            line = int(key.start_mark.line) + 1
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
            if not 0 <= part < len(node.value):
                break
            node = node.value[part]
            line = int(node.start_mark.line) + 1
        else:
            break
    return line


def format_loc(loc: Loc) -> str:
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


# ---------------------------------------------------------------- pydantic errors
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


def _problems(root: yaml.Node, model: type[BaseModel], err: ValidationError) -> list[Problem]:
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


# ---------------------------------------------------------------- cross-key checks
class _Checker:
    """Collects the problems that need several keys, each with its key path."""

    def __init__(self, root: yaml.Node, prefix: Loc) -> None:
        self.root = root
        self.prefix = prefix
        self.problems: list[Problem] = []

    def add(self, loc: Loc, message: str) -> None:
        full = (*self.prefix, *loc)
        self.problems.append(Problem(line_of(self.root, full), format_loc(full), message))


def _number_text(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def _value_type(spec: RegisterSpec) -> ValueType:
    return next(kind for kind in ValueType if kind.label == spec.type)


def _build_registers(device: DeviceFileSpec, check: _Checker) -> RegisterMap | None:
    default_order = WordOrder(device.device.word_order)
    functions = set(device.device.function_codes)
    registers: list[Register] = []
    owner: dict[tuple[Table, int], str] = {}
    names: set[str] = set()
    for index, spec in enumerate(device.registers):
        at: Loc = ("registers", index)
        table, kind, access = Table(spec.table), _value_type(spec), Access(spec.access.lower())
        ok = True
        if spec.name in names:
            check.add((*at, "name"), f"register {spec.name!r} defined twice (names are unique)")
            ok = False
        names.add(spec.name)
        if table.is_bit != (kind is ValueType.BOOL):
            allowed = "bool" if table.is_bit else "any type but bool"
            check.add((*at, "type"), f"{spec.type} in the {spec.table} table (allowed: {allowed})")
            ok = False
        if kind is ValueType.STRING and spec.length is None:
            check.add((*at, "length"), "missing: a string needs its length in registers")
            ok = False
        if kind is not ValueType.STRING and spec.length is not None:
            check.add((*at, "length"), "only a string has a length (its type fixes the size)")
            ok = False
        if access.writable and not table.writable:
            check.add((*at, "access"), f"{spec.access} on the read-only {spec.table} table (R)")
            ok = False
        count = spec.length or kind.words
        if spec.address + count - 1 > MAX_ADDRESS:
            check.add((*at, "address"), f"{spec.address}+{count} runs past 65535")
            ok = False
        limit = device.device.max_read_registers
        if access.readable and not table.is_bit and count > limit:
            check.add(
                (*at, "length" if spec.length is not None else "type"),
                f"{count} registers: more than one read takes ({limit})",
            )
            ok = False
        if kind in (ValueType.BOOL, ValueType.STRING) and (
            spec.scale != 1.0 or spec.offset != 0.0 or spec.range is not None
        ):
            check.add(at, f"a {spec.type} has no scale, offset or range")
            ok = False
        if spec.values is not None and (kind in (ValueType.BOOL, ValueType.STRING)):
            check.add((*at, "values"), f"a {spec.type} has no values (a number register has)")
            ok = False
        if spec.values is not None and not access.writable:
            check.add((*at, "values"), "values are the writes allowed: for access W or RW")
            ok = False
        if spec.range is not None and spec.range[0] > spec.range[1]:
            check.add((*at, "range"), f"[{spec.range[0]}, {spec.range[1]}]: minimum > maximum")
            ok = False
        if access.readable and READ_FUNCTION[table] not in functions:
            check.add(
                (*at, "table"),
                f"readable {spec.table} needs function code {READ_FUNCTION[table]} "
                "in device.function_codes (or access W)",
            )
            ok = False
        if access.writable and table.writable and not functions & set(WRITE_FUNCTIONS[table]):
            codes = " or ".join(str(c) for c in WRITE_FUNCTIONS[table])
            check.add(
                (*at, "access"),
                f"writable {spec.table} needs function code {codes} in device.function_codes",
            )
            ok = False
        if ok:
            for address in range(spec.address, spec.address + count):
                other = owner.get((table, address))
                if other is not None:
                    check.add(
                        (*at, "address"),
                        f"{spec.name} overlaps {other} at {spec.table} {address} "
                        "(each address belongs to one register)",
                    )
                    ok = False
                    break
                owner[(table, address)] = spec.name
        if not ok:
            continue
        register = Register(
            name=spec.name,
            address=spec.address,
            value_type=kind,
            doc=spec.manual,
            table=table,
            access=access,
            word_order=WordOrder(spec.word_order) if spec.word_order else default_order,
            scale=spec.scale,
            offset=spec.offset,
            unit=spec.unit,
            minimum=spec.range[0] if spec.range else None,
            maximum=spec.range[1] if spec.range else None,
            length=spec.length or 0,
            description=spec.description,
        )
        if spec.range is not None and kind is not ValueType.STRING:
            for end in spec.range:
                try:
                    encode(register, end)
                except CodecError as err:
                    check.add((*at, "range"), f"{end} does not fit the register: {err}")
                    ok = False
                    break
        if ok and spec.values is not None and kind is not ValueType.STRING:
            for value in spec.values:
                try:
                    to_raw(register, value)
                    encode(register, value)
                except CodecError as err:
                    check.add((*at, "values"), f"{_number_text(value)} cannot be written: {err}")
                    ok = False
                    break
        if ok:
            registers.append(register)
    if check.problems:
        return None
    d = device.device
    limits = DeviceLimits(
        max_read_registers=d.max_read_registers,
        max_write_registers=d.max_write_registers,
        max_read_bits=d.max_read_bits,
        read_undefined_ok=d.read_undefined,
        max_gap=d.max_gap,
        function_codes=frozenset(d.function_codes),
        reply_delay_s=d.reply_delay_s,
    )
    return RegisterMap(d.name, tuple(registers), limits)


def _joint_source(
    register_map: RegisterMap,
    joint: JointSpec,
    what: Literal["position", "velocity", "effort"],
    spec: JointValueSpec,
    check: _Checker,
    at: Loc,
) -> JointSource | None:
    if spec.register_name not in register_map:
        check.add((*at, what, "register"), f"no register named {spec.register_name!r}")
        return None
    if spec.factor == 0:
        check.add((*at, what, "factor"), "0 would make every value 0 (allowed: non-zero)")
        return None
    register = register_map[spec.register_name]
    if not register.access.readable or register.value_type in (ValueType.BOOL, ValueType.STRING):
        check.add(
            (*at, what, "register"),
            f"{spec.register_name} is not a readable number (access R or RW, a numeric type)",
        )
        return None
    wanted = SI_UNITS[(joint.kind, what)]
    unit = UNITS_TO_SI.get(register.unit)
    if unit is None or unit[0] != wanted:
        allowed = ", ".join(u for u, (si, _) in UNITS_TO_SI.items() if si == wanted)
        check.add(
            (*at, what, "register"),
            f"{spec.register_name}'s unit {register.unit!r} is not a {joint.kind} {what} "
            f"(REP 103 {wanted}; allowed units: {allowed})",
        )
        return None
    per_revolution = _per_revolution(register, spec.per_revolution, check, (*at, what))
    if per_revolution is None:
        return None
    return JointSource(spec.register_name, unit[1] * spec.factor / per_revolution)


def _per_revolution(
    register: Register, given: float | None, check: _Checker, at: Loc
) -> float | None:
    """A Hz register's cycles per revolution (default 1); only a Hz register has one."""
    if given is not None and register.unit != "Hz":
        check.add(
            (*at, "per_revolution"),
            f"{register.name}'s unit is {register.unit!r}: per_revolution is for a Hz register",
        )
        return None
    return 1.0 if given is None else given


def _build_joints(
    spec: DeviceFileSpec, register_map: RegisterMap, check: _Checker
) -> tuple[Joint, ...]:
    joints: list[Joint] = []
    names: set[str] = set()
    for index, joint in enumerate(spec.joints):
        at: Loc = ("joints", index)
        if joint.name in names:
            check.add((*at, "name"), f"joint {joint.name!r} given twice (names are unique)")
        names.add(joint.name)
        if joint.position is None and joint.velocity is None:
            check.add(at, f"joint {joint.name!r} needs a position or a velocity register")
            continue
        position = velocity = effort = None
        if joint.position is not None:
            position = _joint_source(register_map, joint, "position", joint.position, check, at)
        if joint.velocity is not None:
            velocity = _joint_source(register_map, joint, "velocity", joint.velocity, check, at)
        if joint.effort is not None:
            effort = _joint_source(register_map, joint, "effort", joint.effort, check, at)
        motion = None
        if joint.sim is not None:
            motion = _joint_motion(register_map, joint, joint.sim, check, (*at, "sim"))
        if not check.problems:
            joints.append(Joint(joint.name, position, velocity, effort, motion))
    return tuple(joints)


def _joint_motion(
    register_map: RegisterMap, joint: JointSpec, sim: JointSimSpec, check: _Checker, at: Loc
) -> JointMotion | None:
    if joint.position is None and sim.mode == "position":
        check.add((*at, "mode"), "a joint without a position register moves by velocity")
        return None
    register = _writable(register_map, sim.command, check, at, field="command")
    if register is None:
        return None
    wanted = SI_UNITS[(joint.kind, sim.mode)]
    unit = UNITS_TO_SI.get(register.unit)
    if unit is None or unit[0] != wanted:
        allowed = ", ".join(u for u, (si, _) in UNITS_TO_SI.items() if si == wanted)
        check.add(
            (*at, "command"),
            f"{sim.command}'s unit {register.unit!r} is not a {joint.kind} {sim.mode} "
            f"({wanted}; allowed units: {allowed})",
        )
        return None
    if sim.speed is not None and sim.mode == "velocity":
        check.add((*at, "speed"), "speed is for mode position (a velocity command sets it)")
        return None
    if sim.mode == "position" and (sim.time_constant_s is not None or sim.run_register):
        check.add(at, "time_constant_s and run_register are for mode velocity")
        return None
    per_revolution = _per_revolution(register, sim.per_revolution, check, at)
    if per_revolution is None:
        return None
    if (sim.run_register is None) != (sim.run_values is None):
        check.add(at, "give run_register and run_values together")
        return None
    if sim.run_register is not None and sim.run_register not in register_map:
        check.add((*at, "run_register"), f"no register named {sim.run_register!r}")
        return None
    return JointMotion(
        sim.command,
        unit[1] / per_revolution,
        sim.mode,
        sim.speed,
        sim.time_constant_s,
        sim.run_register,
        tuple(sim.run_values or ()),
    )


def _writable(
    register_map: RegisterMap,
    name: str,
    check: _Checker,
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
    values = ", ".join(_number_text(v) for v in allowed)
    return f"{name} takes one of {values}, not {_number_text(value)}"


def _check_commands(spec: DeviceFileSpec, register_map: RegisterMap, check: _Checker) -> None:
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
            where = (*at, "writes", k)
            if write.register_name not in register_map:
                check.add((*where, "register"), f"no register named {write.register_name!r}")
                continue
            register = register_map[write.register_name]
            if not register.access.writable:
                check.add(
                    (*where, "register"), f"{write.register_name} is read only (needs W or RW)"
                )
                continue
            value = write.value
            if isinstance(value, bool) != (register.value_type is ValueType.BOOL) or not (
                isinstance(value, int | float)
            ):
                allowed = "true or false" if register.value_type is ValueType.BOOL else "a number"
                check.add(
                    (*where, "value"), f"{value!r} for {write.register_name} (allowed: {allowed})"
                )
                continue
            try:
                encode(register, value)
            except CodecError as err:
                check.add((*where, "value"), str(err))
                continue
            choices = allowed_values(spec).get(write.register_name)
            if choices is not None and float(value) not in choices:
                check.add((*where, "value"), not_allowed(write.register_name, value, choices))
    for index, value_service in enumerate(commands.values):
        at = ("commands", "values", index)
        named(value_service.name, at)
        _writable(register_map, value_service.register_name, check, at)
    for index, coil in enumerate(commands.coils):
        at = ("commands", "coils", index)
        named(coil.name, at)
        _writable(register_map, coil.register_name, check, at, bool_only=True)
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
        target = _writable(register_map, topic.register_name, check, at)
        if topic.stop_value != 0:
            # The stream guard's stop is a 0 message (register value 0 x scale = 0): a
            # different stop value would make a 0 command and the deadman disagree.
            check.add(
                (*at, "stop_value"),
                f"{_number_text(topic.stop_value)}: a command topic stops at 0 (allowed: 0)",
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


def _build_device(
    spec: DeviceFileSpec, check: _Checker, *, on_line: bool, line_timeout_s: float | None = None
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
        check.add(("device", "unit_id"), "0 is the RTU broadcast: nobody answers (1-247)")
    register_map = _build_registers(spec, check)
    if register_map is None:
        return None
    joints = _build_joints(spec, register_map, check)
    _check_commands(spec, register_map, check)
    keepalive = _build_keepalive(spec, register_map, check)
    if spec.device.require_keepalive and spec.keepalive is None:
        check.add(("device", "require_keepalive"), "true, but the file has no keepalive")
    readable = [r.name for r in register_map if r.access.readable]
    state = spec.device.state
    if state is not None:
        for index, name in enumerate(state):
            if name not in register_map or not register_map[name].access.readable:
                check.add(("device", "state", index), f"{name!r} is not a readable register")
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
    )


def _build_keepalive(
    spec: DeviceFileSpec, register_map: RegisterMap, check: _Checker
) -> Keepalive | None:
    keepalive = spec.keepalive
    if keepalive is None:
        return None
    at: Loc = ("keepalive",)
    register = _writable(register_map, keepalive.register_name, check, at)
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
            to_raw(register, keepalive.value)
            encode(register, keepalive.value)
        except CodecError as err:
            check.add((*at, "value"), f"{_number_text(keepalive.value)} cannot be written: {err}")
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


def _address_texts(spec: DeviceFileSpec, check: _Checker) -> dict[str, str]:
    """The addresses the file wrote in another notation than decimal (``0x2100``)."""
    texts: dict[str, str] = {}
    for index, register in enumerate(spec.registers):
        node = node_at(check.root, (*check.prefix, "registers", index, "address"))
        if isinstance(node, yaml.ScalarNode) and str(node.value) != str(register.address):
            texts[register.name] = str(node.value)
    return texts


def load(path: str | Path) -> Description:
    """Read and validate a description file; raises ``DescriptionError`` (one line)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise DescriptionError(path, [Problem(0, "", f"cannot read: {err.strerror}")]) from None
    root, data = _compose(path, raw)
    bus = "devices" in data or "line" in data
    model: type[BaseModel] = BusFileSpec if bus else DeviceFileSpec
    try:
        # Validated as JSON data in strict mode: a number is a number and text is text
        # everywhere (``scale: "100"`` is refused as ``address: "100"`` is), and a list
        # may fill a fixed-length pair (``range``). YAML's .inf/.nan survive the trip.
        parsed = model.model_validate_json(json.dumps(data), strict=True)
    except ValidationError as err:
        raise DescriptionError(path, _problems(root, model, err)) from None
    problems: list[Problem] = []
    devices: list[Device] = []
    if isinstance(parsed, BusFileSpec):
        units: dict[int, int] = {}
        names: dict[str, int] = {}
        for index, device_spec in enumerate(parsed.devices):
            check = _Checker(root, ("devices", index))
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
        check = _Checker(root, ())
        device = _build_device(parsed, check, on_line=False)
        problems += check.problems
        if device is not None:
            devices.append(device)
        line = None
    if problems:
        raise DescriptionError(path, problems)
    return Description(path, tuple(devices), line)
