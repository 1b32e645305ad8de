"""ConfigCache: whole read once, then one request per poll while a refresh is due."""

from __future__ import annotations

from bridge_core.runtime.config_cache import ConfigCache
from bridge_core.wire.channel import Priority
from bridge_core.wire.codec import Value
from bridge_core.wire.planner import ReadRequest, plan_reads
from bridge_core.wire.registers import DeviceLimits, Register, RegisterMap, ValueType

MAP = RegisterMap(
    "cfg",
    tuple(Register(f"r{i}", 10 * i, ValueType.U16, "t") for i in range(3)),
    DeviceLimits(max_gap=0),
)
PLAN = plan_reads(MAP, list(MAP))


def test_read_all_then_refresh_one_request_per_step() -> None:
    now = [0.0]
    reads: list[int] = []
    device = {"r0": 1, "r1": 2, "r2": 3}

    def read(request: ReadRequest, priority: Priority) -> dict[str, Value]:
        reads.append(request.address)
        return {reg.name: device[reg.name] for reg in request.registers}

    cache = ConfigCache(PLAN, read, refresh_s=5.0, clock=lambda: now[0])
    assert len(PLAN) == 3 and not cache.complete
    cache.read_all()
    assert cache.complete and cache.values == device and reads == [0, 10, 20]
    reads.clear()
    cache.refresh_step()
    assert reads == []  # not due yet
    device["r2"] = 30
    now[0] = 5.0
    for _ in range(3):
        cache.refresh_step()
    assert reads == [0, 10, 20] and cache.values["r2"] == 30
    reads.clear()
    cache.refresh_step()
    assert reads == []  # next refresh at t = 10
    cache.refresh_soon()
    cache.refresh_step()
    assert reads == [0]
    cache.note_written("r1", 99)
    cache.note_written("unknown", 1)
    assert cache.values["r1"] == 99 and "unknown" not in cache.values
    cache.clear()
    assert not cache.complete
