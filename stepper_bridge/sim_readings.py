"""The other readings the stepper simulator plays for ``bridge_commission stepper``
(docs/tools.md, "Device personalities"): 32-bit values high word first (stepper decision
1, ``--word-order high``), undefined rows answered with zeros (decisions 7, 21,
``--answer-undefined``), interpolation pairs 2 and 3 by the point rows (decision 19,
``--pair-reading point_rows``), and homing that leaves the coordinate (decision 20,
``--no-zero-at-home``).

The simulated device holds the switches (``StepperSimDevice.high_word_first`` ...); this
module holds what they do to an answer and their command-line options. "Stepper decision
N" is reading N of docs/decisions/stepper.md.
"""

from __future__ import annotations

import argparse
from typing import Protocol

from bridge_core.wire.registers import RegisterMap, Table

WORD_ORDERS = ("low", "high")  # the manual's (decision 1) first
PAIR_READINGS = ("type_rows", "point_rows")  # the simulator's default first
DOUBLE_WORD = 2  # the 32-bit rows whose words the order swaps


class Readings(Protocol):
    """The switches, as the simulated device holds them."""

    high_word_first: bool
    answer_undefined: bool
    pair_reading: str
    zero_at_home: bool


def undefined(register_map: RegisterMap, address: int, count: int) -> bool:
    """No row of the map owns any holding address of the read (answered with zeros with
    ``--answer-undefined``)."""
    return all(
        register_map.owner_at(Table.HOLDING, a) is None for a in range(address, address + count)
    )


def high_word_first(register_map: RegisterMap, address: int, words: list[int]) -> list[int]:
    """``words`` read from holding ``address`` with every whole 32-bit value high word
    first (the map stores them low word first)."""
    out = list(words)
    at = address
    while at < address + len(out):
        owner = register_map.owner_at(Table.HOLDING, at)
        if owner is None or owner.count != DOUBLE_WORD or owner.address != at:
            at += 1
            continue
        start = at - address
        if owner.end <= address + len(out):
            out[start], out[start + 1] = out[start + 1], out[start]
        at = owner.end
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--word-order",
        choices=WORD_ORDERS,
        default=WORD_ORDERS[0],
        help="32-bit values as read: low word first (the manual, decision 1) or high word "
        "first (reads only)",
    )
    parser.add_argument(
        "--answer-undefined",
        action="store_true",
        help="a read of undefined rows only answers zeros, not 0x02 (decisions 7, 21)",
    )
    parser.add_argument(
        "--pair-reading",
        choices=PAIR_READINGS,
        default=PAIR_READINGS[0],
        help="which motors pairs 2 and 3 drive: by the type rows (2 = 1+3, 3 = 2+3) or the "
        "point rows (2 = 2+3, 3 = 1+3) (decision 19)",
    )
    parser.add_argument(
        "--no-zero-at-home",
        action="store_true",
        help="homing leaves the coordinate as it was (decision 20's other reading)",
    )


def apply(device: Readings, args: argparse.Namespace) -> None:
    device.high_word_first = args.word_order == "high"
    device.answer_undefined = args.answer_undefined
    device.pair_reading = args.pair_reading
    device.zero_at_home = not args.no_zero_at_home
