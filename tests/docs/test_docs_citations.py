"""Citations stay inside the repository: a clone must be able to follow every one.

No tracked file names a design note, a manual's or a note's path outside the repository
(manuals are cited by their label in docs/manuals.md; design background is in
docs/architecture.md), and every link of README.md and of a page under ``docs/`` to another
file of the repository, and to a heading of a page, resolves.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

# Built from parts so that this file does not name them itself.
OUTSIDE = tuple(
    re.compile(pattern)
    for pattern in (
        r"\bDESIGN" + r"\b",
        "seeds " + "README",
        "shared/" + "seeds",
        "shared/" + "notes",
        r"\.\./" + "shared",
    )
)

# Being rewritten on other branches; their citations are fixed after those merges.

LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$")
FENCE = re.compile(r"^(```|~~~)")


def tracked_files() -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True
    ).stdout
    return [name for name in out.decode().split("\0") if name]


def text_of(path: Path) -> str | None:
    """The file's text, or None for a binary file (or one gone from the worktree)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if b"\0" in data:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def outside_citations(name: str) -> list[str]:
    text = text_of(ROOT / name)
    if text is None:
        return []
    return [
        f"{name}:{number}: {line.strip()}"
        for number, line in enumerate(text.splitlines(), 1)
        if any(pattern.search(line) for pattern in OUTSIDE)
    ]


def test_no_citation_outside_the_repository() -> None:
    found = [hit for name in tracked_files() for hit in outside_citations(name)]
    assert not found, "cite docs/architecture.md or docs/manuals.md instead:\n" + "\n".join(found)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"`|\*\*|__", "", heading).strip().lower()
    kept = "".join(ch for ch in text if ch in " -_" or unicodedata.category(ch)[0] in "LN")
    return kept.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    found: set[str] = set()
    counts: dict[str, int] = {}
    fenced = False
    for line in page.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        match = None if fenced else HEADING.match(line)
        if match:
            base = slug(match.group(1))
            n = counts.get(base, 0)
            counts[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
    return found


def doc_pages() -> list[Path]:
    """README.md and every page under docs/ (bridges/, decisions/ included)."""
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]


def doc_links() -> list[tuple[Path, str]]:
    links = []
    for page in doc_pages():
        for target in LINK.findall(page.read_text(encoding="utf-8")):
            if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
                continue
            links.append((page, target))
    return links


def test_docs_links_resolve() -> None:
    broken = []
    for page, target in doc_links():
        path_part, _, anchor = target.partition("#")
        linked = (page.parent / path_part).resolve() if path_part else page
        if not linked.exists() or ROOT not in (linked, *linked.parents):
            broken.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
        elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
            broken.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
    assert not broken, "\n".join(broken)


ARCHITECTURE_CITATION = re.compile(r'docs/architecture\.md,\s*"([^"]+)"')


def test_architecture_citations_name_its_sections() -> None:
    """A tracked file that cites a section of docs/architecture.md by its quoted name names
    a heading of that page."""
    headings = anchors(DOCS / "architecture.md")
    wrong = []
    for name in tracked_files():
        text = text_of(ROOT / name)
        for section in ARCHITECTURE_CITATION.findall(text or ""):
            if slug(section) not in headings:
                wrong.append(f"{name}: {section}")
    assert not wrong, "no such section in docs/architecture.md:\n" + "\n".join(wrong)


def test_slug_follows_github() -> None:
    assert slug("Halts: every motion the bridge starts, the bridge stops") == (
        "halts-every-motion-the-bridge-starts-the-bridge-stops"
    )
    assert slug("`bridge_core/wire/`: Modbus on the wire") == "bridge_corewire-modbus-on-the-wire"
