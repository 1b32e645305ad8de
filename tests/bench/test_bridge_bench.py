"""bench/bridge_bench.py counts a node's polls from its /diagnostics: the "slow group"
value it reads is the one the node base writes (``node_diagnostics.slow_group_text``),
and a poll count takes the slow group's requests out before dividing by the fast
group's (a bench that divided by the whole map's requests printed wrong ratios)."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import cast

import pytest

from bench.bridge_bench import ReadPlan, slow_group_status
from bridge_core.ros.node_diagnostics import slow_group_text
from bridge_core.runtime.rate_groups import PollGroups

NOW = 1_000_000.0


def text(slow: int, period_s: float, read_time: float) -> str:
    """The node's value for a slow group of ``slow`` requests (a stand-in for the
    ``PollGroups``: only these three attributes are read)."""
    groups = SimpleNamespace(slow=[object()] * slow, period_s=period_s, slow_read_time=read_time)
    return slow_group_text(cast(PollGroups, groups), NOW)


def test_the_node_s_slow_group_value_reads_back() -> None:
    requests, period, age = slow_group_status(text(0, 1.0, 0.0))
    assert (requests, age) == (0, None) and math.isnan(period)
    assert slow_group_status(text(2, 1.0, 0.0)) == (2, 1.0, None)
    assert slow_group_status(text(2, 1.0, NOW - 0.34)) == (2, 1.0, 0.3)
    assert slow_group_status(text(3, 2.5, NOW - 12.0)) == (3, 2.5, 12.0)
    with pytest.raises(ValueError, match="slow group"):
        slow_group_status("2 requests, once in a while")


def test_polls_leave_the_slow_group_out() -> None:
    plan = ReadPlan(
        fast=(("holding", 0, 10),) * 11, slow=(("holding", 100, 4),) * 2, slow_period_s=1.0
    )
    # 1100 polls, 5 of them with the slow group: 1100 x 11 + 5 x 2 transactions.
    assert plan.polls(1100 * 11 + 5 * 2, 5) == 1100
    assert ReadPlan.from_json(plan.to_json()) == plan
