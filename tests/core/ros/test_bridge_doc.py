"""docs/bridges/<bridge>.md, the reference pages ``bridge_doc`` renders from each bridge's
interface listing: the committed pages are what a fresh render gives, and
every parameter, topic, service and action a node declares is named on its page.

The coverage check reads the committed page's tables itself (not through the renderer),
as the UR ROS 2 driver's controller doc coverage test does: a spec added without
regenerating the page fails here by name.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import pytest

from bridge_core.ros import bridge_doc
from bridge_core.ros.bridge_doc import main
from bridge_core.runtime import interface, interface_doc
from bridge_core.runtime.interface import NodeInterface, Service, Topic
from bridge_core.runtime.interface_doc import BEGIN, END, HEADING
from bridge_core.runtime.parameters import ParameterSpec

ROOT = Path(__file__).resolve().parents[3]
BRIDGES = interface.bridges()  # the entry-point group's names: r6, xarm, ...
NODE_HEADING = re.compile(r"^### Node `(?P<name>[^`]+)`")
TABLE_HEADING = re.compile(r"^#### (?P<kind>\w+)")
UNESCAPED_BAR = re.compile(r"(?<!\\)\|")


def committed_region(bridge: str) -> str:
    """The text between the markers of the committed page."""
    lines = (ROOT / "docs" / "bridges" / f"{bridge}.md").read_text(encoding="utf-8").splitlines()
    begin, end = lines.index(BEGIN), lines.index(END)
    return "".join(line + "\n" for line in lines[begin + 1 : end])


def named(region: str) -> dict[str, dict[str, set[str]]]:
    """Per node heading, per table (Topics, Services, Actions, Parameters): the names in
    its rows' first column."""
    found: dict[str, dict[str, set[str]]] = {}
    node: dict[str, set[str]] = {}
    table: set[str] = set()
    for line in region.splitlines():
        if match := NODE_HEADING.match(line):
            node = found.setdefault(match["name"], {})
        elif match := TABLE_HEADING.match(line):
            table = node.setdefault(match["kind"], set())
        elif line.startswith("| `"):
            first = UNESCAPED_BAR.split(line)[1].strip()
            table.add(first.strip("`").replace("\\|", "|"))
    return found


def coverage_gaps(node: NodeInterface, region: str) -> list[str]:
    """What ``node`` declares that the page region does not name (patterns as declared)."""
    tables = named(region).get(node.node)
    if tables is None:
        return [f"node `{node.node}` (executable `{node.executable}`)"]
    declared = {
        "Topics": [t.name for t in node.declared_topics],
        "Services": [s.name for s in node.declared_services],
        "Actions": [a.name for a in node.declared_actions],
        "Parameters": [p.name for p in node.parameters],
    }
    return [
        f"{kind.lower().removesuffix('s')} `{name}` of node `{node.node}`"
        for kind, names in declared.items()
        for name in names
        if name not in tables.get(kind, set())
    ]


@pytest.mark.parametrize("bridge", list(BRIDGES))
def test_the_committed_page_is_a_fresh_render(bridge: str) -> None:
    assert committed_region(bridge) == interface_doc.render(BRIDGES[bridge]), (
        f"docs/bridges/{bridge}.md is stale: run `bridge_doc --write {bridge}`"
    )


@pytest.mark.parametrize("bridge", list(BRIDGES))
def test_the_page_keeps_its_title_and_heading(bridge: str) -> None:
    """The hand-written parts go around the markers: title first, the heading above them."""
    lines = (ROOT / "docs" / "bridges" / f"{bridge}.md").read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith(f"# {BRIDGES[bridge].package}") and lines[1] == "", lines[:2]
    assert HEADING in lines[: lines.index(BEGIN)]


def test_every_listed_node_is_named_on_its_page() -> None:
    pages = {b.package: name for name, b in BRIDGES.items()}
    regions = {name: committed_region(name) for name in BRIDGES}
    missing: dict[str, list[str]] = {}
    for node in interface.nodes():
        bridge = pages[node.package]
        missing.setdefault(bridge, []).extend(coverage_gaps(node, regions[bridge]))
    problems = [
        f"docs/bridges/{bridge}.md does not name {', '.join(gaps)}: "
        f"run `bridge_doc --write {bridge}`"
        for bridge, gaps in missing.items()
        if gaps
    ]
    assert not problems, "\n".join(problems)


