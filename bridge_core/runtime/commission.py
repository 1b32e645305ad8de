"""``bridge_commission``'s model: the hardware checks as data, their verdicts, the reply
times and the parameters they recommend (``commission_stats``, re-exported here), and the
report (Markdown, JSON, a params file).

Plain Python (no rclpy, no pymodbus). Each bridge declares its checks in
``<bridge>/commission.py`` as ``COMMISSIONING`` (a ``Commissioning``): one ``Check`` per
hardware check of its decisions page, read-only (``read``), guided (``guided``: it writes
or moves, and runs only after the operator typed ``yes``) or manual (prose only, for a
person with a pendant). The same rows render the page's "Hardware checks" list
(``runtime.commission_doc``) and drive the tool (``runtime.commission_run``; the command
line is ``bridge_core.ros.commission``), so the page and the tool cannot drift apart.
"""

from __future__ import annotations

import enum
import importlib
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ..wire.channel import RegisterIO
from ..wire.registers import Register, RegisterMap
from . import entries
from .commission_stats import (
    POLL_RATE_HEADROOM,
    REPLY_SAMPLES_DEFAULT,
    REPLY_SAMPLES_RANGE,
    TIMEOUT_FLOOR_S,
    TIMEOUT_OVER_MAX,
    TIMEOUT_STEP_S,
    ReplyTimes,
    carried_poll_rate_hz,
    percentile,
    recommend_poll_rate_hz,
    recommend_timeout_s,
    reply_times,
)
from .interface import NodeInterface
from .parameters import ParameterSpec, ParameterValue


class Verdict(enum.StrEnum):
    """What a check found about its decision."""

    CONFIRMED = "confirmed"  # the device does what the decision's reading says
    CONTRADICTED = "contradicted"  # it does the other thing: read what was seen
    UNCLEAR = "could not tell"  # it ran, and what it read settles nothing
    NOT_RUN = "not run"  # skipped, refused, a manual check, or the run was interrupted


class Kind(enum.StrEnum):
    READ = "read-only"  # reads only: run in the read-only phase
    GUIDED = "guided"  # writes or moves: one at a time, after the operator's `yes`
    MANUAL = "manual"  # a person runs it with the pendant and `ros2` (the page's prose)


@dataclass(frozen=True)
class Finding:
    """A check's result: the verdict, what was seen (one paragraph), and the parameters
    the bridge should run with because of it (name -> value, as in a params file)."""

    verdict: Verdict
    seen: str
    recommend: Mapping[str, ParameterValue] = field(default_factory=dict)


class Probe:
    """What a check is given: the device's channel, the parameters the tool was started
    with (the bridge's, parsed as the bridge parses them), the bridge's own device object
    (``device``, made by ``Commissioning.setup``), the facts the report lists, the rows the
    read-only phase scanned, and the operator (a line to say, a stop asked for)."""

    def __init__(
        self,
        io: RegisterIO,
        values: Mapping[str, Any],
        *,
        say: Callable[[str], None] = print,
        stop_requested: Callable[[], bool] = lambda: False,
    ) -> None:
        self.io = io
        self.values = values
        self.say = say
        # Whether the operator asked the running step to stop; ``wait(seconds)`` sleeps
        # unless a stop is asked for (True: asked). The guided phase sets both.
        self.stop_requested = stop_requested
        self.wait: Callable[[float], bool] = self._sleep
        self.device: Any = None
        self.facts: dict[str, str] = {}
        self.rows: RowScan | None = None

    def _sleep(self, seconds: float) -> bool:
        time.sleep(seconds)
        return self.stop_requested()


ReadFunction = Callable[[Probe], Finding]


@dataclass(frozen=True)
class Guided:
    """A check that writes or moves. ``moves``: what will move or be written, and how far;
    ``stop_how``: how to stop it besides the tool's stop key (the pendant); ``run`` does
    it, asking ``probe.stop_requested()`` often (it returns a Finding; a stop asked for is
    ``Verdict.UNCLEAR``, "stopped by the operator"); ``send_stop`` is sent by the runner
    on every way out of ``run`` (its end, an error, Ctrl-C, SIGTERM, stdin closed) and
    returns what it did and read back."""

    moves: str
    stop_how: str
    run: Callable[[Probe], Finding]
    send_stop: Callable[[Probe], str]


