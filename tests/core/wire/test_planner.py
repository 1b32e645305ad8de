"""Read planner: merges where the device allows, splits where it must."""

from __future__ import annotations

import pytest

from bridge_core.wire.planner import decode_reply, plan_reads
from bridge_core.wire.registers import DeviceLimits, Register, RegisterMap, Table, ValueType


def make_map(limits: DeviceLimits) -> RegisterMap:
    return RegisterMap(
        "test",
        (
            Register("a", 0, ValueType.U16, "t"),
            Register("b", 1, ValueType.U32, "t"),
            Register("c", 3, ValueType.U16, "t"),
            Register("gap_filler", 4, ValueType.U16, "t"),
            Register("d", 5, ValueType.I32, "t"),
            # 7..9 undefined
            Register("e", 10, ValueType.U16, "t"),
            Register("f", 60, ValueType.U16, "t"),
            Register("in", 0, ValueType.U16, "t", table=Table.INPUT),
        ),
        limits,
    )


def spans(requests: list) -> list[tuple[str, int, int]]:  # type: ignore[type-arg]
    return [(r.table.value, r.address, r.count) for r in requests]


def test_contiguous_registers_merge() -> None:
    m = make_map(DeviceLimits())
    assert spans(plan_reads(m, m.select(["a", "b", "c"]))) == [("holding", 0, 4)]


def test_reads_through_defined_gap_but_not_undefined_one() -> None:
    m = make_map(DeviceLimits())
    # c..d: reads through gap_filler (defined, readable) -> one request.
    assert spans(plan_reads(m, m.select(["c", "d"]))) == [("holding", 3, 4)]
    # d..e: 7-9 undefined and the device refuses them -> two requests.
    assert spans(plan_reads(m, m.select(["d", "e"]))) == [("holding", 5, 2), ("holding", 10, 1)]


def test_undefined_gap_allowed_when_device_permits() -> None:
    m = make_map(DeviceLimits(read_undefined_ok=True, max_gap=4))
    assert spans(plan_reads(m, m.select(["d", "e"]))) == [("holding", 5, 6)]
    # ...but not past max_gap (10 -> 60 is 49 registers).
    assert len(plan_reads(m, m.select(["e", "f"]))) == 2


def test_max_registers_per_request_splits_without_cutting_values() -> None:
    m = make_map(DeviceLimits(max_read_registers=2))
    requests = plan_reads(m, m.select(["a", "b", "c"]))
    assert spans(requests) == [("holding", 0, 1), ("holding", 1, 2), ("holding", 3, 1)]


def test_gap_that_cuts_a_value_is_not_read_through() -> None:
    m = make_map(DeviceLimits())
    # a and c without b: reading 1..2 means reading b whole, which is fine...
    assert spans(plan_reads(m, m.select(["a", "c"]))) == [("holding", 0, 4)]


def test_tables_are_planned_separately_and_decoded() -> None:
    m = make_map(DeviceLimits())
    requests = plan_reads(m, m.select(["in", "a", "b"]))
    assert spans(requests) == [("holding", 0, 3), ("input", 0, 1)]
    values = decode_reply(requests[0], [7, 0x0001, 0x0002])
    assert values == {"a": 7, "b": 0x00010002}


def test_write_only_register_cannot_be_planned() -> None:
    from bridge_core.wire.registers import Access

    m = RegisterMap("w", (Register("cmd", 0, ValueType.U16, "t", access=Access.WRITE),))
    with pytest.raises(ValueError, match="write-only"):
        plan_reads(m, m.select(["cmd"]))


def test_map_validation() -> None:
    with pytest.raises(ValueError, match="overlaps"):
        RegisterMap(
            "x", (Register("a", 0, ValueType.U32, "t"), Register("b", 1, ValueType.U16, "t"))
        )
    with pytest.raises(ValueError, match="duplicate"):
        RegisterMap(
            "x", (Register("a", 0, ValueType.U16, "t"), Register("a", 1, ValueType.U16, "t"))
        )
    with pytest.raises(ValueError, match="cite"):
        Register("a", 0, ValueType.U16, "")
    with pytest.raises(ValueError, match="read-only"):
        from bridge_core.wire.registers import Access

        Register("a", 0, ValueType.U16, "t", table=Table.INPUT, access=Access.WRITE)


def test_block_decoder_matches_the_codec_for_every_type_and_order() -> None:
    import random

    from bridge_core.wire.codec import decode, encode
    from bridge_core.wire.registers import Access, WordOrder

    rng = random.Random(7)
    for order in WordOrder:
        regs = []
        address = 0
        for kind in (
            ValueType.U16,
            ValueType.I16,
            ValueType.U32,
            ValueType.I32,
            ValueType.U64,
            ValueType.I64,
            ValueType.F32,
            ValueType.F64,
            ValueType.STRING,
        ):
            for scale, offset in ((1.0, 0.0), (10.0, 0.0), (10.0, -273.15)):
                if kind is ValueType.STRING and scale != 1.0:
                    continue
                length = 3 if kind is ValueType.STRING else 0
                regs.append(
                    Register(
                        f"r{address}",
                        address,
                        kind,
                        "t",
                        word_order=order,
                        scale=scale,
                        offset=offset,
                        length=length,
                        access=Access.READ_WRITE,
                    )
                )
                address = regs[-1].end + 1  # leave a gap word between values
        m = RegisterMap("fast", tuple(regs), DeviceLimits(read_undefined_ok=True, max_gap=1))
        (request,) = plan_reads(m, regs)
        for _ in range(200):
            words = [rng.randrange(0x10000) for _ in range(request.count)]
            for reg in regs:
                if reg.value_type is ValueType.STRING:
                    words[reg.address : reg.end] = encode(reg, "ab")
                elif reg.value_type.is_float:  # random words may be a NaN, never equal
                    words[reg.address : reg.end] = encode(reg, rng.uniform(-1e4, 1e4))
            expected = {r.name: decode(r, words[r.address : r.end]) for r in regs}
            assert decode_reply(request, words) == expected
