"""Registers <-> values: integer widths, word order, strings and scaling.

Pure Python on purpose: it is the part most worth testing with known vectors, and keeping
it free of pymodbus means a pymodbus upgrade cannot silently change a word order.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

from .errors import CommandRejected
from .registers import Register, ValueType, WordOrder

WORD_MASK = 0xFFFF
Value = int | float | str | bool
# IEEE 754 formats of the float types, as big-endian bytes of their words high first.
FLOAT_FORMATS = {ValueType.F32: ">f", ValueType.F64: ">d"}


class CodecError(CommandRejected):
    """A value does not fit its register (out of range, wrong type, wrong length)."""


def words_to_int(words: Sequence[int], signed: bool, word_order: WordOrder) -> int:
    """Join 16-bit words into one integer."""
    ordered = list(words) if word_order is WordOrder.HIGH_FIRST else list(reversed(words))
    raw = 0
    for word in ordered:
        if not 0 <= word <= WORD_MASK:
            raise CodecError(f"register value {word} is not a 16-bit word")
        raw = (raw << 16) | word
    bits = 16 * len(words)
    if signed and raw >= 1 << (bits - 1):
        raw -= 1 << bits
    return raw


def int_to_words(value: int, word_count: int, signed: bool, word_order: WordOrder) -> list[int]:
    """Split an integer into 16-bit words; raises CodecError if it does not fit."""
    bits = 16 * word_count
    low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    if not low <= value <= high:
        kind = "signed" if signed else "unsigned"
        raise CodecError(f"{value} does not fit {bits}-bit {kind} ({low}..{high})")
    raw = value & ((1 << bits) - 1)
    words = [(raw >> (16 * (word_count - 1 - i))) & WORD_MASK for i in range(word_count)]
    return words if word_order is WordOrder.HIGH_FIRST else list(reversed(words))


def words_to_string(words: Sequence[int]) -> str:
    """Two characters per register, high byte first; trailing NUL padding dropped."""
    data = b"".join(word.to_bytes(2, "big") for word in words)
    return data.rstrip(b"\x00").decode("latin-1")


def string_to_words(text: str, word_count: int) -> list[int]:
    data = text.encode("latin-1")
    if len(data) > 2 * word_count:
        raise CodecError(f"string of {len(data)} bytes does not fit {word_count} registers")
    data = data.ljust(2 * word_count, b"\x00")
    return [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]


def words_to_float(words: Sequence[int], kind: ValueType, word_order: WordOrder) -> float:
    """An IEEE 754 value from its words (f32: 2, f64: 4) in ``word_order``."""
    ordered = list(words) if word_order is WordOrder.HIGH_FIRST else list(reversed(words))
    data = b"".join(word.to_bytes(2, "big") for word in ordered)
    return float(struct.unpack(FLOAT_FORMATS[kind], data)[0])


def float_to_words(value: float, kind: ValueType, word_order: WordOrder) -> list[int]:
    """The words of an IEEE 754 value; raises CodecError if it does not fit (f32)."""
    try:
        data = struct.pack(FLOAT_FORMATS[kind], value)
    except OverflowError as err:
        raise CodecError(f"{value} does not fit {kind.label}") from err
    words = [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]
    return words if word_order is WordOrder.HIGH_FIRST else list(reversed(words))


def decode_raw(register: Register, words: Sequence[int]) -> int | float | str | bool:
    """The unscaled value of ``register`` from its words."""
    if len(words) != register.count:
        raise CodecError(f"{register.name}: expected {register.count} words, got {len(words)}")
    kind = register.value_type
    if kind is ValueType.STRING:
        return words_to_string(words)
    if kind is ValueType.BOOL:
        return bool(words[0])
    if kind.is_float:
        return words_to_float(words, kind, register.word_order)
    return words_to_int(words, kind.signed, register.word_order)


def decode(register: Register, words: Sequence[int]) -> Value:
    """Engineering value: ``raw / scale + offset`` (a float when scaled or offset, else
    the raw int)."""
    raw = decode_raw(register, words)
    if (register.scale != 1.0 or register.offset != 0.0) and not isinstance(raw, str | bool):
        return raw / register.scale + register.offset
    return raw


def to_raw(register: Register, value: Value) -> int | float | str | bool:
    """Engineering value -> raw number, checked against the register's write range."""
    kind = register.value_type
    if kind is ValueType.STRING:
        if not isinstance(value, str):
            raise CodecError(f"{register.name} takes a string")
        return value
    if kind is ValueType.BOOL:
        return bool(value)
    if isinstance(value, str):
        raise CodecError(f"{register.name} takes a number, not {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise CodecError(f"{register.name}: {value} is outside any range")
    if (register.minimum is not None and value < register.minimum) or (
        register.maximum is not None and value > register.maximum
    ):
        unit = f" {register.unit}" if register.unit else ""
        raise CodecError(
            f"{register.name}: {value}{unit} is outside "
            f"{register.minimum}..{register.maximum}{unit}"
        )
    if kind.is_float:
        return (float(value) - register.offset) * register.scale
    if isinstance(value, int) and register.scale == 1.0 and register.offset == 0.0:
        return value  # exact: a float product would lose 64-bit precision
    # Quantise to the register's step (e.g. 33.33 % -> 333 at 0.1 % steps); range was checked.
    return round((value - register.offset) * register.scale)


def encode(register: Register, value: Value) -> list[int]:
    """Words for writing ``value`` (engineering units) to ``register``."""
    raw = to_raw(register, value)
    kind = register.value_type
    if kind is ValueType.STRING:
        assert isinstance(raw, str)
        return string_to_words(raw, register.count)
    if kind is ValueType.BOOL:
        return [1 if raw else 0]
    if kind.is_float:
        assert isinstance(raw, float)
        try:
            return float_to_words(raw, kind, register.word_order)
        except CodecError as err:
            raise CodecError(f"{register.name}: {err}") from err
    assert isinstance(raw, int)
    try:
        return int_to_words(raw, kind.words, kind.signed, register.word_order)
    except CodecError as err:
        raise CodecError(f"{register.name}: {err}") from err
