"""One way to refuse bad input: known vectors for every check."""

from __future__ import annotations

import pytest

from bridge_core.runtime.checks import (
    MESSAGE_MAX_CHARS,
    board_zero_index,
    bounded_text,
    check_choice,
    check_converted,
    check_count,
    check_finite,
    check_index,
    check_range,
    check_raw,
    check_whole_number,
    listed,
)
from bridge_core.wire.errors import CommandRejected
from bridge_core.wire.registers import ValueType


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf"), True, "1", None])
def test_finite_refuses(value: object) -> None:
    with pytest.raises(CommandRejected, match="is not a finite number"):
        check_finite("speed", value)  # type: ignore[arg-type]


def test_range_names_value_and_bounds() -> None:
    assert check_range("speed", 3000, -3000, 3000, "rpm") == 3000
    with pytest.raises(CommandRejected, match=r"speed 3001 rpm outside -3000\.\.3000 rpm"):
        check_range("speed", 3001, -3000, 3000, "rpm")
    with pytest.raises(CommandRejected):
        check_range("speed", float("nan"), -1, 1)


@pytest.mark.parametrize(
    ("value", "ok"),
    [
        (3, True),
        (3.0, True),
        (3.5, False),
        (True, False),
        (-1, False),
        (65536, False),
        (1e308, False),
    ],
)
def test_whole_number(value: float, ok: bool) -> None:
    if ok:
        assert check_whole_number("microstep", value, 0, 0xFFFF) == 3
    else:
        with pytest.raises(CommandRejected, match=r"outside the whole numbers 0\.\.65535"):
            check_whole_number("microstep", value, 0, 0xFFFF)


def test_raw_limits_come_from_the_value_type() -> None:
    assert check_raw("value", -(2**31), ValueType.I32) == -(2**31)
    with pytest.raises(CommandRejected, match="2147483647"):
        check_raw("value", 2**31, ValueType.I32)
    with pytest.raises(CommandRejected, match=r"0\.\.65535"):
        check_raw("value", -1, ValueType.U16)


def test_choice_and_index() -> None:
    assert check_choice("mode", 1, (1, 2)) == 1
    with pytest.raises(CommandRejected, match=r"mode True refused: one of \[1, 2\]"):
        check_choice("mode", True, (1, 2))
    assert check_index("output", 12, range(1, 13)) == 12
    with pytest.raises(CommandRejected, match="output 13 outside 1-12"):
        check_index("output", 13, range(1, 13))
    with pytest.raises(CommandRejected, match="motor True outside 1-5"):
        check_index("motor", True, range(1, 6))


def test_board_zero() -> None:
    assert board_zero_index("drive", 0, 2) == 2
    with pytest.raises(
        CommandRejected, match=r"board 1 refused: the drive has 1 board \(board 0\)"
    ):
        board_zero_index("drive", 1, 2)


def test_converted_overflow_is_a_refusal() -> None:
    counts = 1e308 / 6.283 * 10000.0  # ~move 1e308 rad: inf
    with pytest.raises(CommandRejected, match="position 1e308 rad in counts is out of range"):
        check_converted("position 1e308 rad in counts", counts, -(2**31), 2**31 - 1)
    assert check_converted("x", 5.0, 0, 10) == 5.0


def test_bounded_text_names_the_size_of_what_it_cuts_and_never_its_values() -> None:
    assert bounded_text("short") == "short"
    assert bounded_text("index 99 outside 0-15") == "index 99 outside 0-15"  # normal size
    text = "set_digital_outputs " + str(list(range(30000)))
    assert bounded_text(text) == f"set_digital_outputs ({len(text)} characters, not shown)"
    name = "x" * 300_000
    said = bounded_text(f"no register named {name!r}")
    assert said == f"no register named ({300_000 + 20} characters, not shown)"
    assert bounded_text("7" * 2000) == "a text (2000 characters, not shown)"
    assert len(bounded_text("y" * 10**6)) < MESSAGE_MAX_CHARS
    # A long explanation (a refusal with its hardware check) is said whole.
    reason = "line_move pair 2 refused: interpolation pairs 2 and 3 " + "x" * 250
    assert bounded_text(reason) == reason


def test_a_long_list_is_described_by_its_count() -> None:
    assert listed([2, 9], "outputs") == "2, 9"
    assert listed([1, 2, 3], "projects", bracketed=True) == "[1, 2, 3]"  # as a list prints
    assert listed(range(3000), "projects", bracketed=True) == "(3000 projects)"
    assert listed([], "outputs") == "(none)"
    assert listed(range(30000), "outputs") == "(30000 outputs)"
    assert check_count("indexes", 16, 16) == 16
    with pytest.raises(CommandRejected, match=r"^30000 indexes, at most 16$"):
        check_count("indexes", 30000, 16)
