"""``~/joint_commands``: one ``sensor_msgs/JointState`` command topic per node
(docs/ros2_control.md).

Part of the ROS side (imports rclpy). The checks are ``bridge_core.runtime.joint_commands``
(plain Python); here is the subscription: a message is checked whole on arrival, on the
node's ``Inbox`` (a thread of its own, not the executor: a flood of 1000 msg/s neither
waits behind a write nor starves the polls), then its values are offered
to the joints' stream guards, whose writers and deadman (``node_streams.StreamHost``) do the
rest. A refused message writes nothing, counts in the diagnostics by kind
(``joint_commands refused``) and, the first time of its kind, is one WARN line.

The node that owns the topic need not own the joints: the MOTEC bus owner has one topic for
every drive of its bus, and each ``CommandJoint`` offers to its own drive node's guards, is
judged by that node's state (a drive's deactivate refuses its own values only) and counts
its refusals in that node's diagnostics (``CommandJoint.counts``). A message refused whole
counts for each node whose joints it names (every node's, when it names none of them).
"""

from __future__ import annotations

import traceback
from collections.abc import Iterable
from typing import Any

from sensor_msgs.msg import JointState

from ..runtime.joint_commands import (
    DIAGNOSTICS_KEY,
    TOPIC,
    CommandJoint,
    RefusalCounts,
    Refused,
    apply,
    message_fields,
    plan,
    refused_arrival,
)
from .node_parameters import ParameterNode

# A few messages may wait for the callback: partial messages from two senders (each naming
# its own joints) must not replace each other before they were read. The guards keep only
# the newest value per joint, so a longer queue would only replay old values.
JOINT_COMMANDS_DEPTH = 5


class JointCommandTopic:
    """The ``~/joint_commands`` subscription of ``node`` for ``joints``, on its inbox."""

    def __init__(self, node: ParameterNode, joints: Iterable[CommandJoint]) -> None:
        self.node = node
        self.joints = {joint.name: joint for joint in joints}
        self.counts = RefusalCounts()
        self.accepted = 0  # messages offered to the guards
        self._bug_said = False
        node.inbox.subscribe(JointState, TOPIC, self._arrived, JOINT_COMMANDS_DEPTH)

    def _counts(self, joint: CommandJoint) -> RefusalCounts:
        return joint.counts if joint.counts is not None else self.counts

    def _arrived(self, msg: Any) -> None:
        fields = message_fields(msg)
        named = [self.joints[n] for n in dict.fromkeys(fields[0]) if n in self.joints]
        try:
            planned = plan(self.joints, *fields)
        except Refused as refused:
            refused_arrival(named)
            self._count(named or list(self.joints.values()), refused)
            return
        except Exception as err:  # a bug must not end the subscription's callbacks
            if not self._bug_said:
                self._bug_said = True
                self.node.get_logger().error(
                    f"joint_commands failed: {err}\n{traceback.format_exc()}"
                )
            return
        for joint, closed in planned.refused:
            refused_arrival([joint])
            self._count([joint], closed)
        apply(planned)
        self.accepted += 1

    def _count(self, joints: list[CommandJoint], refused: Refused) -> None:
        """Count a refusal once in each node's count of ``joints``; said (one WARN) the
        first time of its kind in any of them."""
        counts = {id(c): c for c in (self._counts(joint) for joint in joints)} or {
            id(self.counts): self.counts
        }
        first = [c.add(refused.kind) for c in counts.values()]
        if any(first):
            self.node.get_logger().warn(
                f"{refused.text} (said once per kind; diagnostics '{DIAGNOSTICS_KEY}' "
                "counts every refusal)"
            )


__all__ = ["JOINT_COMMANDS_DEPTH", "JointCommandTopic"]
