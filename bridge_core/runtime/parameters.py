"""One spec per node parameter: type, default, range or choices, start-up-only or live.

Plain Python, importable without rclpy (the node base turns a spec into a
``ParameterDescriptor``; ``bridge_core.runtime.interface`` lists them without starting ROS). This
module also holds the specs every node shares (where the device is, the retry policy, the
poll rate ...). A start-up-only
parameter is declared ``read_only`` so ``ros2 param set`` is refused with a reason instead
of answering "successful" and changing nothing; a live one is validated here and applied
by the node's set-parameters callback. An integer given for a double parameter
(``-p poll_rate_hz:=20``) is taken as that double.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..wire.batches import MAX_IN_FLIGHT_RANGE
from ..wire.channel import UNIT_ID_MAX, UNIT_ID_MIN
from .diagnostics import DIAGNOSTIC_PERIOD_DEFAULT_S, DIAGNOSTIC_PERIOD_RANGE_S
from .rate_groups import SLOW_POLL_PERIOD_DEFAULT_S, SLOW_POLL_PERIOD_RANGE_S

ParameterValue = bool | int | float | str | list[bool] | list[int] | list[float] | list[str]


@dataclass(frozen=True)
class ParameterSpec:
    name: str
    default: ParameterValue
    description: str
    low: float | None = None  # numeric range (inclusive), checked by ROS and by validate()
    high: float | None = None
    choices: tuple[str, ...] = ()  # allowed strings (case-insensitive), e.g. parity
    live: bool = False  # may change at run time (applied by the node), else read-only
    item_positive: bool = False  # every item of a double array must be > 0 and finite
    # The description when it depends on run-time values (MOTEC ``lifeguard_ms``: the
    # floor of its bus): ``described(**facts)`` calls it with the node's facts.
    text_of: Callable[..., str] | None = field(default=None, compare=False, repr=False)
    # The description ``described`` replaced: the reference pages (bridge_doc) hold for
    # every bus, so they name this one.
    static_description: str = field(default="", compare=False, repr=False)
    kind: type = field(init=False)

    def __post_init__(self) -> None:
        kind: type
        if isinstance(self.default, bool):
            kind = bool
        elif isinstance(self.default, int):
            kind = int
        elif isinstance(self.default, float):
            kind = float
        elif isinstance(self.default, str):
            kind = str
        elif isinstance(self.default, list):
            kind = list
        else:
            raise TypeError(f"parameter {self.name}: unsupported default {self.default!r}")
        object.__setattr__(self, "kind", kind)
        if (self.low is None) != (self.high is None):
            raise ValueError(f"parameter {self.name}: give both ends of the range or neither")
        if self.low is not None and self.kind not in (int, float):
            raise ValueError(f"parameter {self.name}: a range needs a number")
        reason = self.validate(self.default)
        if reason is not None:
            raise ValueError(f"parameter {self.name}: default refused: {reason}")

    def described(self, **facts: Any) -> ParameterSpec:
        """This spec with its description for these run-time facts (if it names
        ``text_of``; else itself)."""
        if self.text_of is None:
            return self
        return dataclasses.replace(
            self, description=self.text_of(**facts), static_description=self.static_text
        )

    @property
    def static_text(self) -> str:
        """The description before any run-time facts (``described``) filled it in."""
        return self.static_description or self.description

    @property
    def type_name(self) -> str:
        """The ROS parameter type: bool, integer, double, string, or an array of one."""
        names = {bool: "bool", int: "integer", float: "double", str: "string"}
        if isinstance(self.default, list):
            item = type(self.default[0]) if self.default else str
            return f"{names[item]}[]"
        return names[self.kind]

    def coerce(self, value: ParameterValue) -> ParameterValue:
        """An integer for a double parameter becomes that double (and int lists likewise)."""
        if self.kind is float and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        default = self.default
        if (
            isinstance(default, list)
            and default
            and isinstance(default[0], float)
            and isinstance(value, list)
            and all(isinstance(item, int | float) and not isinstance(item, bool) for item in value)
        ):
            return [float(item) for item in value]
        return value

    def validate(self, value: ParameterValue) -> str | None:
        """None if ``value`` is acceptable, else the reason (one line)."""
        if (
            self.low is not None
            and self.high is not None
            and not _within(value, self.low, self.high)
        ):
            return f"{self.name} {value!r} outside {self.low:g}..{self.high:g}"
        if self.choices and (
            not isinstance(value, str) or value.upper() not in {c.upper() for c in self.choices}
        ):
            return f"{self.name} {value!r} is not one of {', '.join(self.choices)}"
        if self.item_positive and isinstance(value, list):
            for item in value:
                if (
                    not isinstance(item, int | float)
                    or isinstance(item, bool)
                    or not math.isfinite(item)
                    or item <= 0
                ):
                    return f"{self.name}: every value must be positive and finite, got {item!r}"
        return None

    def type_hint(self, given: object) -> str:
        """Why a value of the wrong type was given, where the reason is known: ROS reads a
        parameter value as YAML, so ``-p parity:=N`` (N, n, no, off ...) arrives as false."""
        if self.kind is str and isinstance(given, bool):
            example = self.choices[0] if self.choices else "text"
            return (
                f" (ROS read the value as the boolean {str(given).lower()}: quote it, "
                f"-p \"{self.name}:='{example}'\")"
            )
        return ""


def _within(value: object, low: float, high: float) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and low <= value <= high
    )


# ---------------------------------------------------------------- the shared specs
PARITIES = ("N", "E", "O")
UNIT_ID_RANGE = (UNIT_ID_MIN, UNIT_ID_MAX)
# RTU: unit 0 is the broadcast address, and no device answers a broadcast (a bridge that
# polls it never gets a reply). TCP devices often answer unit 0, so it stays allowed there.
RTU_UNIT_ID_RANGE = (UNIT_ID_MIN + 1, UNIT_ID_MAX)
# ``goal_timeout_s``: the time limit of a goal that gives ``timeout_s`` 0 (a goal whose
# client vanished must end by itself); a node with action servers declares it, live.
GOAL_TIMEOUT_DEFAULT_S = 600.0
GOAL_TIMEOUT_MAX_S = 86400.0


# The ranges of the common parameters, once: the bridges' nodes and modbus_bridge's
# description files take them from here.
BAUDRATE_RANGE = (300, 4_000_000)
TIMEOUT_MAX_S = 10.0
POLL_RATE_RANGE_HZ = (0.1, 1000.0)


@dataclass(frozen=True)
class DeviceDefaults:
    """A kind of device as its bridge knows it: its name and the defaults of its parameters.

    One value per bridge (e.g. ``R6_DEFAULTS``), so that the node, the bus owner and the
    docs agree on them; users override each default with a ROS parameter.
    """

    device_name: str
    transport: str  # "tcp" or "rtu"
    poll_rate_hz: float = 20.0
    host: str = "127.0.0.1"
    port: int = 502
    serial_port: str = "/dev/ttyUSB0"
    baudrate: int = 9600
    parity: str = "N"
    stopbits: int = 1
    unit_id: int = 1
    timeout_s: float = 0.5
    timeout_min_s: float = 0.01  # a reply timeout below this can never be met
    frame_gap_s: float = 0.0  # RTU: least silence between frames beyond t3.5
    # RTU: reply timeout of a stop sent while the device is marked down (None: timeout_s).
    # Short, so that a stop repeated over a dead line is not still waiting out a long
    # timeout when the line comes back (the goal: a stop within 0.3 s of the line's return;
    # bench/stop_after_outage.py measures it).
    stop_timeout_s: float | None = None
    # TCP: reads of one poll in flight before the first reply (1: one at a time).
    max_in_flight: int = 1
    # A PoseStamped topic the node publishes (R6, xArm: "~/tcp_pose"), stamped with
    # ``frame_id`` like ``~/state``: only ``frame_id``'s description names it.
    pose_topic: str = ""


# Off by default: recording costs CPU per frame (bench/wire_record.py).
RECORD_WIRE_SPEC = ParameterSpec(
    "record_wire",
    False,
    "publish every Modbus frame the link sends and receives on ~/wire "
    "(msg_defs/ModbusFrame); on a shared line the bus owner's ~/wire carries every unit's",
)


def transport_specs(defaults: DeviceDefaults) -> tuple[ParameterSpec, ...]:
    """Where the device is: the parameters of a node (or bus) that opens its own link."""
    specs: tuple[ParameterSpec, ...]
    if defaults.transport == "tcp":
        specs = (
            ParameterSpec("host", defaults.host, "device IP address or host name"),
            ParameterSpec("port", defaults.port, "Modbus TCP port", 1, 65535),
            ParameterSpec(
                "max_in_flight",
                defaults.max_in_flight,
                "reads of a poll sent before the first reply (pipelined Modbus TCP, matched "
                "by transaction id); 1 = one at a time. Falls back to 1 for good, with one "
                "WARN, if the device mishandles it",
                *MAX_IN_FLIGHT_RANGE,
            ),
        )
    else:
        specs = (
            ParameterSpec(
                "serial_port",
                defaults.serial_port,
                "serial device path or pyserial URL (e.g. socket://host:port)",
            ),
            ParameterSpec("baudrate", defaults.baudrate, "serial baud rate", *BAUDRATE_RANGE),
            ParameterSpec("parity", defaults.parity, "serial parity", choices=PARITIES),
            ParameterSpec("stopbits", defaults.stopbits, "serial stop bits", 1, 2),
            ParameterSpec(
                "frame_gap_s",
                defaults.frame_gap_s,
                "least silence between frames beyond the 3.5 characters of Modbus RTU",
                0.0,
                1.0,
            ),
        )
    return (
        *specs,
        ParameterSpec(
            "timeout_s",
            defaults.timeout_s,
            "reply timeout per transaction",
            defaults.timeout_min_s,
            TIMEOUT_MAX_S,
        ),
        RECORD_WIRE_SPEC,
    )


def channel_specs() -> tuple[ParameterSpec, ...]:
    """One device's retry and reconnect policy."""
    return (
        ParameterSpec(
            "retries", 1, "extra attempts for a failed read; writes are never retried", 0, 10
        ),
        ParameterSpec(
            "reconnect_max_s", 5.0, "cap of the exponential reconnect backoff", 0.1, 300.0
        ),
    )


