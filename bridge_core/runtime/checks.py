"""Checks every command runs on its inputs before the first write.

One module, so every bridge refuses bad input the same way: a ``CommandRejected`` whose
text names the value, what it is and the range it must lie in (the service reply shows it
as is). ``bool`` is never taken for a number (``True`` is not motor 1), NaN and infinities
never pass a range, and a value that would overflow a conversion (``1e308`` rad to encoder
counts) is refused here, never an ``OverflowError`` with a traceback.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from typing import TypeVar

from ..wire.errors import CommandRejected
from ..wire.registers import ValueType

Choice = TypeVar("Choice")

# The longest command description or refusal text a reply or log line carries: an
# oversized request (300 KB of indexes) is named by its size, never echoed back. Long
# enough for every explanation the bridges give (the longest, a stepper pair refusal with
# its hardware check, is ~300 characters); the values of a request are bounded before
# that (``listed``, ``check_count``).
MESSAGE_MAX_CHARS = 1000
# The longest list a command description shows item by item; a longer one is named by
# its count ("set_digital_outputs (30000 outputs)").
LISTED_MAX_CHARS = 160
# What of an oversized text is kept: its leading words, up to the first value.
_LEADING_WORDS = re.compile(r"[A-Za-z_][A-Za-z_ ]*")
LEADING_WORDS_MAX_CHARS = 60


def bounded_text(text: str, limit: int = MESSAGE_MAX_CHARS) -> str:
    """``text``, or, when it is longer than ``limit``, only its leading words (what it is:
    "set_digital_outputs", "no register named") and its size: never the values in it,
    which can be a whole oversized request."""
    if len(text) <= limit:
        return text
    match = _LEADING_WORDS.match(text)
    leading = match.group(0)[:LEADING_WORDS_MAX_CHARS].strip() if match else ""
    return f"{leading or 'a text'} ({len(text)} characters, not shown)"


def listed(items: Iterable[object], noun: str, *, bracketed: bool = False) -> str:
    """A command description's list: its items (``[1, 2]`` with ``bracketed``, as a list
    prints), or only their count when they would make a long text (an oversized request
    is named by its size, never echoed)."""
    shown = [str(item) for item in items]
    text = ", ".join(shown)
    if len(text) > LISTED_MAX_CHARS:
        return f"({len(shown)} {noun})"
    if bracketed:
        return f"[{text}]"
    return text or "(none)"


def check_count(what: str, count: int, most: int) -> int:
    """At most ``most`` items of a list request; the refusal names the count, not the
    items ("30000 indexes, at most 16")."""
    if count > most:
        raise CommandRejected(f"{count} {what}, at most {most}")
    return count


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def check_finite(what: str, value: float) -> float:
    """A finite number (int or float, not bool); returns it as a float."""
    if not _is_number(value) or not math.isfinite(value):
        raise CommandRejected(f"{what} {value!r} is not a finite number")
    return float(value)


def check_range(what: str, value: float, low: float, high: float, unit: str = "") -> float:
    """A finite number within ``low..high`` (inclusive); returns it unchanged."""
    check_finite(what, value)
    if not low <= value <= high:
        suffix = f" {unit}" if unit else ""
        raise CommandRejected(f"{what} {value!r}{suffix} outside {low:g}..{high:g}{suffix}")
    return value


def check_whole_number(what: str, value: float, low: int, high: int) -> int:
    """A whole number within ``low..high`` (``3.0`` passes as 3, ``3.5`` does not)."""
    if (
        not _is_number(value)
        or not math.isfinite(value)
        or value != int(value)
        or not low <= value <= high
    ):
        raise CommandRejected(f"{what} {value!r} outside the whole numbers {low}..{high}")
    return int(value)


def check_raw(what: str, value: float, value_type: ValueType) -> int:
    """A whole number that fits ``value_type``'s raw range (e.g. i32 for a register)."""
    return check_whole_number(what, value, value_type.raw_min, value_type.raw_max)


def check_choice(what: str, value: Choice, allowed: Iterable[Choice]) -> Choice:
    """One of ``allowed``; the message lists them."""
    options = list(allowed)
    if isinstance(value, bool) and not all(isinstance(o, bool) for o in options):
        raise CommandRejected(f"{what} {value!r} refused: one of {options}")
    if value not in options:
        raise CommandRejected(f"{what} {value!r} refused: one of {options}")
    return value


def check_index(what: str, value: int, valid: range | Sequence[int]) -> int:
    """A channel, output, motor or board number among ``valid`` (a range is shown as a..b)."""
    if isinstance(value, bool) or not isinstance(value, int) or value not in valid:
        if isinstance(valid, range) and valid.step == 1 and len(valid):
            shown = f"{valid.start}-{valid.stop - 1}"
        else:
            shown = ", ".join(str(v) for v in valid)
        raise CommandRejected(f"{what} {value!r} outside {shown}")
    return value


def check_board(board: int, device: str, boards: int = 1) -> int:
    """Board number of a device with ``boards`` IO boards numbered from 0."""
    if isinstance(board, bool) or not isinstance(board, int) or not 0 <= board < boards:
        known = "board 0" if boards == 1 else f"boards 0-{boards - 1}"
        raise CommandRejected(
            f"board {board!r} refused: the {device} has {boards} board{'s' * (boards > 1)} "
            f"({known})"
        )
    return board


def board_zero_index(device: str, board: int, index: int) -> int:
    """``index`` of a request that names a board, on a device with one board (board 0)."""
    check_board(board, device)
    return index


def check_converted(what: str, value: float, low: float, high: float) -> float:
    """The result of a unit conversion (e.g. rad -> counts) before it is rounded.

    A huge input turns into ``inf`` or a number no register can hold; refuse it with the
    input's name instead of letting ``round()`` raise ``OverflowError``.
    """
    if not math.isfinite(value) or not low <= value <= high:
        raise CommandRejected(f"{what} is out of range ({value:g} outside {low:g}..{high:g})")
    return value


__all__ = [
    "MESSAGE_MAX_CHARS",
    "board_zero_index",
    "bounded_text",
    "check_board",
    "check_choice",
    "check_converted",
    "check_count",
    "check_finite",
    "check_index",
    "check_range",
    "check_raw",
    "check_whole_number",
    "listed",
]
