"""The other readings the R6 simulator plays for ``bridge_commission`` (docs/tools.md,
"Device personalities"): 32/64-bit values low word first (R6 decision 1, ``--word-order
low``), the rows past the axis and IO board counts answered (decision 8,
``--answer-past-counts``), registers outside the map answered with 0 (decision 11,
``--answer-undefined``), the M boards' rows and coils refused as on the handheld
network-port version (decision 21, ``--no-m-boards``).

The simulated device holds the switches (``R6SimDevice.low_word_first`` ...); this module
holds what they do to an answer and their command-line options. "R6 decision N" is
reading N of docs/decisions/r6.md.
"""

from __future__ import annotations

import argparse
from typing import Protocol

from bridge_core.wire.registers import RegisterMap, Table

from .registers import COIL_BANKS, M_BOARDS, R6_MAP

WORD_ORDERS = ("high", "low")
MULTI_WORD_COUNTS = (2, 4)  # the 32- and 64-bit rows whose words the order swaps
M_BOARD_ROWS = frozenset(
    (
        *range(R6_MAP["m_board_input_0"].address, R6_MAP[f"m_board_input_{M_BOARDS - 1}"].end),
        *range(R6_MAP["m_board_output_0"].address, R6_MAP[f"m_board_output_{M_BOARDS - 1}"].end),
    )
)
M_BOARD_COILS = range(COIL_BANKS[1][1], COIL_BANKS[1][1] + COIL_BANKS[1][2])


class Readings(Protocol):
    """The switches, as the simulated device holds them."""

    low_word_first: bool
    answer_past_counts: bool
    answer_undefined: bool
    m_boards_offered: bool


def m_board_refused(table: Table, address: int, count: int) -> bool:
    """A read that touches an M board's rows or coils (refused with ``--no-m-boards``)."""
    rows = M_BOARD_COILS if table is Table.COIL else M_BOARD_ROWS
    return any(a in rows for a in range(address, address + count))


def undefined(register_map: RegisterMap, table: Table, address: int, count: int) -> bool:
    """No row of the map owns any address of the read (answered 0 with
    ``--answer-undefined``)."""
    return all(register_map.owner_at(table, a) is None for a in range(address, address + count))


def low_word_first(
    register_map: RegisterMap, table: Table, address: int, words: list[int]
) -> list[int]:
    """``words`` read from ``address`` with every whole 32/64-bit value low word first."""
    out = list(words)
    at = address
    while at < address + len(out):
        owner = register_map.owner_at(table, at)
        if owner is None or owner.count not in MULTI_WORD_COUNTS or owner.address != at:
            at += 1
            continue
        start = at - address
        if owner.end <= address + len(out):
            out[start : start + owner.count] = reversed(out[start : start + owner.count])
        at = owner.end
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--word-order",
        choices=WORD_ORDERS,
        default="high",
        help="32/64-bit values high word first (the manual, decision 1) or low word first",
    )
    parser.add_argument(
        "--answer-past-counts",
        action="store_true",
        help="answer the rows of axes and IO boards past their counts (decision 8: refused)",
    )
    parser.add_argument(
        "--answer-undefined",
        action="store_true",
        help="answer registers outside the map with 0 (decision 11: exception 0x02)",
    )
    parser.add_argument(
        "--no-m-boards",
        action="store_true",
        help="refuse the M boards' rows and coils, as the handheld network-port version "
        "(decision 21)",
    )


def apply(device: Readings, args: argparse.Namespace) -> None:
    device.low_word_first = args.word_order == "low"
    device.answer_past_counts = args.answer_past_counts
    device.answer_undefined = args.answer_undefined
    device.m_boards_offered = not args.no_m_boards
