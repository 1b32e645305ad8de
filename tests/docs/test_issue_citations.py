"""The docs cite nothing a reader cannot follow: no "issue N".

The repository has no issue tracker, so an issue cited by its number leads nowhere. A page
states the fact itself, or cites what a clone holds: a decision by its number ("decision
17", docs/decisions/<bridge>.md), or a section by a link.
"""

from __future__ import annotations

import re
from pathlib import Path

from .test_docs_citations import ROOT, doc_pages

# "issue" or "issues", any case, then a number ("#" allowed), also split over a line.
ISSUE = re.compile(r"\bissues?\s+#?\d", re.IGNORECASE)
# Being rewritten by another change now; drop the entry when it lands.
PENDING = {"docs/architecture.md"}


def issue_citations(page: Path) -> list[str]:
    """``file:line: text`` of every "issue N" on ``page``."""
    text = page.read_text(encoding="utf-8")
    lines = text.splitlines()
    found = []
    for match in ISSUE.finditer(text):
        number = text.count("\n", 0, match.start()) + 1
        found.append(f"{page.relative_to(ROOT)}:{number}: {lines[number - 1].strip()}")
    return found


def test_docs_cite_no_issue_numbers() -> None:
    pages = [page for page in doc_pages() if str(page.relative_to(ROOT)) not in PENDING]
    found = [hit for page in pages for hit in issue_citations(page)]
    assert not found, (
        'no issue tracker: state the fact, or cite "decision N" or a docs section instead of:\n'
        + "\n".join(found)
    )
