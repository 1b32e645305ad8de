"""The "Hardware checks" list of ``docs/decisions/<bridge>.md``, rendered from the bridge's
``Commissioning.checks`` (``runtime.commission``): one bullet per check, its bold title
with the decisions it settles, its prose, and how ``bridge_commission`` runs it.

The list lives between two marker lines (``BEGIN``, ``END``) under the page's
``## Hardware checks`` heading; the paragraph above them is hand-written.
``bridge_commission --write-docs`` rewrites it, ``--check-docs`` (and
tests/docs/test_commission_pages.py) fails when the page differs from the data.
"""

from __future__ import annotations

import re
from pathlib import Path

from .commission import Check, Commissioning, Kind

BEGIN = "<!-- bridge_commission:begin -->"
END = "<!-- bridge_commission:end -->"
PAGES = Path("docs") / "decisions"  # under the repository root
WIDTH = 90  # the pages' line length
INDENT = "  "  # a bullet's continuation lines
# A word for wrapping: a code span whole (its spaces kept), or a run without spaces.
WORD = re.compile(r"(?:`[^`]*`|[^\s`])+")


class PageError(Exception):
    """A page whose list cannot be found or replaced (one line for the user)."""


def decisions_text(numbers: tuple[int, ...]) -> str:
    if len(numbers) == 1:
        return f"decision {numbers[0]}"
    return f"decisions {', '.join(map(str, numbers))}"


def how_run(check: Check, bridge: str) -> str:
    if check.kind is Kind.READ:
        return f"`bridge_commission {bridge}` reads this itself (read-only)."
    if check.guided is not None:
        return (
            f"`bridge_commission {bridge}` runs this as a guided step, after you type `yes`: "
            f"{check.guided.moves}."
        )
    return ""


def wrap(text: str, first: str, rest: str, width: int = WIDTH) -> list[str]:
    """``text`` in lines of at most ``width`` (a longer code span gets a line of its own),
    never broken inside a code span."""
    lines: list[str] = []
    line = first
    for word in WORD.findall(text):
        fresh = line in (first, rest) and not line.strip(" -")
        if not fresh and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = rest + word
        else:
            line = line + word if fresh else f"{line} {word}"
    lines.append(line)
    return lines


def item(check: Check, bridge: str) -> list[str]:
    lead = f"**{check.title} ({decisions_text(check.decisions)}).**"
    text = " ".join(part for part in (lead, check.text, how_run(check, bridge)) if part)
    return wrap(text, "- ", INDENT)


def render(commissioning: Commissioning) -> str:
    """The list between the markers, markers included, ending with a newline."""
    lines = [BEGIN]
    for check in commissioning.checks:
        lines += item(check, commissioning.bridge)
    lines.append(END)
    return "\n".join(lines) + "\n"


def page_name(commissioning: Commissioning) -> str:
    return str(PAGES / f"{commissioning.bridge}.md")


def split_page(text: str, name: str) -> tuple[str, str, str]:
    """(before, the list with its markers, after)."""
    start = text.find(BEGIN)
    stop = text.find(END)
    if start < 0 or stop < start or text.count(BEGIN) != 1 or text.count(END) != 1:
        raise PageError(f"{name}: needs one {BEGIN} line and one {END} line after it")
    stop += len(END)
    if text[stop : stop + 1] == "\n":
        stop += 1
    return text[:start], text[start:stop], text[stop:]


def differs(commissioning: Commissioning, root: Path) -> str | None:
    """Why the page's list is not the data's (one line), or None."""
    name = page_name(commissioning)
    fix = f"run `bridge_commission --write-docs {commissioning.bridge}`"
    path = root / name
    if not path.exists():
        return f"{name}: missing"
    try:
        _, current, _ = split_page(path.read_text(encoding="utf-8"), name)
    except PageError as err:
        return f"{err}; {fix}"
    if current != render(commissioning):
        return f"{name}: the hardware checks differ from {commissioning.bridge}'s data; {fix}"
    return None


def written(commissioning: Commissioning, root: Path) -> str:
    """The page with a fresh list."""
    name = page_name(commissioning)
    before, _, after = split_page((root / name).read_text(encoding="utf-8"), name)
    return before + render(commissioning) + after


__all__ = ["BEGIN", "END", "PageError", "differs", "render", "wrap", "written"]
