"""A bridge's ROS API reference as Markdown, rendered from its ``<bridge>/interface.py``
(the listing ``tests/core/ros/test_interface.py`` checks against running nodes), so its page says
what the nodes declare. Plain text in, text out: ``bridge_core.ros.bridge_doc`` (the
``bridge_doc`` tool) reads and writes the pages, ``modbus_doc`` uses ``table``.

The rendered section lives in ``docs/bridges/<bridge>.md`` between two marker lines
(``BEGIN``, ``END``); the prose around them is hand-written.
"""

from __future__ import annotations

import importlib
import json
from collections.abc import Mapping, Sequence

from .interface import Bridge, NodeInterface, nodes
from .parameters import ParameterSpec, ParameterValue

BEGIN = "<!-- bridge_doc:begin -->"
END = "<!-- bridge_doc:end -->"
HEADING = "## ROS API (generated)"
NOTE_ATTRIBUTE = "DOC_NOTE"  # a bridge's interface module may say what its nodes depend on
RANGE_DIGITS = 12  # significant digits of a range's ends


# What rclpy adds to every node: in the ROS graph, not in a bridge's listing.
STANDARD_NOTE = (
    "Besides what each node lists below, rclpy gives every node `use_sim_time`, the "
    "parameter services (`~/get_parameters`, ...), `/rosout` and `/parameter_events`, and "
    "every lifecycle node `~/change_state`, `~/get_state` and `~/transition_event`."
)


class PageError(Exception):
    """A page the generated section cannot be put into (one line for the user)."""


# ---------------------------------------------------------------- rendering
def cell(text: str) -> str:
    """Table cell text: a ``|`` would end the cell, a line break the row."""
    return " ".join(text.split()).replace("|", "\\|")


def code(text: str) -> str:
    return f"`{cell(text)}`"


def value_text(value: ParameterValue | float) -> str:
    """A parameter value as a YAML parameter file would give it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(value_text(item) for item in value) + "]"
    return repr(value)


def number_text(value: float) -> str:
    """A range's end, short: ``1e+06`` rather than ``1000000.0`` (the type column says
    integer or double)."""
    return f"{value:.{RANGE_DIGITS}g}"


def bounds_text(spec: ParameterSpec) -> str:
    """Range, choices, and the per-item rule of one parameter."""
    parts = []
    if spec.low is not None and spec.high is not None:
        parts.append(f"{number_text(spec.low)} .. {number_text(spec.high)}")
    if spec.choices:
        parts.append(", ".join(code(choice) for choice in spec.choices))
    if spec.item_positive:
        parts.append("each item > 0")
    return "; ".join(parts)


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A Markdown table's lines (also ``modbus_doc``'s)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def placeholder_lines(expansion: Mapping[str, Sequence[object]]) -> list[str]:
    """What each ``{placeholder}`` of the node's names takes by default."""
    if not expansion:
        return []
    lines = ["Placeholders in names take, in the default configuration:", ""]
    for key, values in expansion.items():
        taken = ", ".join(code(str(v)) for v in values) or "none (the pattern names nothing)"
        lines.append(f"- `{{{key}}}`: {taken}")
    return [*lines, ""]


def section(title: str, header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    return [f"#### {title}", "", *table(header, rows), ""] if rows else []


def node_lines(node: NodeInterface) -> list[str]:
    kind = "lifecycle node" if node.lifecycle else "plain node (not managed)"
    lines = [
        f"### Node {code(node.node)}",
        "",
        f"Executable {code(node.executable)}, {kind}: {node.text}.",
        "",
        *placeholder_lines(node.expansion),
    ]
    topics = [
        [code(t.name), code(t.type), "published" if t.published else "subscribed", cell(t.text)]
        for t in node.declared_topics
    ]
    lines += section("Topics", ("name", "type", "direction", "description"), topics)
    services = [[code(s.name), code(s.type), cell(s.text)] for s in node.declared_services]
    lines += section("Services", ("name", "type", "description"), services)
    actions = [[code(a.name), code(a.type), cell(a.text)] for a in node.declared_actions]
    lines += section("Actions", ("name", "type", "description"), actions)
    parameters = [
        [
            code(p.name),
            p.type_name,
            code(value_text(p.default)),
            bounds_text(p),
            "live" if p.live else "start-up only",
            cell(p.static_text),
        ]
        for p in node.parameters
    ]
    header = ("name", "type", "default", "range / choices", "changes", "description")
    return lines + section("Parameters", header, parameters)


def render(bridge: Bridge) -> str:
    """The generated section of ``bridge``'s page (the text between the markers)."""
    note = getattr(importlib.import_module(bridge.module), NOTE_ATTRIBUTE, "")
    lines = [
        f"Generated by `bridge_doc {bridge.name}` from `{bridge.source}`; do not edit by hand.",
        "",
        STANDARD_NOTE,
        "",
        *([note, ""] if note else []),
    ]
    for node in nodes([bridge.spec]):
        lines += node_lines(node)
    while lines and not lines[-1]:
        lines.pop()
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- pages
def split_page(text: str, where: str) -> tuple[str, str, str]:
    """The page before its BEGIN line (inclusive), the region, and from END on."""
    lines = text.splitlines(keepends=True)
    marks = [i for i, line in enumerate(lines) if line.strip() in (BEGIN, END)]
    if [lines[i].strip() for i in marks] != [BEGIN, END]:
        raise PageError(
            f"{where}: no generated section: put a line {BEGIN} and, below it, a line {END} "
            f"under {HEADING!r}"
        )
    begin, end = marks
    return "".join(lines[: begin + 1]), "".join(lines[begin + 1 : end]), "".join(lines[end:])


def region(text: str, where: str = "page") -> str:
    """The generated region of a page's text."""
    return split_page(text, where)[1]


def new_page(bridge: Bridge, rendered: str) -> str:
    return f"# {bridge.package}\n\n{HEADING}\n\n{BEGIN}\n{rendered}{END}\n"
