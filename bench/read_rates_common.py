"""What the parts of bench/read_rates.py share: joint 1 of each device and the values
its change probe sets it to, the probe's latency figures and their table cell, the slow
group's period.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bench.change_probe import ChangeProbe
from bench.latency_phase import latency_stats
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S

SLOW_PERIOD_S = SLOW_POLL_PERIOD_DEFAULT_S  # the devices are built with the node default

# Joint 1 of each device's snapshot, and the values the probe sets it to (integers: the
# stepper's user units, MOTEC counts, R6 and xArm degrees), inside what the simulators
# allow without tripping a limit switch.
JOINT_READERS: dict[str, Callable[[Any], float]] = {
    "stepper": lambda s: float(s.coordinates[0]),
    "motec": lambda s: float(s.position_actual),
    "r6": lambda s: float(s.axis_positions_deg[0]),
    "xarm": lambda s: float(s.joint_angles_deg[0]),
}
JOINT_RANGES: dict[str, tuple[int, int]] = {
    "stepper": (1, 400),
    "motec": (-1_000_000, 1_000_000),
    "r6": (-170, 170),
    "xarm": (-180, 180),
}


def latency(probe: ChangeProbe) -> dict[str, Any]:
    return {
        **latency_stats(probe.samples_s),
        "missed": probe.missed,
        "error": probe.error,
        "what": "register change -> snapshot (device layer)",
    }


def latency_cell(lat: dict[str, Any]) -> str:
    if not lat["n"]:
        return f"- (0, {lat['missed']})"
    return f"{lat['p50_ms']:.1f}/{lat['p99_ms']:.1f} ({lat['n']}, {lat['missed']})"
