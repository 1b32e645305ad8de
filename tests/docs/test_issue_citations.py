"""Nothing in the repository cites what a reader cannot follow: no "issue N".

The repository has no issue tracker, so an issue cited by its number leads nowhere. Code,
tests, benchmarks, scripts, configuration and docs state the fact itself, or cite what a
clone holds: a decision by its number ("decision 17", docs/decisions/<bridge>.md), or a
section by a link. (Another project's tracker is cited by its address.)
"""

from __future__ import annotations

import re
from pathlib import Path

from .test_docs_citations import ROOT, text_of, tracked_files

# "issue" or "issues", any case, then a number ("#" allowed), also split over a line.
ISSUE = re.compile(r"\bissues?\s+#?\d", re.IGNORECASE)
# Text a reader reads: every tracked file of these kinds, wherever it is.
SUFFIXES = {
    ".py",
    ".md",
    ".yaml",
    ".yml",
    ".toml",
    ".sh",
    ".txt",
    ".cfg",
    ".xml",
    ".msg",
    ".srv",
    ".action",
}


def issue_citations(name: str) -> list[str]:
    """``file:line: text`` of every "issue N" in the tracked file ``name``."""
    text = text_of(ROOT / name)
    if text is None:
        return []
    lines = text.splitlines()
    found = []
    for match in ISSUE.finditer(text):
        number = text.count("\n", 0, match.start()) + 1
        found.append(f"{name}:{number}: {lines[number - 1].strip()}")
    return found


def test_nothing_cites_an_issue_number() -> None:
    names = [n for n in tracked_files() if Path(n).suffix in SUFFIXES]
    found = [hit for name in names for hit in issue_citations(name)]
    assert not found, (
        'no issue tracker: state the fact, or cite "decision N" or a docs section instead of:\n'
        + "\n".join(found)
    )