@dataclass(frozen=True)
class Check:
    """One hardware check: a row of the decisions page's list and, unless manual, a step
    of the tool. ``key``: stable id (the report's); ``title``: the bold lead of the item;
    ``decisions``: the numbers it settles; ``text``: the prose after the title (Markdown,
    one paragraph, wrapped when rendered)."""

    key: str
    title: str
    decisions: tuple[int, ...]
    text: str
    read: ReadFunction | None = field(default=None, compare=False)
    guided: Guided | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.read is not None and self.guided is not None:
            raise ValueError(f"check {self.key}: read-only or guided, not both")

    @property
    def kind(self) -> Kind:
        if self.read is not None:
            return Kind.READ
        return Kind.GUIDED if self.guided is not None else Kind.MANUAL


@dataclass(frozen=True)
class Described:
    """A bridge whose node and rows a file makes (modbus_bridge's ``device_file``): the
    parameters ``first`` are declared first; ``node(values)`` is the node their values
    make (its other parameters are declared next) and ``bind(commissioning, values)`` the
    commissioning of that file (its ``register_map`` and ``ping``). ``node`` may raise
    ``ConfigurationError`` (one line, exit 2)."""

    first: tuple[ParameterSpec, ...]
    node: Callable[[Mapping[str, Any]], NodeInterface]
    bind: Callable[[Commissioning, Mapping[str, Any]], Commissioning]


@dataclass(frozen=True)
class Commissioning:
    """A bridge's hardware checks and how the tool reaches its device.

    ``bridge``: the bridge's name (``r6``: ``docs/decisions/r6.md``); ``node``: the node
    whose parameters the tool takes (its ``NodeInterface.node``, also the params file's
    block ``/**/<node>``); ``register_map``: the rows the read-only phase reads;
    ``ping``: one short read, timed for the reply times; ``requests_per_poll``: the
    requests of one poll of the bridge (for the poll rate the line carries); ``setup``:
    builds ``probe.device`` and fills ``probe.facts`` (firmware, counts), reads only;
    ``refusal_reason``: why a row refused with an exception is expected (None:
    unexpected); ``described``: set when a parameter names the file that makes the node
    and its rows (then ``register_map`` and ``ping`` are placeholders)."""

    bridge: str
    node: str
    register_map: RegisterMap
    checks: tuple[Check, ...]
    ping: Callable[[RegisterIO], object]
    requests_per_poll: Callable[[Probe], int]
    setup: Callable[[Probe], None] = lambda _probe: None
    refusal_reason: Callable[[Register, Probe], str | None] = lambda _reg, _probe: None
    described: Described | None = None

    def __post_init__(self) -> None:
        keys = [check.key for check in self.checks]
        if len(set(keys)) != len(keys):
            raise ValueError(f"{self.bridge}: check keys repeat: {keys}")

    @property
    def params_block(self) -> str:
        return f"/**/{self.node}"


COMMISSION_MODULE = "commission"  # <package>.commission holds COMMISSIONING
COMMISSION_ATTRIBUTE = "COMMISSIONING"


def commissionings() -> dict[str, Commissioning]:
    """Every bridge that has a ``<package>/commission.py``, by bridge name."""
    found: dict[str, Commissioning] = {}
    for name, package in entries.bridge_packages().items():
        try:
            module = importlib.import_module(f"{package}.{COMMISSION_MODULE}")
        except ModuleNotFoundError as err:
            if err.name != f"{package}.{COMMISSION_MODULE}":
                raise
            continue
        found[name] = getattr(module, COMMISSION_ATTRIBUTE)
    return found


# ---------------------------------------------------------------- the row scan
@dataclass(frozen=True)
class Refusal:
    """A row of the map the device refused (or did not answer): why, and whether the
    bridge expects it (``expected``: the reason, e.g. "axis 7 past the axis count 6")."""

    name: str
    address: int
    table: str
    error: str
    expected: str | None


@dataclass
class RowScan:
    """Every readable row of the map, read alone: how many answered, what each answered,
    and the refusals."""

    answered: dict[str, list[int]] = field(default_factory=dict)
    refused: list[Refusal] = field(default_factory=list)

    def refused_names(self) -> set[str]:
        return {r.name for r in self.refused}

    @property
    def unexpected(self) -> list[Refusal]:
        return [r for r in self.refused if r.expected is None]


# ---------------------------------------------------------------- the report
@dataclass
class Result:
    check: Check
    finding: Finding


