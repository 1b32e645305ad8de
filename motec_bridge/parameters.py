"""Which MOTEC parameter ``~/read_parameter`` / ``~/write_parameter`` may read or write,
and with what value (§3.1, §3.2, §5.2; MOTEC decision 13): every check made before the
first request, so a refused one sends nothing. ``MotecDevice`` does the I/O. No ROS here.
"""

from __future__ import annotations

from bridge_core.runtime.checks import check_index, check_whole_number
from bridge_core.wire.errors import CommandRejected
from bridge_core.wire.registers import Register, Table

from .registers import MOTEC_MAP, PARAMETER_OWN_SERVICE, parameter_numbers, parameter_register

# Pr.N is holding address N, one of 65536 (FC 03 / FC 06 carry a 16-bit address); an
# unlisted parameter is one 16-bit word.
PARAMETER_NUMBER_LIMIT = 0x10000
U16_LIMIT = 0xFFFF
I16_LIMIT = 0x8000


def second_word_of(number: int) -> None:
    """Refuse Pr.``number`` if it is the low word of a named 32-bit parameter."""
    for other in MOTEC_MAP.in_table(Table.HOLDING):
        if number in other.addresses() and number != other.address:
            raise CommandRejected(
                f"Pr.{number} is the low word of the 32-bit Pr.{other.address} ({other.name}, "
                f"high word first, §3.1.2): give {other.address}"
            )


def known_parameter(number: int) -> Register:
    """The register of Pr.``number`` (a parameter the manual names), else refused."""
    reg = parameter_register(number)
    if reg is not None:
        return reg
    second_word_of(number)
    known = ", ".join(str(n) for n in parameter_numbers())
    raise CommandRejected(
        f"Pr.{number} is not a parameter the manual names, so its range is unknown (known: "
        f"{known}); the drive node's allow_unlisted_parameters lets ~/write_parameter send it "
        "anyway (the drive checks the value: exception 03)"
    )


def parameter_to_read(number: int) -> Register | None:
    """The named register of Pr.``number`` (read whole), or None: any other number is
    read as one unsigned 16-bit word (a read needs no range: a number past the drive's
    table answers exception 02, §2.7). The low word of a named 32-bit value is refused."""
    check_index("parameter number", number, range(PARAMETER_NUMBER_LIMIT))
    reg = parameter_register(number)
    if reg is None:
        second_word_of(number)
    return reg


def parameter_to_write(
    number: int, value: int, allow_unlisted: bool
) -> tuple[Register | None, int]:
    """What Pr.``number`` = ``value`` writes: the named register and its value, within
    the manual's range; or None and the word for a number the manual does not name (only
    with ``allow_unlisted``: one word, 0..65535 or -32768..-1 as its two's complement; its
    range is the drive's to check, which answers exception 03, §2.7, §3.1). Refused
    (``CommandRejected``) otherwise."""
    reg = parameter_to_read(number)
    if reg is None:
        if not allow_unlisted:
            known_parameter(number)  # refused, with the list of known ones
        word = check_whole_number(f"Pr.{number} (unlisted)", value, -I16_LIMIT, U16_LIMIT)
        return None, word & U16_LIMIT
    what = f"Pr.{number} (0x{number:X}, {reg.name})"
    if not reg.access.writable:
        raise CommandRejected(f"{what} is read only (§3.2)")
    if reg.name in PARAMETER_OWN_SERVICE:
        raise CommandRejected(f"{what} is written by {PARAMETER_OWN_SERVICE[reg.name]}")
    low, high = int(reg.minimum or 0), int(reg.maximum or 0)
    return reg, check_whole_number(what, value, low, high)
