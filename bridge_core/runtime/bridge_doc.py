"""``bridge_doc BRIDGE``: the ROS API reference of a bridge's page, rendered from its
``<bridge>/interface.py`` (the listing ``tests/test_interface.py`` checks against running
nodes), so the page says what the nodes declare.

The rendered section lives in ``docs/bridges/<bridge>.md`` between two marker lines
(``BEGIN``, ``END``); the prose around them is hand-written. ``bridge_doc --write``
rewrites the section, ``bridge_doc --check`` fails when a page differs from a fresh
render (tests/core/runtime/test_bridge_doc.py runs the same comparison). ROS-free: the
listing needs no rclpy.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from . import entries
from .interface import ENTRY_POINT_GROUP, NodeInterface, nodes
from .parameters import ParameterSpec, ParameterValue

BEGIN = "<!-- bridge_doc:begin -->"
END = "<!-- bridge_doc:end -->"
HEADING = "## ROS API (generated)"
PAGES = Path("docs") / "bridges"  # under the repository root
NOTE_ATTRIBUTE = "DOC_NOTE"  # a bridge's interface module may say what its nodes depend on
RANGE_DIGITS = 12  # significant digits of a range's ends
EXIT_DIFFERS = 1  # --check: a page is not what bridge_doc renders
EXIT_USAGE = 2  # a bad name, a page the tool cannot rewrite


# What rclpy adds to every node: in the ROS graph, not in a bridge's listing.
STANDARD_NOTE = (
    "Besides what each node lists below, rclpy gives every node `use_sim_time`, the "
    "parameter services (`~/get_parameters`, ...), `/rosout` and `/parameter_events`, and "
    "every lifecycle node `~/change_state`, `~/get_state` and `~/transition_event`."
)


class PageError(Exception):
    """A page the generated section cannot be put into (one line for the user)."""


@dataclass(frozen=True)
class Bridge:
    """One bridge package as the entry-point group names it (``r6`` -> ``r6_bridge``)."""

    name: str
    spec: str  # module:attr of its NODES

    @property
    def module(self) -> str:
        return self.spec.partition(":")[0]

    @property
    def package(self) -> str:
        return self.module.split(".")[0]

    @property
    def source(self) -> str:
        return self.module.replace(".", "/") + ".py"

    @property
    def page_name(self) -> str:
        """The page as messages name it: relative to the repository root."""
        return str(PAGES / f"{self.name}.md")

    def page(self, root: Path) -> Path:
        return root / self.page_name


def bridges() -> dict[str, Bridge]:
    """Every bridge by name, as pyproject.toml declares them (the checkout holding us)."""
    table = entries.entry_table(ENTRY_POINT_GROUP)
    return {name: Bridge(name, spec) for name, spec in table.items()}


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


def written(bridge: Bridge, root: Path) -> str:
    """The page's text with a fresh section (a new page if there is none)."""
    page = bridge.page(root)
    rendered = render(bridge)
    if not page.exists():
        return new_page(bridge, rendered)
    before, _, after = split_page(page.read_text(encoding="utf-8"), bridge.page_name)
    return before + rendered + after


def differs(bridge: Bridge, root: Path) -> str | None:
    """Why the page is not what bridge_doc renders (one line), or None."""
    page = bridge.page(root)
    fix = f"run `bridge_doc --write {bridge.name}`"
    if not page.exists():
        return f"{bridge.page_name}: missing; {fix}"
    try:
        current = region(page.read_text(encoding="utf-8"), bridge.page_name)
    except PageError as err:
        return str(err)
    if current != render(bridge):
        return f"{bridge.page_name}: differs from `bridge_doc {bridge.name}`; {fix}"
    return None


# ---------------------------------------------------------------- command line
def chosen(names: Sequence[str], known: Mapping[str, Bridge]) -> list[Bridge]:
    unknown = [name for name in names if name not in known]
    if unknown:
        raise PageError(f"unknown bridge {unknown[0]!r} (one of {', '.join(known)})")
    return [known[name] for name in names or known]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bridge_doc", description="a bridge's ROS API reference, from its interface.py"
    )
    parser.add_argument(
        "bridges", nargs="*", metavar="BRIDGE", help="r6, xarm, ... (--write, --check: default all)"
    )
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="rewrite docs/bridges/BRIDGE.md")
    mode.add_argument("--check", action="store_true", help="exit 1 if a page differs")
    parser.add_argument("--root", type=Path, default=entries.ROOT, help="repository root")
    args = parser.parse_args(argv)
    try:
        targets = chosen(args.bridges, bridges())
        if args.check:
            found = [line for b in targets if (line := differs(b, args.root)) is not None]
            for line in found:
                print(line)
            return EXIT_DIFFERS if found else 0
        if args.write:
            pages = {b.page(args.root): written(b, args.root) for b in targets}  # all or none
            for page, text in pages.items():
                page.parent.mkdir(parents=True, exist_ok=True)
                page.write_text(text, encoding="utf-8")
            return 0
        if len(args.bridges) != 1:
            raise PageError("name one bridge to print (or give --write or --check)")
        sys.stdout.write(render(targets[0]))
        return 0
    except (PageError, OSError) as err:  # one line for the user, not a traceback
        print(f"bridge_doc: {err}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
