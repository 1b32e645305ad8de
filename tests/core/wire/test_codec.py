"""Known vectors for every value type in both word orders, both directions."""

from __future__ import annotations

import pytest

from bridge_core.wire.codec import (
    CodecError,
    decode,
    encode,
    int_to_words,
    string_to_words,
    words_to_int,
    words_to_string,
)
from bridge_core.wire.registers import Access, Register, ValueType, WordOrder

HIGH, LOW = WordOrder.HIGH_FIRST, WordOrder.LOW_FIRST

# (type, value, words high-word-first); low-word-first is the same words reversed.
VECTORS = [
    (ValueType.U16, 0, [0x0000]),
    (ValueType.U16, 0xABCD, [0xABCD]),
    (ValueType.U16, 65535, [0xFFFF]),
    (ValueType.I16, -1, [0xFFFF]),
    (ValueType.I16, -32768, [0x8000]),
    (ValueType.I16, 32767, [0x7FFF]),
    (ValueType.U32, 0x12345678, [0x1234, 0x5678]),
    (ValueType.U32, 4294967295, [0xFFFF, 0xFFFF]),
    (ValueType.I32, -2, [0xFFFF, 0xFFFE]),
    (ValueType.I32, -2147483648, [0x8000, 0x0000]),
    (ValueType.I32, 100000, [0x0001, 0x86A0]),
    (ValueType.U64, 0x0102030405060708, [0x0102, 0x0304, 0x0506, 0x0708]),
    (ValueType.U64, 2**64 - 1, [0xFFFF] * 4),
    (ValueType.I64, -1, [0xFFFF] * 4),
    (ValueType.I64, -(2**63), [0x8000, 0, 0, 0]),
    (ValueType.I64, 5000, [0, 0, 0, 0x1388]),
]


@pytest.mark.parametrize(("kind", "value", "words"), VECTORS)
@pytest.mark.parametrize("order", [HIGH, LOW])
def test_integer_vectors(kind: ValueType, value: int, words: list[int], order: WordOrder) -> None:
    on_wire = words if order is HIGH else list(reversed(words))
    assert int_to_words(value, kind.words, kind.signed, order) == on_wire
    assert words_to_int(on_wire, kind.signed, order) == value
    reg = Register("v", 0, kind, "test", word_order=order, access=Access.READ_WRITE)
    assert encode(reg, value) == on_wire
    assert decode(reg, on_wire) == value


def test_low_word_first_differs_from_high_word_first() -> None:
    # Stepper manual: "低16位在前" - 0x00010002 is sent as 0002 0001.
    assert int_to_words(0x00010002, 2, False, LOW) == [0x0002, 0x0001]
    assert words_to_int([0x0002, 0x0001], False, LOW) == 0x00010002
    assert words_to_int([0x0002, 0x0001], False, HIGH) == 0x00020001


@pytest.mark.parametrize(
    ("kind", "value"),
    [
        (ValueType.U16, -1),
        (ValueType.U16, 65536),
        (ValueType.I16, 32768),
        (ValueType.U32, 2**32),
        (ValueType.I32, -(2**31) - 1),
        (ValueType.U64, -1),
        (ValueType.I64, 2**63),
    ],
)
def test_out_of_range_integers_are_refused(kind: ValueType, value: int) -> None:
    with pytest.raises(CodecError):
        int_to_words(value, kind.words, kind.signed, HIGH)


def test_scaled_values_both_directions() -> None:
    position = Register("p", 0, ValueType.I32, "test", scale=1000, access=Access.READ_WRITE)
    assert encode(position, -1.5) == [0xFFFF, 0xFA24]  # -1500
    assert decode(position, [0xFFFF, 0xFA24]) == pytest.approx(-1.5)
    speed = Register(
        "s", 0, ValueType.U16, "test", scale=10, minimum=0, maximum=100, access=Access.READ_WRITE
    )
    assert encode(speed, 10.0) == [100]
    assert encode(speed, 33.33) == [333]  # quantised to the 0.1 step
    assert decode(speed, [1000]) == pytest.approx(100.0)
    with pytest.raises(CodecError, match="outside"):
        encode(speed, 100.1)
    with pytest.raises(CodecError, match="outside"):
        encode(speed, -0.1)


def test_strings() -> None:
    # R6 §3.1.2: odd length, the last register's low byte is 0.
    words = string_to_words("ABC", 2)
    assert words == [0x4142, 0x4300]
    assert words_to_string(words) == "ABC"
    reg = Register("name", 0, ValueType.STRING, "test", length=2, access=Access.READ_WRITE)
    assert decode(reg, [0x4142, 0x4300]) == "ABC"
    with pytest.raises(CodecError):
        encode(reg, "ABCDE")


def test_decode_checks_word_count() -> None:
    reg = Register("v", 0, ValueType.U32, "test")
    with pytest.raises(CodecError):
        decode(reg, [1])


@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf")])
def test_non_finite_values_are_refused(value: float) -> None:
    reg = Register(
        "s", 0, ValueType.U16, "test", scale=10, minimum=0, maximum=100, access=Access.READ_WRITE
    )
    with pytest.raises(CodecError, match="outside"):
        encode(reg, value)


# IEEE 754 known vectors (words high word first): 1.0, -2.5, pi as f32 and f64.
FLOAT_VECTORS = [
    (ValueType.F32, 1.0, [0x3F80, 0x0000]),
    (ValueType.F32, -2.5, [0xC020, 0x0000]),
    (ValueType.F64, 1.0, [0x3FF0, 0, 0, 0]),
    (ValueType.F64, 3.141592653589793, [0x4009, 0x21FB, 0x5444, 0x2D18]),
]


@pytest.mark.parametrize(("kind", "value", "words"), FLOAT_VECTORS)
@pytest.mark.parametrize("order", [HIGH, LOW])
def test_float_vectors(kind: ValueType, value: float, words: list[int], order: WordOrder) -> None:
    on_wire = words if order is HIGH else list(reversed(words))
    reg = Register("v", 0, kind, "test", word_order=order, access=Access.READ_WRITE)
    assert encode(reg, value) == on_wire
    assert decode(reg, on_wire) == value


def test_f32_overflow_is_refused() -> None:
    reg = Register("v", 0, ValueType.F32, "test", access=Access.READ_WRITE)
    with pytest.raises(CodecError, match="does not fit f32"):
        encode(reg, 1e39)


def test_offset_both_directions() -> None:
    # value = raw / scale + offset: 0.1 degC steps from -40 degC (raw 0 = -40.0).
    temperature = Register(
        "t", 0, ValueType.U16, "test", scale=10, offset=-40.0, access=Access.READ_WRITE
    )
    assert encode(temperature, 21.5) == [615]
    assert decode(temperature, [615]) == pytest.approx(21.5)
    assert decode(temperature, [0]) == pytest.approx(-40.0)
    scaled_float = Register(
        "f", 0, ValueType.F32, "test", scale=2.0, offset=1.0, access=Access.READ_WRITE
    )
    assert encode(scaled_float, 2.0) == [0x4000, 0x0000]  # (2 - 1) * 2 = 2.0
    assert decode(scaled_float, [0x4000, 0x0000]) == 2.0
