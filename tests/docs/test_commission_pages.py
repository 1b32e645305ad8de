"""Each decisions page's "Hardware checks" list is its bridge's check rows, rendered.

The rows (``<bridge>/commission.py``) drive ``bridge_commission`` and render the list
between the page's markers; a page edited by hand, or rows changed without
``bridge_commission --write-docs``, fail here (as bridge_doc's generated sections do in
tests/core/ros/test_bridge_doc.py).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from bridge_core.runtime import commission_doc
from bridge_core.runtime.commission import Commissioning, commissionings

ROOT = Path(__file__).resolve().parents[2]
KNOWN = commissionings()


def test_the_r6_has_checks() -> None:
    """The scan finds the R6's rows (a scan that finds nothing proves nothing)."""
    assert "r6" in KNOWN and KNOWN["r6"].checks


@pytest.mark.parametrize("bridge", sorted(KNOWN))
def test_the_page_lists_the_data(bridge: str) -> None:
    assert commission_doc.differs(KNOWN[bridge], ROOT) is None


def test_a_changed_row_is_found(tmp_path: Path) -> None:
    """One word of one row changed: the page differs, and --write-docs puts it right."""
    r6 = KNOWN["r6"]
    first = r6.checks[0]
    changed = dataclasses.replace(first, text=first.text.replace("Expected", "Hoped"))
    edited: Commissioning = dataclasses.replace(r6, checks=(changed, *r6.checks[1:]))
    page = tmp_path / commission_doc.page_name(r6)
    page.parent.mkdir(parents=True)
    page.write_text((ROOT / commission_doc.page_name(r6)).read_text(encoding="utf-8"))
    reason = commission_doc.differs(edited, tmp_path)
    assert reason is not None and "--write-docs r6" in reason
    page.write_text(commission_doc.written(edited, tmp_path), encoding="utf-8")
    assert commission_doc.differs(edited, tmp_path) is None
    assert "Hoped" in page.read_text(encoding="utf-8")


def test_wrapping_keeps_code_spans_whole() -> None:
    text = "word " * 20 + "`ros2 topic echo /a/b --field c` and more words to wrap here"
    lines = commission_doc.wrap(text, "- ", "  ", width=40)
    assert any("`ros2 topic echo /a/b --field c`" in line for line in lines)
    assert all(len(line) <= 40 or "`" in line for line in lines)