AUTOSTART_SPEC = ParameterSpec(
    "autostart", True, "configure and activate at start (false: wait for lifecycle transitions)"
)
UNIT_IDS_SPEC = ParameterSpec("unit_ids", [1], "devices on the bus, one node each")
GOAL_TIMEOUT_SPEC = ParameterSpec(
    "goal_timeout_s",
    GOAL_TIMEOUT_DEFAULT_S,
    "time limit (s) of an action goal that gives timeout_s 0; 0 = none",
    0.0,
    GOAL_TIMEOUT_MAX_S,
    live=True,
)


def unit_id_spec(defaults: DeviceDefaults) -> ParameterSpec:
    """The device's unit id, for a node that opens its own link (RTU: no broadcast)."""
    rtu = defaults.transport == "rtu"
    return ParameterSpec(
        "unit_id",
        defaults.unit_id,
        "Modbus unit (slave) id" + (" (0 is the RTU broadcast: nobody answers)" if rtu else ""),
        *(RTU_UNIT_ID_RANGE if rtu else UNIT_ID_RANGE),
    )


def frame_id_text(defaults: DeviceDefaults) -> str:
    """``frame_id``'s description: the headers the node stamps with it (``BridgeNode.stamped``;
    ``joint_states`` gets a stamp only)."""
    if defaults.pose_topic:
        return f"header frame_id of {defaults.pose_topic} and ~/state (joint_states: none)"
    return "header frame_id of ~/state (joint_states: none)"


