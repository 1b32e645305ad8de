"""The MOTEC lifeguard's arithmetic (§3.4, docs/bridges/motec.md "Lifeguard"): when a
feed falls due, the shortest lifeguard time a bus can keep fed, and the range a lifeguard
time must lie in. No I/O and no ROS here.

The drive's side (``MotecDevice``): ``arm_lifeguard(ms)`` writes 0x112 = ms then 0x114 =
9999 (the manual's two FC 06 frames), ``disarm_lifeguard`` 0x112 = 0 then 0x114 = 0;
``feed_lifeguard`` rewrites 0x112 (at ``Priority.KEEPALIVE``, before commands and polls)
when no other write went to the drive for a feed period (also while the drive is marked
down), so the drive's watchdog only fires when the bridge is gone (or the bus is, for
longer than the lifeguard time less a feed period). ``lifeguard_min_ms`` is the shortest
lifeguard time a bus can keep fed.
"""

from __future__ import annotations

import math

from bridge_core.runtime.keepalive import FEED_WAKE_S
from bridge_core.wire.errors import CommandRejected

from .registers import MOTEC_MAP

LIFEGUARD_MIN_MS = 50  # below this a feed every third of it would crowd the bus
FEEDS_PER_PERIOD = 3  # the bridge writes at least 3 times per lifeguard time
# While a drive is marked down, within the lifeguard time since its last write, a feed is
# tried this often (each try holds the line for the short stop timeout): a line that
# answers again is found, and the drive fed, within about this (docs/bridges/motec.md,
# "Across line outages").
DOWN_FEED_RETRY_S = 0.1


def check_lifeguard_ms(time_ms: int) -> None:
    """Refuse a lifeguard time outside ``LIFEGUARD_MIN_MS``..0x112's maximum."""
    reg = MOTEC_MAP["lifeguard_time"]
    if (
        isinstance(time_ms, bool)
        or not isinstance(time_ms, int)
        or not LIFEGUARD_MIN_MS <= time_ms <= (reg.maximum or 0)
    ):
        raise CommandRejected(
            f"lifeguard time {time_ms!r} ms outside {LIFEGUARD_MIN_MS}..{int(reg.maximum or 0)}"
        )


def next_feed_time(
    time_ms: int, last_write: float, last_feed_try: float, down: bool = False
) -> float:
    """When the lifeguard needs its next write (the clock of ``last_write``, the request
    of the drive's last successful write, and ``last_feed_try``, the last feed's request).

    Up: a feed period after the request of the last write of any kind (a feed that failed
    while the line was down does not delay it: once the line answers again the overdue feed
    goes at once; docs/bridges/motec.md, "Across line outages"). Down (``down``): the first
    try a feed period after the last write, then one every ``DOWN_FEED_RETRY_S`` until the
    lifeguard time since the last write is over (after it a real drive has tripped unless a
    try got through), then one per feed period."""
    period = lifeguard_feed_period_s(time_ms)
    first = last_write + period
    if not down or last_feed_try < first - period:
        return first
    trip = last_write + time_ms / 1000.0
    retry = DOWN_FEED_RETRY_S if last_feed_try + DOWN_FEED_RETRY_S < trip else period
    return max(first, last_feed_try + min(retry, period))


def lifeguard_feed_period_s(time_ms: int) -> float:
    return time_ms / 1000.0 / FEEDS_PER_PERIOD


def lifeguard_min_ms(drives: int, hold_s: float) -> int:
    """The shortest lifeguard time the bridge can keep fed on a bus (docs/bridges/motec.md).

    A feed falls due ``time / FEEDS_PER_PERIOD`` after the request of the drive's last
    write (counted from the request, not the reply: the drive's watchdog may restart as
    early as the request reaches it), starts up to ``FEED_WAKE_S`` late, then waits for
    the line: for the transaction in progress and for the feeds of the other drives
    queued before it (feeds go first), each at most ``hold_s``
    (``SerialSettings.longest_hold_s``: silence, the longest frame, the reply timeout).
    The gap between two writes to a live drive stays within the time if
        time / 3 + FEED_WAKE_S + drives x hold_s <= time,
    i.e. time >= 1.5 x (FEED_WAKE_S + drives x hold_s) with 3 feeds per period. While
    the line is down the feeds go on with the short stop timeout (``next_feed``: every
    ``DOWN_FEED_RETRY_S`` within the lifeguard time), so a drive whose line answers x
    after its last write is fed before it trips when x + DOWN_FEED_RETRY_S +
    FEED_WAKE_S + hold_s < time (docs/bridges/motec.md, "Across line outages";
    bench/motec_blackout.py)."""
    gap_s = FEED_WAKE_S + drives * hold_s
    bound_ms = gap_s * FEEDS_PER_PERIOD / (FEEDS_PER_PERIOD - 1) * 1000.0
    return max(LIFEGUARD_MIN_MS, math.ceil(round(bound_ms, 6)))  # 90.00000000000001 is 90


def lifeguard_bound_text(drives: int, hold_s: float) -> str:
    """The formula of ``lifeguard_min_ms`` with this bus's numbers, for messages."""
    return (
        f"{FEEDS_PER_PERIOD / (FEEDS_PER_PERIOD - 1):g} x ({FEED_WAKE_S:g} s wake-up + "
        f"{drives} drive(s) x {hold_s:.3f} s, the longest transaction on this line: "
        f"silence, the longest frame, timeout_s)"
    )
