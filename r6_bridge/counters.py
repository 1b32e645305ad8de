"""R6 counters (§3.1.3, §3.1.4, §3.3.2): list their ids, read one by selecting it, write
one and read it back (R6 decision 24). No ROS here. "R6 decision N" is reading N of
docs/decisions/r6.md.
"""

from __future__ import annotations

from bridge_core.runtime.checks import check_whole_number
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import int_to_words, words_to_int
from bridge_core.wire.errors import CommandRejected, NotConfirmed
from bridge_core.wire.registers import MAX_READ_REGISTERS

from .registers import HIGH, MAX_COUNTERS, R6_MAP, U32_MAX

# §3.1.3: ids past the counter count are padded with 0xFF bytes.
COUNTER_ID_PADDING = U32_MAX
COUNTER_IDS_SHOWN = 10  # ids named in a refusal of an unknown counter


def read_counter_ids(io: RegisterIO) -> list[int]:
    """§3.1.3: the count, then 2 registers per id in chunks that keep ids whole."""
    count = io.read_registers(R6_MAP["counter_count"].address, 1)[0]
    count = min(count, MAX_COUNTERS)
    ids: list[int] = []
    per_request = (MAX_READ_REGISTERS // 2) * 2
    first = R6_MAP["counter_id_0"].address
    remaining = 2 * count
    address = first
    while remaining > 0:
        n = min(per_request, remaining)
        words = io.read_registers(address, n)
        ids += [words_to_int(words[k : k + 2], False, HIGH) for k in range(0, n, 2)]
        address += n
        remaining -= n
    # A count that shrank between the two reads pads the rest with 0xFF (§3.1.3).
    return [counter_id for counter_id in ids if counter_id != COUNTER_ID_PADDING]


def read_counter(io: RegisterIO, counter_id: int) -> tuple[int, int, int]:
    """§3.1.4: write the id to 2179, then read id, target and current (6 registers).

    The id read back must be the one written: another client selecting a counter in
    between would otherwise hand us its counter's values."""
    check_whole_number("counter id", counter_id, 0, COUNTER_ID_PADDING - 1)
    address = R6_MAP["counter_select_id"].address
    io.write_registers(address, int_to_words(counter_id, 2, False, HIGH))
    words = io.read_registers(address, 6, priority=Priority.COMMAND)
    selected = words_to_int(words[0:2], False, HIGH)
    if selected != counter_id:
        raise CommandRejected(
            f"counter {counter_id}: the controller answered for counter {selected} "
            "(another client selected a counter in between); try again"
        )
    return (
        selected,
        words_to_int(words[2:4], False, HIGH),
        words_to_int(words[4:6], False, HIGH),
    )


def set_counter(io: RegisterIO, counter_id: int, value: int) -> str:
    """§3.3.2: id, target (ignored by the host: 0) and current value, 6 registers.

    The id must be one the controller lists (§3.1.3): the host acknowledges a write to
    an unknown id and changes nothing. The counter is read back (§3.1.4) and the
    reply says what it holds (R6 decision 24)."""
    check_whole_number("counter id", counter_id, 0, U32_MAX)
    check_whole_number("counter value", value, 0, U32_MAX)
    ids = read_counter_ids(io)
    if counter_id not in ids:
        listed = ", ".join(str(k) for k in ids[:COUNTER_IDS_SHOWN])
        extra = len(ids) - COUNTER_IDS_SHOWN
        more = f" and {extra} more" if extra > 0 else ""
        raise CommandRejected(
            f"counter {counter_id} is not one the controller lists ({listed or 'none'}"
            f"{more}; ~/list_counters)"
        )
    write_counter(io, counter_id, value)
    _, target, current = read_counter(io, counter_id)
    if current != value:
        raise NotConfirmed(
            f"counter {counter_id}: wrote {value}, reads {current} (target {target})"
        )
    return f"counter {counter_id} reads {current} (target {target})"


def write_counter(io: RegisterIO, counter_id: int, value: int) -> None:
    """§3.3.2's frame alone: id, target (ignored by the host: 0) and current value."""
    check_whole_number("counter id", counter_id, 0, U32_MAX)
    check_whole_number("counter value", value, 0, U32_MAX)
    words = [
        *int_to_words(counter_id, 2, False, HIGH),
        0,
        0,
        *int_to_words(value, 2, False, HIGH),
    ]
    io.write_registers(R6_MAP["counter_modify_id"].address, words)
