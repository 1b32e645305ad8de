"""docs/architecture.md and docs/layout.md stay true to the tree.

Every module of the packages (``bridge_core`` and each bridge of ``bridge_packages()``) is
named on one of the two pages, and every module or path they name exists. A page names a
module by its path (``bridge_core/sim/serving.py``, ``r6_bridge/upload.py``), dotted
(``bridge_core.runtime.entries``, ``runtime.reads.read_plan``: the name after the module
must be one it defines), by a list item of its layer's section on architecture.md
(``- `serving`: ...`` under ``### `bridge_core/sim/```), or by ``name.py`` in its
package's block of layout.md's tree (``stepper_bridge/ ... jog.py``). A bare ``name.py``
elsewhere must be a module of some package. Paths under the repository's top-level
directories (``tests/...``, ``bench/...``) must exist too.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

from bridge_core.runtime.entries import bridge_packages

ROOT = Path(__file__).resolve().parents[2]
PAGES = ("docs/architecture.md", "docs/layout.md")
LAYERS = ("wire", "runtime", "ros", "sim")
TOP_DIRS = ("bench", "config", "docs", "launch", "msg_defs", "ros", "scripts", "tests")


def packages() -> tuple[str, ...]:
    return ("bridge_core", *bridge_packages().values())


@cache
def package_modules(root: Path = ROOT) -> frozenset[str]:
    """Every module of the packages, as a path: ``bridge_core/sim/serving.py``."""
    return frozenset(
        path.relative_to(root).as_posix()
        for top in packages()
        for path in (root / top).rglob("*.py")
        if path.name != "__init__.py"
    )


@cache
def _defined(path: Path) -> frozenset[str]:
    """The names a module defines at its top level (functions, classes, assignments, imports)."""
    names: set[str] = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Import | ast.ImportFrom):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return frozenset(names)


@dataclass
class Findings:
    named: set[str] = field(default_factory=set)  # module paths a page names
    stale: list[str] = field(default_factory=list)  # "page:line: what" that does not exist


_TOPS = "|".join(("bridge_core", r"[a-z0-9]+_bridge", *TOP_DIRS))
# A path under a top-level directory: r6_bridge/upload.py, tests/core/test_layers.py, docs/x
PATH = re.compile(rf"(?<![\w./-])((?:{_TOPS})/[\w./-]*\w)")
# bridge_core.runtime.entries, r6_bridge.device.R6Device (a dotted name from a package)
DOTTED = re.compile(r"(?<![\w./-])((?:bridge_core|[a-z0-9]+_bridge)(?:\.\w+)+)")
# `runtime.reads`, `sim.serving`, `ros/node_streams` (a module by its layer)
LAYERED = re.compile(rf"`((?:{'|'.join(LAYERS)})[./]\w+(?:\.\w+)*)")
# `name`: as a list item of a layer's section
ITEM = re.compile(r"`(\w+)`:")
BARE_PY = re.compile(r"(?<![\w./-])(\w+(?:_\*)?\.py)\b")
LAYER_HEADING = re.compile(r"^###\s+`bridge_core/(\w+)/`")
HEADING = re.compile(r"^(#{1,3})\s")
BLOCK_START = re.compile(rf"^((?:{_TOPS}))/\s")


def _resolve_dotted(parts: list[str], root: Path) -> tuple[str | None, str | None]:
    """The module path the longest prefix of ``parts`` names, and the name after it."""
    for end in range(len(parts), 0, -1):
        base = root.joinpath(*parts[:end])
        module = base.with_suffix(".py")
        if module.is_file():
            return module.relative_to(root).as_posix(), (parts[end] if end < len(parts) else None)
        if base.is_dir() and (base / "__init__.py").is_file():
            rest = parts[end] if end < len(parts) else None
            init = base / "__init__.py"
            if rest is None or rest in _defined(init):
                return None, None  # a package (or a name its __init__ defines): no module
            return f"{base.relative_to(root).as_posix()}/{rest}.py", None
    return "/".join(parts) + ".py", None


def _check_module(
    page: str, number: int, what: str, module: str, attr: str | None, root: Path, out: Findings
) -> None:
    path = root / module
    if not path.is_file():
        out.stale.append(f"{page}:{number}: {what}: no module {module}")
        return
    out.named.add(module)
    if attr is not None and attr not in _defined(path):
        out.stale.append(f"{page}:{number}: {what}: {module} defines no {attr}")


def _named_anywhere(page: str, number: int, line: str, root: Path, out: Findings) -> None:
    """Paths, dotted names and layer-relative names: the forms that mean the same anywhere."""
    for match in PATH.finditer(line):
        target = match.group(1)
        if target.endswith(".py") and target.split("/")[0] in packages():
            _check_module(page, number, target, target, None, root, out)
        elif not (root / target).exists():
            out.stale.append(f"{page}:{number}: {target}: no such file or directory")
    for match in DOTTED.finditer(line):
        module, attr = _resolve_dotted(match.group(1).split("."), root)
        if module is not None:
            _check_module(page, number, match.group(1), module, attr, root, out)
    for match in LAYERED.finditer(line):
        token = match.group(1)
        if re.fullmatch(r"\w+\.py", token):
            continue  # sim.py: a bridge's module, not the sim layer
        module, attr = _resolve_dotted(["bridge_core", *re.split(r"[./]", token)], root)
        if module is not None:
            _check_module(page, number, token, module, attr, root, out)


def _bare_names(
    page: str, number: int, line: str, block: str | None, root: Path, out: Findings
) -> None:
    """``name.py``: in a block of the tree, a file under that directory; else a module."""
    for match in BARE_PY.finditer(line):
        name = match.group(1)
        if block is None:
            if not any(Path(m).match(name) for m in package_modules(root)):
                out.stale.append(f"{page}:{number}: {name}: no module of that name")
            continue
        found = sorted((root / block).rglob(name))
        if not found:
            out.stale.append(f"{page}:{number}: {name}: nothing of that name in {block}/")
        out.named.update(p.relative_to(root).as_posix() for p in found if p.name != "__init__.py")


def findings(page: str, text: str, root: Path = ROOT) -> Findings:
    """What ``page`` (its text) names, and what it names that does not exist."""
    out = Findings()
    layer: str | None = None  # the bridge_core layer whose section this line is in
    block: str | None = None  # the top-level directory whose block of the tree this is in
    fenced = False
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            fenced, block = not fenced, None
            continue
        if not fenced and HEADING.match(line):
            heading = LAYER_HEADING.match(line)
            layer = heading.group(1) if heading and heading.group(1) in LAYERS else None
        if fenced:
            start = BLOCK_START.match(line)
            block = start.group(1) if start else (block if line.startswith(" ") else None)
        _named_anywhere(page, number, line, root, out)
        if layer is not None:
            for match in ITEM.finditer(line):
                module = f"bridge_core/{layer}/{match.group(1)}.py"
                _check_module(page, number, f"`{match.group(1)}`", module, None, root, out)
        if block is not None or not fenced:
            _bare_names(page, number, line, block, root, out)
    return out


def page_findings(pages: Iterable[str] = PAGES, root: Path = ROOT) -> Findings:
    total = Findings()
    for page in pages:
        one = findings(page, (root / page).read_text(encoding="utf-8"), root)
        total.named |= one.named
        total.stale += one.stale
    return total


def test_every_module_the_pages_name_exists() -> None:
    stale = page_findings().stale
    assert not stale, (
        "docs/architecture.md / docs/layout.md name what the tree does not have "
        "(a module moved or renamed: fix the page):\n" + "\n".join(stale)
    )


def test_every_module_is_named_on_a_page() -> None:
    missing = sorted(package_modules() - page_findings().named)
    assert not missing, (
        "modules named on neither docs/architecture.md (bridge_core: a line in its layer's "
        "section) nor docs/layout.md (a bridge: its package's block of the tree):\n"
        + "\n".join(missing)
    )


def test_a_stale_or_missing_name_is_found() -> None:
    text = (
        "### `bridge_core/sim/`: the simulators' base\n\n"
        "- `serving`: the server.\n- `gone_module`: moved away.\n\n"
        "## Elsewhere\n\nSee `runtime.reads.read_gone` and bridge_core/wire/nowhere.py.\n\n"
        "```text\nr6_bridge/      registers.py, lost.py\n```\n"
    )
    found = findings("page.md", text)
    assert "bridge_core/sim/serving.py" in found.named
    assert "r6_bridge/registers.py" in found.named
    assert "bridge_core/sim/logs.py" not in found.named
    assert sorted(s.split(": ", 1)[1] for s in found.stale) == [
        "`gone_module`: no module bridge_core/sim/gone_module.py",
        "bridge_core/wire/nowhere.py: no module bridge_core/wire/nowhere.py",
        "lost.py: nothing of that name in r6_bridge/",
        "runtime.reads.read_gone: bridge_core/runtime/reads.py defines no read_gone",
    ], found.stale
