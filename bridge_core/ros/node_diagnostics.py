"""``/diagnostics`` of the bridge nodes: one status per node every ``diagnostic_period_s``
(1 s by default; live).

Part of the node base (imports rclpy). The status joins the link's report (rate, latency,
failures: ``diagnostics.link_report``), the node's own counters, and the device's report
(``BridgeNode.device_report``), at the worst level of them; an inactive node publishes
nothing.
"""

from __future__ import annotations

import time
import traceback
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup

from ..runtime.diagnostics import DIAGNOSTIC_PERIOD_DEFAULT_S, Level, link_report
from ..runtime.joint_commands import DIAGNOSTICS_KEY
from ..runtime.rate_groups import PollGroups
from ..runtime.wire_budget import budget_values

if TYPE_CHECKING:
    from .node_base import BridgeNode

DIAGNOSTICS_DEPTH = 10
NS_PER_S = 1_000_000_000


class DiagnosticsPublisher:
    """Publishes one node's status on ``/diagnostics`` from a timer of its own group."""

    def __init__(
        self, node: BridgeNode[Any], period_s: float = DIAGNOSTIC_PERIOD_DEFAULT_S
    ) -> None:
        self.node = node
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_DEPTH)
        self.timer = node.create_timer(
            period_s, self.publish, callback_group=MutuallyExclusiveCallbackGroup()
        )

    def set_period(self, period_s: float) -> None:
        """``diagnostic_period_s`` changed: the next status comes one new period from now."""
        self.timer.timer_period_ns = round(period_s * NS_PER_S)
        self.timer.reset()

    def publish(self) -> None:
        if not self.node.active:
            return  # an inactive node publishes nothing
        try:
            status = self.status()
            array = DiagnosticArray()
            array.header.stamp = self.node.get_clock().now().to_msg()
            array.status = [status]
            self.pub.publish(array)
        except Exception as err:  # diagnostics must never take the node down
            self.node.get_logger().error(f"diagnostics failed: {err}\n{traceback.format_exc()}")

    def status(self) -> DiagnosticStatus:
        node = self.node
        poller = node.poller
        link = link_report(
            node.channel,
            poll_rate=poller.rate,
            target_rate_hz=poller.rate_hz,
            poll_failures=poller.failures,
        )
        device = node.device_report() if node.channel.connected else None
        level, message, values = link.level, link.message, list(link.values)
        values.append(("snapshots dropped (publisher behind)", str(poller.snapshots_dropped)))
        values.append(("read_only", str(node.read_only).lower()))
        values.append(("slow group", slow_group_text(node.poll_groups(), time.time())))
        values += budget_values(node.wire_budget.budget(), node.link.is_serial)
        if node.line_load is not None:
            values.append(("line load, all devices (%)", node.line_load()))
        if node.wire is not None:
            values += node.wire.values()
        if node.streams.guards:
            values.append(("stream commands refused", str(node.streams.refusals)))
        if node.joint_command_refusals is not None:
            values.append((DIAGNOSTICS_KEY, node.joint_command_refusals.text()))
        if node.actions.servers:
            values.append(("action goals running", "; ".join(node.actions.running) or "none"))
        if node.channel.connected and poller.last_error:
            # Connected but no fresh state: as bad as a lost link for a consumer.
            level, message = Level.ERROR, poller.last_error
        if device is not None:
            values += device.values
            if device.level > level:
                level, message = device.level, device.message
        return DiagnosticStatus(
            level=bytes([int(level)]),
            # The full name: two bridges of one kind in one domain differ by namespace.
            name=f"{node.get_fully_qualified_name()}: {node.device_name} Modbus bridge",
            message=message,
            hardware_id=node.hardware_id,
            values=[KeyValue(key=k, value=v) for k, v in values],
        )


def slow_group_text(groups: PollGroups, now: float) -> str:
    """What the slow group is and how old its values are (the age a user checks)."""
    if not groups.slow:
        return "empty (every register is read every poll)"
    requests = f"{len(groups.slow)} request(s) every {groups.period_s:g} s"
    read = groups.slow_read_time
    return f"{requests}, last read {now - read:.1f} s ago" if read else f"{requests}, not read yet"


__all__ = ["DiagnosticsPublisher", "slow_group_text"]
