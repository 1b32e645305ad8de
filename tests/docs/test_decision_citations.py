"""Every decision a tracked file cites exists.

Code, tests, config and docs cite the readings taken where a manual is unclear by bridge
and number: "R6 decision 21", "stepper decisions 11, 19", "xArm decisions 1-4 and 8",
"MOTEC decisions 7 and 12-15", "modbus_bridge decision 18". Each bridge's readings are a
numbered Markdown list in docs/decisions/<bridge>.md ("21. **M and EU boards** ...", a
number at the start of a line), before the page's "## Hardware checks". A number is never
reused, so a citation stays right as long as the reading it names is on the page.
"""

from __future__ import annotations

import re
from pathlib import Path

from .test_docs_citations import ROOT, text_of, tracked_files

DECISIONS = ROOT / "docs" / "decisions"
# How a citation names the bridge (any case) -> its page in docs/decisions/.
PAGES = {
    "r6": "r6",
    "xarm": "xarm",
    "stepper": "stepper",
    "motec": "motec",
    "modbus_bridge": "modbus",
}
# Words may be split over lines, also of a comment ("# " at the start of the next one).
GAP = r"[\s#]"
NUMBERS = rf"\d+(?:{GAP}*(?:[-\u2013]|,{GAP}*(?:and{GAP}+)?|{GAP}+and{GAP}+){GAP}*\d+)*"
CITATION = re.compile(rf"\b({'|'.join(PAGES)}){GAP}+decisions?{GAP}+({NUMBERS})", re.IGNORECASE)
NUMBERED = re.compile(r"^(\d+)\.\s", re.MULTILINE)
HARDWARE_CHECKS = "\n## Hardware checks"


def numbers_of(page: Path) -> list[int]:
    """The decision numbers of a page, in order: its ordered list before the hardware
    checks (a fenced block or a bullet never starts a line with "N. ")."""
    text = page.read_text(encoding="utf-8").split(HARDWARE_CHECKS, 1)[0]
    return [int(number) for number in NUMBERED.findall(text)]


def cited(numbers: str) -> list[int]:
    """ "11, 19" -> [11, 19]; "1-4 and 8" -> [1, 2, 3, 4, 8]; a range with an en dash too."""
    found: list[int] = []
    flat = " ".join(numbers.replace("#", " ").split())
    for part in re.split(r" ?(?:, ?(?:and )?| and ) ?", flat):
        low, _, high = re.sub(r" ?[-\u2013] ?", "-", part).partition("-")
        found += range(int(low), int(high or low) + 1)
    return found


def citations(text: str) -> list[tuple[int, str, list[int]]]:
    """(line, bridge page, numbers) of every decision citation in ``text``."""
    return [
        (
            text.count("\n", 0, match.start()) + 1,
            PAGES[match.group(1).lower()],
            cited(match.group(2)),
        )
        for match in CITATION.finditer(text)
    ]


def test_every_bridge_has_a_decisions_page_numbered_once_in_order() -> None:
    for page in sorted(set(PAGES.values())):
        numbers = numbers_of(DECISIONS / f"{page}.md")
        assert numbers == list(range(1, len(numbers) + 1)), (page, numbers)
        assert len(numbers) >= 10, (page, numbers)


def test_every_cited_decision_exists() -> None:
    known = {page: set(numbers_of(DECISIONS / f"{page}.md")) for page in set(PAGES.values())}
    missing = []
    count = 0
    for name in tracked_files():
        for line, page, numbers in citations(text_of(ROOT / name) or ""):
            count += 1
            missing += [
                f"{name}:{line}: decision {n} is not in docs/decisions/{page}.md"
                for n in numbers
                if n not in known[page]
            ]
    assert count >= 100, f"only {count} citations found: is the pattern still right?"
    assert not missing, "\n".join(missing)


def test_the_citation_forms() -> None:
    text = (
        "(R6 decision 21) README R6 decisions 3, 19, 21; Stepper decisions 2-4 and\n"
        "xArm decisions 1\u20134 and 8, MOTEC decisions 7 and 12-15; the stepper decision\n"
        "18; modbus_bridge decision 17, R6 decision 28, xArm decision 18 (MOTEC\n"
        "# decision 20); stepper decisions 11,\n# 19"
    )
    assert citations(text) == [
        (1, "r6", [21]),
        (1, "r6", [3, 19, 21]),
        (1, "stepper", [2, 3, 4]),
        (2, "xarm", [1, 2, 3, 4, 8]),
        (2, "motec", [7, 12, 13, 14, 15]),
        (2, "stepper", [18]),
        (3, "modbus", [17]),
        (3, "r6", [28]),
        (3, "xarm", [18]),
        (3, "motec", [20]),
        (4, "stepper", [11, 19]),
    ]


def test_a_citation_of_a_missing_number_is_found() -> None:
    last = max(numbers_of(DECISIONS / "r6.md"))
    ((_, page, numbers),) = citations(f"see R6 decision {last + 1}.")
    assert page == "r6" and numbers == [last + 1]
    assert last + 1 not in numbers_of(DECISIONS / "r6.md")
