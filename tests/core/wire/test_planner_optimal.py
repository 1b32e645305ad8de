"""The planner's request count is the optimum: a brute-force search over every valid read
window agrees on 200 random maps."""

from __future__ import annotations

import random

from bridge_core.wire.planner import ReadRequest, plan_reads, split_request
from bridge_core.wire.registers import Access, DeviceLimits, Register, RegisterMap, Table, ValueType

KINDS = (ValueType.U16, ValueType.I16, ValueType.U32, ValueType.F32, ValueType.U64)
MAPS = 200


def random_map(rng: random.Random) -> RegisterMap:
    regs: list[Register] = []
    for table in (Table.HOLDING, Table.INPUT, Table.COIL):
        address = rng.randrange(3)
        for index in range(rng.randrange(2, 9)):
            kind = ValueType.BOOL if table.is_bit else rng.choice(KINDS)
            access = Access.READ if table is Table.INPUT else rng.choice(list(Access))
            if rng.random() < 0.15:
                access = Access.WRITE if table is not Table.INPUT else Access.READ
            regs.append(
                Register(f"{table.value}_{index}", address, kind, "t", table=table, access=access)
            )
            address = regs[-1].end + (rng.choice((0, 0, 1, 2, 5)) if rng.random() < 0.6 else 0)
            if table.is_bit and rng.random() < 0.3:
                address += rng.randrange(10, 40)
    limits = DeviceLimits(
        max_read_registers=rng.randrange(4, 20),
        max_read_bits=rng.randrange(4, 80),
        read_undefined_ok=rng.random() < 0.5,
        max_gap=rng.choice((None, None, 0, 1, 3)),
        homogeneous_requests=rng.random() < 0.25,
    )
    return RegisterMap("random", tuple(regs), limits)


def window_is_valid(
    register_map: RegisterMap, table: Table, start: int, end: int, wanted: set[str]
) -> bool:
    """A read of ``start..end`` judged from the limits alone (not the planner's code)."""
    limits = register_map.limits
    if end - start > (limits.max_read_bits if table.is_bit else limits.max_read_registers):
        return False
    owners = set()
    gap = 0
    for address in range(start, end):
        owner = register_map.owner_at(table, address)
        if owner is None and not limits.read_undefined_ok:
            return False
        if owner is not None:
            if not owner.access.readable or owner.address < start or owner.end > end:
                return False
            owners.add(owner)
        if owner is None or owner.name not in wanted:
            gap += 1
            cap = limits.max_gap
            if cap is not None and gap > cap * (16 if table.is_bit else 1):
                return False
        else:
            gap = 0
    if limits.homogeneous_requests and not table.is_bit:
        widths = {owner.count for owner in owners}
        if len(widths) > 1 or (widths == {4} and len(owners) > 1):
            return False
    return True


def brute_force_count(register_map: RegisterMap, wanted: list[Register]) -> int:
    """The fewest valid windows covering every wanted register (breadth-first search over
    the sets of registers covered)."""
    total = 0
    for table in {reg.table for reg in wanted}:
        regs = sorted((r for r in wanted if r.table is table), key=lambda r: r.address)
        names = {r.name for r in regs}
        windows: list[int] = []
        for i, first in enumerate(regs):
            for last in regs[i:]:
                if window_is_valid(register_map, table, first.address, last.end, names):
                    windows.append(
                        sum(
                            1 << k
                            for k, r in enumerate(regs)
                            if first.address <= r.address and r.end <= last.end
                        )
                    )
        goal = (1 << len(regs)) - 1
        frontier, seen, depth = {0}, {0}, 0
        while goal not in frontier:
            depth += 1
            frontier = {mask | w for mask in frontier for w in windows} - seen
            seen |= frontier
            assert frontier, "no plan covers the registers"
        total += depth
    return total


def test_plan_count_equals_the_brute_force_optimum_on_random_maps() -> None:
    rng = random.Random(21)
    for _ in range(MAPS):
        register_map = random_map(rng)
        readable = [r for r in register_map if r.access.readable]
        wanted = rng.sample(readable, rng.randrange(1, len(readable) + 1))
        plan = plan_reads(register_map, wanted)
        names = {r.name for r in wanted}
        for request in plan:  # every request is valid and serves whole registers
            assert window_is_valid(
                register_map, request.table, request.address, request.end, names
            ), request
        assert {r.name for request in plan for r in request.registers} == names
        assert len(plan) == brute_force_count(register_map, wanted), (register_map, wanted)


def coils(spacing: int, limits: DeviceLimits) -> RegisterMap:
    return RegisterMap(
        "coils",
        tuple(
            Register(f"c{i}", i * spacing, ValueType.BOOL, "t", table=Table.COIL) for i in range(8)
        ),
        limits,
    )


def test_coil_gaps_are_counted_in_bits_and_max_gap_is_only_a_cap() -> None:
    # 8 coils 37 bits apart: one read of 260 bits when the device serves the gaps.
    uncapped = coils(37, DeviceLimits(read_undefined_ok=True, max_gap=None))
    assert [(r.address, r.count) for r in plan_reads(uncapped, list(uncapped))] == [(0, 260)]
    # a cap of 16 registers is 256 bits: 36-bit gaps fit it
    capped = coils(37, DeviceLimits(read_undefined_ok=True, max_gap=16))
    assert len(plan_reads(capped, list(capped))) == 1
    # a cap of 2 registers is 32 bits: every coil alone
    tight = coils(37, DeviceLimits(read_undefined_ok=True, max_gap=2))
    assert len(plan_reads(tight, list(tight))) == 8


def test_of_equal_plans_the_one_reading_fewer_registers() -> None:
    # a..c fit one request of 11, b..c too: a alone + b..c reads 3 registers, not 12.
    m = RegisterMap(
        "m",
        (
            Register("a", 0, ValueType.U16, "t"),
            Register("b", 10, ValueType.U16, "t"),
            Register("c", 11, ValueType.U16, "t"),
        ),
        DeviceLimits(max_read_registers=11, read_undefined_ok=True, max_gap=None),
    )
    plan = plan_reads(m, list(m))
    assert [(r.address, r.count) for r in plan] == [(0, 1), (10, 2)]


def test_a_refused_merged_read_splits_at_its_gaps_only() -> None:
    m = RegisterMap(
        "m",
        (
            Register("a", 0, ValueType.U16, "t"),
            Register("b", 1, ValueType.U32, "t"),
            Register("c", 5, ValueType.U16, "t"),
        ),
        DeviceLimits(read_undefined_ok=True, max_gap=None),
    )
    (merged,) = plan_reads(m, list(m))
    runs = split_request(merged)
    assert [(r.address, r.count) for r in runs] == [(0, 3), (5, 1)]
    assert split_request(runs[0]) == ()  # no gap: the device refused a or b themselves
    assert split_request(runs[1]) == ()
    single = ReadRequest(Table.HOLDING, 1, 2, (m["b"],))
    assert split_request(single) == ()