def node_specs(defaults: DeviceDefaults) -> tuple[ParameterSpec, ...]:
    """The parameters of every bridge node (besides where its device is)."""
    return (
        *channel_specs(),
        ParameterSpec(
            "poll_rate_hz",
            defaults.poll_rate_hz,
            "full-state polls per second",
            *POLL_RATE_RANGE_HZ,
            live=True,
        ),
        ParameterSpec(
            "slow_poll_period_s",
            SLOW_POLL_PERIOD_DEFAULT_S,
            "seconds between reads of the slow group (registers that do not move by "
            "themselves: configuration, identity); every poll reads the fast group",
            *SLOW_POLL_PERIOD_RANGE_S,
            live=True,
        ),
        ParameterSpec(
            "diagnostic_period_s",
            DIAGNOSTIC_PERIOD_DEFAULT_S,
            "seconds between this node's /diagnostics statuses",
            *DIAGNOSTIC_PERIOD_RANGE_S,
            live=True,
        ),
        ParameterSpec("joint_prefix", "", "prefix of every joint name"),
        ParameterSpec("frame_id", "base_link", frame_id_text(defaults)),
        ParameterSpec(
            "read_only", False, "refuse every command that writes to the device", live=True
        ),
        AUTOSTART_SPEC,
    )


def bridge_specs(defaults: DeviceDefaults, *, owns_link: bool) -> tuple[ParameterSpec, ...]:
    """What a bridge node declares (``BridgeNode``): where its device is, unless it is on a
    bus another node owns (``owns_link`` false), then ``node_specs``."""
    where = (*transport_specs(defaults), unit_id_spec(defaults)) if owns_link else ()
    return (*where, *node_specs(defaults))


def bus_specs(defaults: DeviceDefaults, *, unit_ids: bool = True) -> tuple[ParameterSpec, ...]:
    """What a bus owner declares (``BusNode``): the line, and ``unit_ids`` unless something
    else names the devices (a ``modbus_bridge`` description file)."""
    return (*transport_specs(defaults), *((UNIT_IDS_SPEC,) if unit_ids else ()), AUTOSTART_SPEC)


def padded(values: Sequence[float], count: int, default: float) -> list[float]:
    """A per-joint list parameter cut or padded with ``default`` to ``count`` items."""
    out = [float(v) for v in values][:count]
    return out + [default] * (count - len(out))


__all__ = [
    "AUTOSTART_SPEC",
    "GOAL_TIMEOUT_SPEC",
    "PARITIES",
    "RECORD_WIRE_SPEC",
    "RTU_UNIT_ID_RANGE",
    "UNIT_ID_RANGE",
    "DeviceDefaults",
    "ParameterSpec",
    "ParameterValue",
    "bridge_specs",
    "bus_specs",
    "channel_specs",
    "node_specs",
    "padded",
    "transport_specs",
    "unit_id_spec",
]
