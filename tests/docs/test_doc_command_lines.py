"""Every line of README.md and docs/ that starts a bridge names things that exist.

The lines for a real device (an R6 at a LAN address, a stepper on a USB adapter) cannot
run here (loopback and ptys only), so each is checked without starting anything: its
console script is one of pyproject.toml's, every ``-p name:=value`` is a parameter that a
node of that executable declares (``bridge_core.runtime.interface``), with a value of the
parameter's type and in its range, and every ``--params-file`` under ``config/`` exists.
The lines against the demo run in tests/docs/test_readme_cli.py.
"""

from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path
from typing import cast

import pytest
import yaml  # type: ignore[import-untyped]

from bridge_core.runtime import interface
from bridge_core.runtime.commission import commissionings
from bridge_core.runtime.parameters import ParameterSpec, ParameterValue

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
BASH_BLOCK = re.compile(r"^\s*```(?:bash|sh)\n(.*?)^\s*```", re.DOTALL | re.MULTILINE)


# bridge_commission BRIDGE [options] --ros-args ...: the bridge's parameters, checked alike.
COMMISSION = "bridge_commission"


def console_scripts() -> set[str]:
    with (ROOT / "pyproject.toml").open("rb") as f:
        return set(tomllib.load(f)["project"]["scripts"])


def bridge_lines() -> list[tuple[str, list[str]]]:
    """``(where, words)`` of each line of a bash block that starts a node executable."""
    executables = {node.executable for node in interface.nodes()} | {COMMISSION}
    found = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for block in BASH_BLOCK.finditer(text):
            line_no = text.count("\n", 0, block.start(1)) + 1
            for offset, line in enumerate(block.group(1).splitlines()):
                words = shlex.split(line, comments=True)
                if words and words[0] in executables:
                    where = f"{page.relative_to(ROOT)}:{line_no + offset}"
                    found.append((where, words))
    return found


LINES = bridge_lines()


def spec_problem(spec: ParameterSpec, text: str) -> str | None:
    """Why ``text`` (as ``-p`` gives it: YAML) is not a value of ``spec``, or None."""
    value = yaml.safe_load(text)
    if spec.kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, spec.kind):
        return f"{value!r} is not a {spec.kind.__name__}"
    return spec.validate(cast(ParameterValue, value))


def test_the_pages_have_bridge_lines() -> None:
    """The scan finds the README's real-device lines (a scan that finds nothing proves
    nothing)."""
    readme = [words[0] for where, words in LINES if where.startswith("README.md")]
    assert {"r6_bridge", "stepper_bridge", "motec_bridge"} <= set(readme), readme
    assert any(words[0] == COMMISSION for _, words in LINES)  # docs/commissioning.md


@pytest.mark.parametrize(("where", "words"), LINES, ids=[where for where, _ in LINES])
def test_a_bridge_line_names_what_exists(where: str, words: list[str]) -> None:
    executable = words[0]
    assert executable in console_scripts(), f"{where}: no console script {executable}"
    chosen = [node for node in interface.nodes() if node.executable == executable]
    if executable == COMMISSION:  # the named bridge's node; the tool's options before
        known = commissionings()
        assert words[1] in known, f"{where}: {words[1]} has no hardware checks"
        chosen = [node for node in interface.nodes() if node.node == known[words[1]].node]
        assert "--ros-args" in words, f"{where}: the bridge's parameters need --ros-args"
        words = [executable, *words[words.index("--ros-args") :]]
    assert words[1] == "--ros-args", f"{where}: parameters need --ros-args first"
    specs: dict[str, ParameterSpec] = {}
    for node in chosen:
        specs.update({spec.name: spec for spec in node.parameters})
    problems = []
    args = iter(words[2:])
    for arg in args:
        if arg == "-p":
            name, sep, value = next(args).partition(":=")
            if not sep:
                problems.append(f"-p {name}: no ':='")
            elif name not in specs:
                problems.append(f"{name} is not a parameter of {executable}")
            elif (problem := spec_problem(specs[name], value)) is not None:
                problems.append(f"{name}: {problem}")
        elif arg == "--params-file":
            path = next(args)
            if path.startswith("config/") and not (ROOT / path).is_file():
                problems.append(f"no file {path}")
        else:
            problems.append(f"unexpected {arg!r}")
    assert not problems, f"{where}: {'; '.join(problems)}"
