"""R6 point data (§3.3.5): an upload checked whole, then sent frame by frame.

The ``~/upload_points`` action sends one frame per step (progress, cancel between frames);
the service of the same name sends them all at once. No ROS here. "R6 decision N" is
reading N of docs/decisions/r6.md.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from typing import Any, Protocol

from bridge_core.runtime.checks import check_whole_number
from bridge_core.wire.channel import RegisterIO
from bridge_core.wire.codec import int_to_words
from bridge_core.wire.errors import CommandRejected, LinkError, NotConfirmed
from bridge_core.wire.registers import MAX_WRITE_REGISTERS

from .registers import (
    HIGH,
    I32_MAX,
    I32_MIN,
    POINT_AXIS_MASK_MAX,
    POINT_FRAME_MAX_BYTES,
    POINT_VALUES_PER_POINT,
    R6_MAP,
)


class UploadDevice(Protocol):
    """What an upload writes through (``R6Device``), named here so the device imports
    this module and never the other way round."""

    @property
    def io(self) -> RegisterIO: ...


# Registers in one upload frame: the manual's 256-byte frame cap and Modbus's 123 (FC 10).
POINT_FRAME_MAX_REGISTERS = min(POINT_FRAME_MAX_BYTES // 2, MAX_WRITE_REGISTERS)
POINT_FRAME_HEADER_REGISTERS = 2  # 30005 point count, 30006 clear flag
POINT_DATA = "point_data"  # the axis of an upload goal: the point-data rows 30000-30006


class PointUploadSteps:
    """§3.3.5 point data in steps: configure 30002-30004, then frames at 30005 (count,
    clear flag, data), each one FC 10. The first frame clears the source (30006 = 1),
    later ones append (0). Every value is checked before the first write; each ``step``
    sends the next frame (the first also the configuration), so an action can stop
    between frames."""

    axes: frozenset[Hashable] = frozenset({POINT_DATA})

    def __init__(
        self,
        device: UploadDevice,
        data_source_id: int,
        values_per_point: int,
        axis_mask: int,
        values: Sequence[int],
    ) -> None:
        check_whole_number("data source id", data_source_id, 0, 0xFFFF)
        if values_per_point not in POINT_VALUES_PER_POINT:
            raise CommandRejected(f"values_per_point must be one of {POINT_VALUES_PER_POINT}")
        check_whole_number("axis mask", axis_mask, 0, POINT_AXIS_MASK_MAX)
        # §4 30004: bits 0-5 = axes 1-6 of a point; a point of 4 values has no axes 5-6
        # and a mask of 0 marks no value valid (R6 decision 25).
        if axis_mask == 0:
            raise CommandRejected("axis mask 0 marks no axis of a point valid")
        if axis_mask >> values_per_point:
            raise CommandRejected(
                f"axis mask 0x{axis_mask:02X} names axes past the {values_per_point} values "
                f"of a point (at most 0x{(1 << values_per_point) - 1:02X})"
            )
        if not values or len(values) % values_per_point:
            raise CommandRejected(
                f"{len(values)} values is not a whole, non-zero number of "
                f"{values_per_point}-value points"
            )
        for value in values:
            check_whole_number("point value", value, I32_MIN, I32_MAX)
        per_frame = (POINT_FRAME_MAX_REGISTERS - POINT_FRAME_HEADER_REGISTERS) // (
            2 * values_per_point
        )
        self.frames: list[list[int]] = []
        self.frame_points: list[int] = []
        points = [values[k : k + values_per_point] for k in range(0, len(values), values_per_point)]
        for first in range(0, len(points), per_frame):
            chunk = points[first : first + per_frame]
            words = [len(chunk), 1 if first == 0 else 0]
            for point in chunk:
                for value in point:
                    words += int_to_words(value, 2, True, HIGH)
            self.frames.append(words)
            self.frame_points.append(len(chunk))
        self.device = device
        self.points_held = 0  # points of this upload the source holds
        self.setup = [data_source_id, values_per_point, axis_mask]
        self.what = f"upload_points source {data_source_id}: {len(points)} points"
        self.total = len(self.frames)
        self.sent = 0

    def step(self) -> None:
        io = self.device.io
        if self.sent == 0:
            io.write_registers(R6_MAP["point_source_id"].address, self.setup)
        io.write_registers(R6_MAP["point_count"].address, self.frames[self.sent])
        self.points_held += self.frame_points[self.sent]
        self.sent += 1

    def abandon(self) -> str:
        """An upload that will not finish: clear the source it half filled (the set-up
        again, then a frame of 0 points with the clear flag), so the controller never
        runs a path cut short (R6 decision 25)."""
        io = self.device.io
        io.write_registers(R6_MAP["point_source_id"].address, self.setup)
        io.write_registers(R6_MAP["point_count"].address, [0, 1])
        self.points_held = 0
        return f"source {self.setup[0]} cleared (it held {self.points_held_text()})"

    def points_held_text(self) -> str:
        return f"{sum(self.frame_points[: self.sent])} points of this upload"

    def feedback(self) -> dict[str, Any]:
        return {"frames_sent": self.sent, "frames_total": self.total}

    def result(self) -> dict[str, Any]:
        return {**self.feedback(), "points_held": self.points_held}

    def send_all(self) -> int:
        """Every frame in one go (the ``~/upload_points`` service); the number of data
        frames. A frame that fails after others went out leaves the source half filled:
        it is cleared (``abandon``), and the error says so, or, if the clear fails too,
        how many points of this upload the source holds (R6 decision 25)."""
        while self.sent < self.total:
            try:
                self.step()
            except LinkError as err:
                if self.sent == 0:
                    raise
                failed = f"frame {self.sent + 1} of {self.total} failed ({err})"
                try:
                    undone = self.abandon()
                except LinkError as again:
                    undone = (
                        f"the clear failed too ({again}): source {self.setup[0]} holds "
                        f"{self.points_held_text()}"
                    )
                raise NotConfirmed(f"{failed}; {undone}") from err
        return self.total
