"""The rulebook's refusals (bridge_core.wire.registers): every fault names the field at fault
and what is allowed, so a description file can point it at its key and line."""

from __future__ import annotations

import pytest

from bridge_core.wire.registers import (
    Access,
    DeviceLimits,
    Fault,
    Register,
    RegisterMap,
    RuleError,
    Table,
    ValueType,
)


def faults_of(build: object) -> list[tuple[str | None, str, int | None]]:
    assert callable(build)
    with pytest.raises(RuleError) as caught:
        build()
    assert isinstance(caught.value, ValueError)  # callers catching ValueError still do
    return [(f.field, f.message, f.index) for f in caught.value.faults]


@pytest.mark.parametrize(
    ("fields", "field", "message"),
    [
        ({"name": "9a"}, "name", "'9a' is not a name (allowed: an identifier)"),
        ({"doc": ""}, "doc", "empty: cite the manual section the register comes from"),
        (
            {"table": Table.COIL},
            "value_type",
            "u16 in the coil table (allowed: bool)",
        ),
        (
            {"value_type": ValueType.BOOL},
            "value_type",
            "bool in the holding table (allowed: any type but bool)",
        ),
        (
            {"value_type": ValueType.STRING},
            "length",
            "missing: a string needs its length in registers",
        ),
        ({"length": 2}, "length", "only a string has a length (its type fixes the size)"),
        (
            {"table": Table.INPUT, "access": Access.READ_WRITE},
            "access",
            "RW on the read-only input table (R)",
        ),
        ({"address": -1}, "address", "-1: must be greater than or equal to 0 (0..65535)"),
        ({"address": 70000}, "address", "70000: must be less than or equal to 65535 (0..65535)"),
        (
            {"address": 65535, "value_type": ValueType.U32},
            "address",
            "65535+2 runs past 65535",
        ),
        ({"scale": 0.0}, "scale", "0.0: must be greater than 0 (raw per unit)"),
        ({"minimum": 2.0, "maximum": 1.0}, "minimum", "[2.0, 1.0]: minimum > maximum"),
        (
            {"table": Table.COIL, "value_type": ValueType.BOOL, "maximum": 1.0},
            None,
            "a bool has no scale, offset or range",
        ),
        (
            {"value_type": ValueType.STRING, "length": 2, "offset": 1.0},
            None,
            "a string has no scale, offset or range",
        ),
    ],
)
def test_a_register_fault_names_its_field(
    fields: dict[str, object], field: str | None, message: str
) -> None:
    arguments: dict[str, object] = {
        "name": "a",
        "address": 0,
        "value_type": ValueType.U16,
        "doc": "t",
        **fields,
    }
    assert faults_of(lambda: Register(**arguments)) == [(field, message, None)]  # type: ignore[arg-type]


def test_every_register_fault_is_listed_in_one_error() -> None:
    with pytest.raises(RuleError) as caught:
        Register("a", -1, ValueType.U16, "", table=Table.INPUT, access=Access.WRITE)
    assert [f.field for f in caught.value.faults] == ["doc", "access", "address"]
    assert str(caught.value).startswith("register 'a' @ -1: empty: cite")


def word(name: str, address: int, **fields: object) -> Register:
    return Register(name, address, ValueType.U16, "t", **fields)  # type: ignore[arg-type]


def test_a_map_fault_names_the_register_by_position_and_field() -> None:
    registers = (
        word("a", 0),
        word("b", 1, access=Access.READ_WRITE),
        word("a", 2),
        Register("c", 1, ValueType.U32, "t"),
    )
    assert faults_of(lambda: RegisterMap("x", registers)) == [
        ("name", "duplicate name: register 'a' defined twice (names are unique)", 2),
        ("address", "c overlaps b at holding 1 (each address belongs to one register)", 3),
    ]


def test_a_map_needs_a_read_of_every_readable_register() -> None:
    registers = (
        Register("s", 0, ValueType.STRING, "t", length=5),
        Register("f", 10, ValueType.F64, "t"),
        Register("w", 20, ValueType.F64, "t", access=Access.WRITE),  # never read: any size
    )
    assert faults_of(lambda: RegisterMap("x", registers, DeviceLimits(max_read_registers=3))) == [
        ("length", "5 registers: more than one read takes (3)", 0),
        ("value_type", "4 registers: more than one read takes (3)", 1),
    ]


def test_a_map_needs_the_function_codes_of_its_registers() -> None:
    registers = (
        word("r", 0),
        word("w", 1, access=Access.WRITE),
        Register("c", 0, ValueType.BOOL, "t", table=Table.COIL, access=Access.READ_WRITE),
        Register("d", 0, ValueType.BOOL, "t", table=Table.DISCRETE_INPUT),
    )
    limits = DeviceLimits(function_codes=frozenset({3, 16}))
    assert faults_of(lambda: RegisterMap("x", registers, limits)) == [
        (
            "table",
            "readable coil needs function code 1 in the device's function_codes (or access W)",
            2,
        ),
        ("access", "writable coil needs function code 5 or 15 in the device's function_codes", 2),
        (
            "table",
            "readable discrete_input needs function code 2 in the device's function_codes "
            "(or access W)",
            3,
        ),
    ]
    RegisterMap("x", registers[:2], limits)  # 3 reads, 16 writes the holding ones


@pytest.mark.parametrize(
    ("fields", "expected"),
    [
        (
            {"max_read_registers": 126},
            [Fault("max_read_registers", "126: must be less than or equal to 125 (1..125)")],
        ),
        (
            {"max_write_registers": 0},
            [Fault("max_write_registers", "0: must be greater than or equal to 1 (1..123)")],
        ),
        (
            {"max_read_bits": 2001, "max_gap": -1},
            [
                Fault("max_read_bits", "2001: must be less than or equal to 2000 (1..2000)"),
                Fault("max_gap", "-1: must be greater than or equal to 0 (0..125)"),
            ],
        ),
        ({"max_gap": 126}, [Fault("max_gap", "126: must be less than or equal to 125 (0..125)")]),
    ],
)
def test_device_limit_faults_name_their_field(
    fields: dict[str, int], expected: list[Fault]
) -> None:
    with pytest.raises(RuleError) as caught:
        DeviceLimits(**fields)  # type: ignore[arg-type]
    assert list(caught.value.faults) == expected
