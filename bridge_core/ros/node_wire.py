"""``~/wire``: every Modbus frame of a node's link, published when ``record_wire`` is on
(docs/tools.md, "Recording the wire").

The link's ``wire_tap`` hands each transaction to ``FrameQueue.put`` under the link lock
(never blocking: a full queue drops the frame and counts it); a thread of this module
takes them off the queue and publishes ``msg_defs/ModbusFrame``, so the poll loop never
waits for ROS. Off (the default), none of this exists: no queue, no thread, no topic, no
hook in the link. On a shared line the owner of the link (a ``BusNode``, or a node with a
link of its own) publishes every unit's frames once on its own ``~/wire``; each device
node's diagnostics show the line's counts.
"""

from __future__ import annotations

import array
import threading
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from msg_defs.msg import ModbusFrame

from ..wire.wire_tap import FRAME_QUEUE_DEPTH, FrameQueue, WireCallback, WireFrame

WIRE_TOPIC = "~/wire"
# Reliable, and deep enough for a recorder that lags a second at 100 frames per second.
WIRE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
# How often the publisher thread looks whether it should end (it waits on the queue).
WAKE_S = 0.2
JOIN_S = 2.0
NS_PER_S = 1_000_000_000
# The parameter, declared with the transport's (``runtime.parameters.RECORD_WIRE_SPEC``).
RECORD_WIRE = "record_wire"


def stamp(message_time: Any, wall_time: float) -> None:
    """Set a ``builtin_interfaces/Time`` from ``time.time()``."""
    ns = round(wall_time * NS_PER_S)
    message_time.sec, message_time.nanosec = divmod(ns, NS_PER_S)


def to_message(frame: WireFrame) -> ModbusFrame:
    msg = ModbusFrame()
    msg.sequence = frame.sequence
    msg.rtu = frame.rtu
    msg.unit_id = frame.unit_id
    msg.function_code = frame.function_code
    msg.request = array.array("B", frame.request)
    msg.reply = array.array("B", frame.reply)
    stamp(msg.sent, frame.sent_at)
    stamp(msg.replied, frame.replied_at)
    msg.outcome = int(frame.outcome)
    msg.exception_code = frame.exception_code
    return msg


class WirePublisher:
    """``~/wire`` of one link: its queue, and the thread that publishes from it."""

    def __init__(self, node: Node, depth: int = FRAME_QUEUE_DEPTH) -> None:
        self._node = node
        self.queue = FrameQueue(depth)
        self.published = 0
        self.pub = node.create_publisher(ModbusFrame, WIRE_TOPIC, WIRE_QOS)
        self._thread = threading.Thread(
            target=self._run, name=f"{node.get_name()} wire", daemon=True
        )
        self._thread.start()

    @property
    def callback(self) -> WireCallback:
        """What the link calls with each frame (``ModbusLink(wire=...)``)."""
        return self.queue.put

    def _run(self) -> None:
        queue = self.queue
        while not queue.closed:
            frame = queue.get(WAKE_S)
            if frame is None:
                continue
            try:
                self.pub.publish(to_message(frame))
            except Exception as err:  # the context is gone (exit): nothing left to publish to
                if not self._node.context.ok():
                    return
                self._node.get_logger().error(f"~/wire: frame not published: {err}")
                continue
            self.published += 1

    def values(self) -> list[tuple[str, str]]:
        """The diagnostics' line: frames published, and dropped because the queue was full."""
        return [("wire frames published / dropped", f"{self.published} / {self.queue.dropped}")]

    def close(self) -> None:
        self.queue.close()
        if self._thread is not threading.current_thread():
            self._thread.join(JOIN_S)


def wire_publisher(node: Node, values: dict[str, Any]) -> WirePublisher | None:
    """The publisher if the node's ``record_wire`` is on, else None (nothing installed)."""
    return WirePublisher(node) if values.get(RECORD_WIRE) else None


__all__ = ["WIRE_TOPIC", "WirePublisher", "to_message", "wire_publisher"]