@dataclass
class Report:
    bridge: str
    node: str
    device: str  # where it was reached ("127.0.0.1:502 unit 1")
    facts: dict[str, str] = field(default_factory=dict)
    reply: ReplyTimes | None = None
    rows: RowScan | None = None
    results: list[Result] = field(default_factory=list)
    recommended: dict[str, ParameterValue] = field(default_factory=dict)
    link: dict[str, ParameterValue] = field(default_factory=dict)  # host, port, unit_id ...
    interrupted: str = ""  # why the run ended early ("Ctrl-C"), else empty

    def verdicts(self) -> dict[str, Verdict]:
        return {r.check.key: r.finding.verdict for r in self.results}

    def as_json(self) -> dict[str, Any]:
        return {
            "bridge": self.bridge,
            "node": self.node,
            "device": self.device,
            "facts": self.facts,
            "reply_times": None
            if self.reply is None
            else {
                "count": self.reply.count,
                "failures": self.reply.failures,
                "p50_ms": self.reply.p50_s * 1000,
                "p99_ms": self.reply.p99_s * 1000,
                "max_ms": self.reply.max_s * 1000,
            },
            "refused_rows": [vars(r) for r in (self.rows.refused if self.rows else [])],
            "checks": [
                {
                    "key": r.check.key,
                    "title": r.check.title,
                    "decisions": list(r.check.decisions),
                    "kind": r.check.kind.value,
                    "verdict": r.finding.verdict.value,
                    "seen": r.finding.seen,
                    "recommend": dict(r.finding.recommend),
                }
                for r in self.results
            ],
            "recommended_parameters": self.recommended,
            "interrupted": self.interrupted,
        }

    def json_text(self) -> str:
        return json.dumps(self.as_json(), indent=2, ensure_ascii=False) + "\n"

    def markdown(self) -> str:
        lines = [f"# Commissioning report: {self.bridge} ({self.device})", ""]
        if self.interrupted:
            lines += [f"**Interrupted: {self.interrupted}.** Checks after it: not run.", ""]
        lines += [f"- {key}: {value}" for key, value in self.facts.items()]
        if self.reply is not None:
            lines.append(f"- reply times: {self.reply.text}")
        if self.rows is not None:
            lines.append(
                f"- rows of the map read: {len(self.rows.answered)} answered, "
                f"{len(self.rows.refused)} refused ({len(self.rows.unexpected)} unexpected)"
            )
        lines += [
            "",
            "## Decisions",
            "",
            "| check | decisions | kind | verdict |",
            "|---|---|---|---|",
        ]
        lines += [
            f"| {r.check.title} | {', '.join(map(str, r.check.decisions))} | "
            f"{r.check.kind.value} | **{r.finding.verdict.value}** |"
            for r in self.results
        ]
        lines.append("")
        for r in self.results:
            lines += [
                f"### {r.check.title}",
                "",
                f"**{r.finding.verdict.value}**: {r.finding.seen}",
                "",
            ]
        if self.rows is not None and self.rows.refused:
            lines += ["## Rows refused", "", "| row | address | table | answer | expected |"]
            lines.append("|---|---|---|---|---|")
            lines += [
                f"| {r.name} | {r.address} | {r.table} | {r.error} | {r.expected or 'NO'} |"
                for r in self.rows.refused
            ]
            lines.append("")
        lines += [
            "## Recommended parameters",
            "",
            "```yaml",
            self.params_yaml().rstrip(),
            "```",
            "",
        ]
        return "\n".join(lines)

    def params_yaml(self) -> str:
        """A params file for the bridge: where the device is, as given, and the values
        recommended (pass it after the bridge's own: later files win)."""
        lines = [
            f"# Recommended by bridge_commission {self.bridge} (the report says why).",
            f"{self.params_block}:",
            "  ros__parameters:",
        ]
        for name, value in {**self.link, **self.recommended}.items():
            lines.append(f"    {name}: {yaml_value(value)}")
        return "\n".join(lines) + "\n"

    @property
    def params_block(self) -> str:
        return f"/**/{self.node}"


def yaml_value(value: ParameterValue) -> str:
    """A parameter value as a params file writes it (JSON is YAML)."""
    return json.dumps(value)


def finish_recommendations(report: Report) -> None:
    """Every check's recommendations, in check order (a later check wins a name)."""
    for result in report.results:
        report.recommended.update(result.finding.recommend)


__all__ = [
    "POLL_RATE_HEADROOM",
    "REPLY_SAMPLES_DEFAULT",
    "REPLY_SAMPLES_RANGE",
    "TIMEOUT_FLOOR_S",
    "TIMEOUT_OVER_MAX",
    "TIMEOUT_STEP_S",
    "Check",
    "Commissioning",
    "Described",
    "Finding",
    "Guided",
    "Kind",
    "Probe",
    "Refusal",
    "ReplyTimes",
    "Report",
    "Result",
    "RowScan",
    "Verdict",
    "carried_poll_rate_hz",
    "commissionings",
    "percentile",
    "recommend_poll_rate_hz",
    "recommend_timeout_s",
    "reply_times",
]
