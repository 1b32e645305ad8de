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

# "issue" or "issues", any case, then a number ("#" allowed), also split over a line or
# in a name (a test named after one, with "_"); not in an address ("/issues/1386").
ISSUE = re.compile(r"(?<![a-z])issues?(?:\s+|_)#?\d", re.IGNORECASE)
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


def test_the_pattern_finds_a_citation_in_prose_and_in_names() -> None:
    word = "issue"  # the examples are built, or this file would cite them
    cited = (f"see {word} 12", f"{word.title()}s #3 and 4", f"an {word}\n  7", f"test_{word}_10_x")
    for text in cited:
        assert ISSUE.search(text), text
    for fine in ("issues/1386", "an issue with 3 parts", "tissue 5", "reissue_4"):
        assert not ISSUE.search(fine), fine