def test_the_coverage_check_reports_an_undocumented_declaration() -> None:
    (xarm,) = interface.nodes([BRIDGES["xarm"].spec])
    region = committed_region("xarm")
    assert coverage_gaps(xarm, region) == []
    extra = replace(
        xarm,
        parameters=(*xarm.parameters, ParameterSpec("dummy_gain", 1.0, "not on the page")),
        declared_topics=(*xarm.declared_topics, Topic("~/dummy", "std_msgs/msg/Bool", True)),
        declared_services=(*xarm.declared_services, Service("~/dummy", "std_srvs/srv/Trigger")),
    )
    assert coverage_gaps(extra, region) == [
        "topic `~/dummy` of node `xarm_bridge`",
        "service `~/dummy` of node `xarm_bridge`",
        "parameter `dummy_gain` of node `xarm_bridge`",
    ]
    assert coverage_gaps(replace(xarm, node="xarm_other"), region) == [
        "node `xarm_other` (executable `xarm_bridge`)"
    ]


# ---------------------------------------------------------------- rendering
def test_patterns_stay_patterns_with_their_default_values() -> None:
    text = interface_doc.render(BRIDGES["stepper"])
    assert "| `~/motor_{motor}/jog` | `std_msgs/msg/Float64` | subscribed |" in text
    assert "- `{motor}`: `1`, `2`, `3`, `4`, `5`" in text
    assert "~/motor_1/jog" not in text


def test_a_run_time_description_is_documented_by_its_static_text() -> None:
    (_, drive) = interface.nodes([BRIDGES["motec"].spec])
    (lifeguard,) = [p for p in drive.parameters if p.name == "lifeguard_ms"]
    assert lifeguard.text_of is not None and lifeguard.description != lifeguard.static_text
    text = interface_doc.render(BRIDGES["motec"])
    assert interface_doc.cell(lifeguard.static_text) in text
    assert lifeguard.description not in text


def test_a_bar_in_a_cell_is_escaped() -> None:
    node = NodeInterface(
        "pkg",
        "exe",
        "node",
        "a node",
        (ParameterSpec("gain", 2, "a | b", 0, 10, live=True),),
        (Topic("~/t", "std_msgs/msg/Bool", False, "x|y"),),
    )
    rows = [line for line in interface_doc.node_lines(node) if line.startswith("| `")]
    assert rows == [
        "| `~/t` | `std_msgs/msg/Bool` | subscribed | x\\|y |",
        "| `gain` | integer | `2` | 0 .. 10 | live | a \\| b |",
    ]


def test_the_modbus_page_says_which_description_files_it_shows() -> None:
    text = interface_doc.render(BRIDGES["modbus"])
    assert "config/devices/xarm.yaml" in text and "config/devices/rtu_multidrop.yaml" in text


# ---------------------------------------------------------------- command line
def test_printing_one_bridge(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["xarm"]) == 0
    assert capsys.readouterr().out == interface_doc.render(BRIDGES["xarm"])


def test_an_unknown_bridge_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["ur5"]) == bridge_doc.EXIT_USAGE
    out, err = capsys.readouterr()
    assert out == "" and len(err.splitlines()) == 1 and "'ur5'" in err


def test_write_refuses_a_page_without_markers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    page = tmp_path / "docs" / "bridges" / "r6.md"
    page.parent.mkdir(parents=True)
    page.write_text("# r6_bridge\n\nprose only\n")
    assert main(["--write", "--root", str(tmp_path), "r6"]) == bridge_doc.EXIT_USAGE
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "docs/bridges/r6.md" in err and BEGIN in err
    assert page.read_text() == "# r6_bridge\n\nprose only\n"


def test_write_creates_then_check_finds_tampering(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = ["--root", str(tmp_path)]
    assert main(["--write", *root, "xarm"]) == 0
    page = tmp_path / "docs" / "bridges" / "xarm.md"
    assert page.read_text().startswith(f"# xarm_bridge\n\n{HEADING}\n\n{BEGIN}\n")
    assert main(["--check", *root, "xarm"]) == 0
    page.write_text(page.read_text().replace("joint positions", "joint angles"))
    assert main(["--check", *root, "xarm"]) == bridge_doc.EXIT_DIFFERS
    out = capsys.readouterr().out
    assert out.splitlines() == [
        "docs/bridges/xarm.md: differs from `bridge_doc xarm`; run `bridge_doc --write xarm`"
    ]


def test_write_keeps_the_prose_around_the_markers(tmp_path: Path) -> None:
    page = tmp_path / "docs" / "bridges" / "r6.md"
    page.parent.mkdir(parents=True)
    before = f"# r6_bridge\n\nIntro.\n\n{HEADING}\n\n{BEGIN}\n"
    page.write_text(f"{before}stale\n{END}\n\n## Hardware checks\n\nText.\n")
    assert main(["--write", "--root", str(tmp_path), "r6"]) == 0
    rendered = interface_doc.render(BRIDGES["r6"])
    assert page.read_text() == f"{before}{rendered}{END}\n\n## Hardware checks\n\nText.\n"


def test_check_of_all_pages_in_the_tree(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--check"]) == 0, capsys.readouterr().out
