"""R6 outputs: one output point of any board, or a whole IO board's outputs under a mask,
as checked writes (R6 decisions 3, 19, 21, 24). No ROS here. "R6 decision N" is reading N
of docs/decisions/r6.md.
"""

from __future__ import annotations

from bridge_core.runtime.checks import check_whole_number
from bridge_core.runtime.reads import read_named
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import int_to_words, words_to_int
from bridge_core.wire.errors import CommandRejected

from .registers import (
    EU_BOARD,
    FIRST_M_BOARD,
    HIGH,
    MAX_IO_BOARDS,
    OUTPUT_BOARDS_ACCEPTED,
    OUTPUT_POINTS,
    POINTS_PER_BOARD,
    R6_MAP,
    U32_MAX,
)


def set_output(
    io: RegisterIO,
    board: int,
    point: int,
    on: bool,
    boards_in_use: int | None,
    *,
    m_boards: bool,
    eu_board: bool,
) -> None:
    """Boards 0-3: §3.3.3, board, point and state in one FC 10 write to 20056-20058.
    Boards 4-8 (IO board 4, M boards 5-7, EU board 8): §5's FC 05 coil 32·board + point,
    the numbering that is unambiguous (R6 decisions 3, 19, 21). ``m_boards`` /
    ``eu_board``: the device offers those boards (``R6Device``)."""
    if point not in OUTPUT_POINTS:
        raise CommandRejected(f"output point {point} outside 0-31")
    if board in OUTPUT_BOARDS_ACCEPTED:
        # A board the controller does not report in use has no outputs to switch: the
        # write would be acknowledged with no effect (R6 decision 24).
        _check_board_in_use(board, _boards(io, boards_in_use))
        words = [board, point, 1 if on else 0]
        io.write_registers(R6_MAP["output_board"].address, words)
        return
    if board < FIRST_M_BOARD:
        _check_board_in_use(board, _boards(io, boards_in_use))
    elif board < EU_BOARD:
        if not m_boards:
            raise CommandRejected(
                f"output board {board} (M board {board - FIRST_M_BOARD}) refused: the M "
                "boards are off (parameter m_boards; the handheld network-port version "
                "does not offer them)"
            )
    elif board == EU_BOARD:
        if not eu_board:
            raise CommandRejected(
                f"output board {board} (EU board) refused: no EU board (parameter eu_board)"
            )
    else:
        raise CommandRejected(f"output board {board} outside 0-{EU_BOARD}")
    io.write_coil(POINTS_PER_BOARD * board + point, on)


def write_board_outputs(
    io: RegisterIO, board: int, bits: int, mask: int, boards_in_use: int | None
) -> str:
    """§3.3.1: outputs of one IO board (FC 10, 2 registers, high word first); only the
    outputs in ``mask`` change (R6 decision 24).

    The manual has no mask write, so a partial mask is a read-modify-write at command
    priority, the read just before the write: not atomic against the robot program,
    which may switch an output of the board in between (that change is then undone).
    ``boards_in_use`` (the count the controller last reported, 2186): a board past it
    is refused. Returns what was read and written."""
    if not 0 <= board < MAX_IO_BOARDS:
        raise CommandRejected(f"IO board {board} outside 0-{MAX_IO_BOARDS - 1}")
    check_whole_number("output bits", bits, 0, U32_MAX)
    check_whole_number("output mask", mask, 0, U32_MAX)
    if mask == 0:
        raise CommandRejected(
            "mask 0 changes no output: set bit n of mask for each output n to change "
            "(0xFFFFFFFF: the whole board)"
        )
    if bits & ~mask:
        raise CommandRejected(
            f"bits 0x{bits:08X} set outputs outside mask 0x{mask:08X} "
            f"(0x{bits & ~mask:08X}): add them to the mask or clear them"
        )
    _check_board_in_use(board, _boards(io, boards_in_use))
    reg = R6_MAP[f"io_board_output_{board}"]
    if mask == U32_MAX:
        io.write_registers(reg.address, int_to_words(bits, 2, False, HIGH))
        return f"board {board} outputs = 0x{bits:08X}"
    words = io.read_registers(reg.address, 2, priority=Priority.COMMAND)
    before = words_to_int(words, False, HIGH)
    after = (before & ~mask) | bits
    io.write_registers(reg.address, int_to_words(after, 2, False, HIGH))
    return (
        f"board {board} outputs read 0x{before:08X}, wrote 0x{after:08X} (mask "
        f"0x{mask:08X}; a read-modify-write, not atomic against the robot program)"
    )


def _boards(io: RegisterIO, boards_in_use: int | None) -> int:
    """The IO board count: as last polled, else read now (2186)."""
    if boards_in_use is not None:
        return boards_in_use
    return int(read_named(io, R6_MAP, ("io_board_count",))["io_board_count"])


def _check_board_in_use(board: int, boards_in_use: int | None) -> None:
    """``boards_in_use``: the count the controller last reported (2186); None before the
    first poll."""
    if boards_in_use is not None and board >= boards_in_use:
        raise CommandRejected(
            f"IO board {board} is not in use: the controller reports {boards_in_use} board(s)"
        )
