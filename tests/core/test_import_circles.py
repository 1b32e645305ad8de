"""No new import circle among bridge_core and the bridges, read from the source.

Every import counts, ``if TYPE_CHECKING:`` ones too (a reader follows them as well) and
relative ones resolved. A circle (a strongly connected component of the module graph)
fails unless it lies inside an entry of ALLOWED, which says why it is tolerated. A job
module that needs its host types it with a small ``typing.Protocol`` instead of
importing the host (stepper_bridge.jog.JogDevice, bridge_core.sim.logs.LoggedSimulator,
stepper_bridge.node_services.StepperServicesOwner, motec_bridge.bus.BusDrive).
"""

from __future__ import annotations

import ast
from pathlib import Path

from bridge_core.runtime.entries import bridge_packages

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("bridge_core", *bridge_packages().values())

ALLOWED: dict[frozenset[str], str] = {
    frozenset({"bridge_core.wire.batches", "bridge_core.wire.channel"}): (
        "the channel runs batches and a batch types the channel it runs on (one job in two files)"
    ),
    frozenset(
        {
            "bridge_core.ros.node_base",
            "bridge_core.ros.node_actions",
            "bridge_core.ros.node_diagnostics",
            "bridge_core.ros.node_streams",
            "bridge_core.ros.node_services",
        }
    ): "the node base and its hosts: each host types the node it serves",
}


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_graph(root: Path, packages: tuple[str, ...]) -> dict[str, set[str]]:
    """Module -> the modules of ``packages`` it imports (every import statement)."""
    files = {module_name(p, root): p for top in packages for p in (root / top).rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in files}
    for name, path in files.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")
                    anchor = anchor[: len(anchor) - (node.level - 1)]
                    base = ".".join([*anchor, base] if base else anchor)
                # ``from pkg import module`` imports the module; else the names of ``base``.
                targets = [base, *(f"{base}.{alias.name}" for alias in node.names)]
            else:
                continue
            graph[name].update(t for t in targets if t in files and t != name)
    return graph


def circles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[frozenset[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = {stack.pop()}
            while node not in component:
                component.add(stack.pop())
            if len(component) > 1:
                found.append(frozenset(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def not_allowed(found: list[frozenset[str]]) -> list[str]:
    return [" <-> ".join(sorted(c)) for c in found if not any(c <= allowed for allowed in ALLOWED)]


def test_no_import_circle_outside_the_allowed_table() -> None:
    assert not_allowed(circles(import_graph(ROOT, PACKAGES))) == []


def test_a_new_circle_is_found_type_only_too(tmp_path: Path) -> None:
    files = {
        "pkg/__init__.py": "",
        "pkg/a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import B\n",
        "pkg/b.py": "from . import a\n",
        "pkg/c.py": "from pkg.a import X\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    found = circles(import_graph(tmp_path, ("pkg",)))
    assert found == [frozenset({"pkg.a", "pkg.b"})]
    assert not_allowed(found) == ["pkg.a <-> pkg.b"]
