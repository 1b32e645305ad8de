"""Stepper line and arc interpolation: the pair readings, the checks, the writes and the
run the bridge started.

Interpolation pairs: types 2 and 3 are refused until ``interpolation_pair_reading`` says
which of the manual's two readings the controller follows (stepper decisions 11, 19):
``pair_axes``. The controller has no "interpolation running" register: a line / arc the
bridge started counts as running until a poll begun after its start coil shows its motors
stopped (or a stop / e-stop is acknowledged). §5(1) 40201 / 40211: "插补过程运行中不可调节";
a second line / arc is refused meanwhile (decision 14). A line / arc that moves a motor
outside its configured pair is reported once (``take_wrong_pair``): the node stops it.
No ROS here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

from bridge_core.runtime.checks import check_choice, check_finite
from bridge_core.wire.codec import Value, encode
from bridge_core.wire.errors import CommandRejected, LinkError

from .confirm import ConfirmingDevice, confirm_started, confirm_stopped
from .jog import JogControl
from .registers import (
    ARC_MODE_CENTER,
    ARC_MODE_THREE_POINTS,
    DISTANCE_SCALE,
    INTERPOLATION_PAIRS,
    INTERPOLATION_PAIRS_POINT_ROWS,
    STEPPER_MAP,
    SYSTEM_COILS,
    coil,
)
from .replies import check_integer, coil_label, motor_coils_text


class InterpolationDevice(ConfirmingDevice, Protocol):
    """What a line / arc uses of the device (``StepperDevice``), named here so the
    device imports this module and never the other way round."""

    @property
    def pair_reading(self) -> str: ...

    @property
    def next_poll(self) -> int: ...

    @property
    def jog_control(self) -> JogControl: ...

    def write_values(self, values: Sequence[tuple[str, Value]], *, jog: bool = False) -> None: ...

    def send_coil(self, name: str) -> None: ...

    def send_motor_stops(self, motors: Sequence[int]) -> LinkError | None: ...


# interpolation_pair_reading: which of the manual's two readings of pair types 2 and 3 the
# controller follows (stepper decision 19). Unset until the hardware check in
# docs/decisions/stepper.md settles it: pairs 2 and 3 are refused meanwhile.
PAIR_READING_UNSET = "unset"
PAIR_READINGS: dict[str, dict[int, tuple[int, int]]] = {
    "type_rows": INTERPOLATION_PAIRS,
    "point_rows": INTERPOLATION_PAIRS_POINT_ROWS,
}
PAIR_READING_CHOICES = (PAIR_READING_UNSET, *PAIR_READINGS)
# Every motor an interpolation pair can name, under either reading: what
# stop_interpolation stops when the bridge started no line / arc itself.
INTERPOLATION_MOTORS = tuple(
    sorted({m for pairs in PAIR_READINGS.values() for pair in pairs.values() for m in pair})
)


@dataclass(frozen=True)
class InterpolationRun:
    """A line / arc the bridge started: its motors (under both readings of the pair), the
    first poll sequence number that began after its start coil was sent, the pair's motors
    by the configured reading and every motor's coordinate read before the start."""

    kind: str
    motors: tuple[int, ...]
    first_poll: int
    pair: int = 0
    expected: tuple[int, ...] = ()
    start_coordinates: dict[int, float] = field(default_factory=dict)

    def moved(self, coordinates: Sequence[float]) -> list[int]:
        """Motors of either reading whose coordinate is off its value at the start by a
        step or more (the registers count hundredths of a unit)."""
        return [
            m
            for m, at_start in self.start_coordinates.items()
            if round(coordinates[m - 1] * DISTANCE_SCALE) != round(at_start * DISTANCE_SCALE)
        ]

    def wrong_motors(self, coordinates: Sequence[float]) -> list[int]:
        """Moved motors outside the configured pair (the controller reads it otherwise)."""
        return [m for m in self.moved(coordinates) if m not in self.expected]


def pair_axes(pair: int, reading: str) -> tuple[int, int]:
    """The (first, second) motor of an interpolation pair under the configured reading.

    Pair 1 is motors 1+2 under both readings of the manual. Pairs 2 and 3 are motors 1+3
    and 2+3 by the type rows (40182 / 40202) but 2+3 and 1+3 by the point rows under them:
    refused (one line) until ``interpolation_pair_reading`` names the reading the hardware
    check showed (registers.INTERPOLATION_PAIRS).
    """
    check_pair(pair)
    by_type, by_points = INTERPOLATION_PAIRS[pair], INTERPOLATION_PAIRS_POINT_ROWS[pair]
    if by_type == by_points:
        return by_type
    if reading not in PAIR_READINGS:
        raise CommandRejected(
            f"interpolation pair {pair} refused: the manual names motors "
            f"{by_type[0]}+{by_type[1]} for it in its type rows (40182/40202) and "
            f"{by_points[0]}+{by_points[1]} in its point rows; run the hardware check in "
            "docs/decisions/stepper.md, then set interpolation_pair_reading to type_rows or "
            "point_rows (pair 1 needs neither)"
        )
    return PAIR_READINGS[reading][pair]


class InterpolationControl:
    """The line / arc commands of one controller and the run the bridge started (``run``);
    the pair reading is the device's ``pair_reading``."""

    def __init__(self, device: InterpolationDevice) -> None:
        self.device = device
        self.run: InterpolationRun | None = None
        # A line / arc that moved a motor outside its configured pair, once per run: the
        # node stops it (stepper decision 19). Set by a poll, taken by the node.
        self._wrong_pair: str | None = None
        self._wrong_pair_run: InterpolationRun | None = None

    def check_line_move(
        self, pair: int, start: tuple[float, float], end: tuple[float, float], speed_rpm: int
    ) -> None:
        """A line's pair, points and speed checked (no I/O)."""
        self.pair_axes(pair)
        check_integer("speed", speed_rpm, low=1)
        check_points([("start", start), ("end", end)])
        if same_point(start, end):
            raise CommandRejected("line start and end are the same point")
        self._check_none_running()

    def check_arc_move(
        self,
        pair: int,
        mode: int,
        start: tuple[float, float],
        end: tuple[float, float],
        center: tuple[float, float],
        via: tuple[float, float],
        speed_rpm: int,
    ) -> None:
        """An arc's pair, mode, points and speed checked (no I/O)."""
        self.pair_axes(pair)
        check_choice("arc mode", mode, (ARC_MODE_CENTER, ARC_MODE_THREE_POINTS))
        check_integer("speed", speed_rpm, low=1)
        check_points([("start", start), ("end", end), ("center", center), ("via", via)])
        third = center if mode == ARC_MODE_CENTER else via
        if same_point(start, end) or same_point(start, third) or same_point(end, third):
            raise CommandRejected("an arc needs three different points (manual: 三点确定圆弧)")
        if mode == ARC_MODE_THREE_POINTS and collinear(start, via, end):
            raise CommandRejected("start, via and end are on one line: no arc passes them")
        self._check_none_running()

    def line_move(
        self,
        pair: int,
        start: tuple[float, float],
        end: tuple[float, float],
        speed_rpm: int,
        *,
        confirm: bool = True,
    ) -> str:
        """Line interpolation: 40202-40211 in one FC 10, then the start coil (00102)."""
        self.check_line_move(pair, start, end, speed_rpm)
        at_start = self.device.coordinates(self.pair_motors(pair))
        # The motors first run to the start each at its own speed (40202 note 2).
        self._restore_speeds(pair)
        self.device.write_values(
            [
                ("line_pair", pair),
                ("line_start_a", float(start[0])),
                ("line_start_b", float(start[1])),
                ("line_end_a", float(end[0])),
                ("line_end_b", float(end[1])),
                ("line_speed", int(speed_rpm)),
            ]
        )
        return self._start("line", pair, at_start, confirm)

    def arc_move(
        self,
        pair: int,
        mode: int,
        start: tuple[float, float],
        end: tuple[float, float],
        center: tuple[float, float],
        via: tuple[float, float],
        counterclockwise: bool,
        speed_rpm: int,
        *,
        confirm: bool = True,
    ) -> str:
        """Arc interpolation: 40182-40201 in one FC 10, then the start coil (00100).

        Mode 0 uses start, end and centre; mode 1 start, end and the middle point ``via``.
        The point the mode does not use is written as given (the device ignores it).
        """
        self.check_arc_move(pair, mode, start, end, center, via, speed_rpm)
        at_start = self.device.coordinates(self.pair_motors(pair))
        self._restore_speeds(pair)
        self.device.write_values(
            [
                ("arc_pair", pair),
                ("arc_mode", mode),
                ("arc_start_a", float(start[0])),
                ("arc_start_b", float(start[1])),
                ("arc_end_a", float(end[0])),
                ("arc_end_b", float(end[1])),
                ("arc_center_a", float(center[0])),
                ("arc_center_b", float(center[1])),
                ("arc_via_a", float(via[0])),
                ("arc_via_b", float(via[1])),
                ("arc_direction", 1 if counterclockwise else 0),
                ("arc_speed", int(speed_rpm)),
            ]
        )
        return self._start("arc", pair, at_start, confirm)

    def _restore_speeds(self, pair: int) -> None:
        """The pair's motors (under either reading) that a jog left at its speed, unless
        still jogging, get their configured speed back before the approach runs."""
        motors = set(INTERPOLATION_PAIRS[pair]) | set(INTERPOLATION_PAIRS_POINT_ROWS[pair])
        self.device.jog_control.restore_speeds(sorted(motors))

    def stop_interpolation(self) -> str:
        """Arc stop (00101) and line stop (00103), then the stop coil of each motor the
        line / arc may move (the bridge's run's, under either reading of its pair; every
        motor a pair can name when the bridge started none), every one tried even if
        one fails; then their running flags read back until 0 (stepper decision 23: a
        controller that kept running after the interpolation stops was once reported
        stopped). Raises the first LinkError, or NotConfirmed."""
        run = self.run
        motors = list(run.motors) if run is not None else list(INTERPOLATION_MOTORS)
        error: LinkError | None = None
        for name in ("arc_stop", "line_stop"):
            try:
                self.device.send_coil(name)
            except LinkError as err:
                error = error or err
        error = self.device.send_motor_stops(motors) or error
        if error is not None:
            raise error
        wrote = ", ".join(
            f"{name.replace('_', ' ')} (coil {coil_label(coil(SYSTEM_COILS[name]))} = ON)"
            for name in ("arc_stop", "line_stop")
        )
        said = confirm_stopped(self.device, motors, f"{wrote}, {motor_coils_text(motors, 'stop')}")
        if self.run is run:
            self.run = None
        return said

    # ------------------------------------------------------------------ the run
    def pair_axes(self, pair: int) -> tuple[int, int]:
        """The pair's (first, second) motor by the configured reading (``pair_axes``)."""
        return pair_axes(pair, self.device.pair_reading)

    def pair_motors(self, pair: int) -> tuple[int, ...]:
        """The pair's motors under either reading of the type (decision 11)."""
        return tuple(
            sorted(set(INTERPOLATION_PAIRS[pair]) | set(INTERPOLATION_PAIRS_POINT_ROWS[pair]))
        )

    def _start(self, kind: str, pair: int, at_start: dict[int, float], confirm: bool) -> str:
        """The start coil; from then on (even when its reply is lost: it may have started)
        the move counts as running until a later poll shows its motors stopped. With
        ``confirm`` the start is read back (a motor of the pair runs or moved)."""
        name = f"{kind}_start"
        try:
            self.device.send_coil(name)
        finally:
            self.run = InterpolationRun(
                kind,
                self.pair_motors(pair),
                self.device.next_poll,
                pair,
                self.pair_axes(pair),
                dict(at_start),
            )
        wrote = f"{kind} start (coil {coil_label(coil(SYSTEM_COILS[name]))} = ON)"
        if not confirm:
            return f"wrote {wrote}"
        return confirm_started(self.device, sorted(at_start), wrote, at_start)

    def note_wrong_pair(self, coordinates: Sequence[float]) -> None:
        run = self.run
        if run is None or run is self._wrong_pair_run:
            return
        wrong = run.wrong_motors(coordinates)
        if wrong:
            self._wrong_pair_run = run
            self._wrong_pair = wrong_pair_text(run, wrong, coordinates, self.device.pair_reading)

    def take_wrong_pair(self) -> str | None:
        """Why the running line / arc must be stopped (a motor outside its configured pair
        moved), once; None when nothing is wrong."""
        why, self._wrong_pair = self._wrong_pair, None
        return why

    def wrong_pair_not_stopped(self) -> None:
        """The stop after ``take_wrong_pair`` failed: the next poll says so again."""
        self._wrong_pair_run = None

    def note_running(self, sequence: int, running: tuple[bool, ...]) -> None:
        run = self.run
        if (
            run is not None
            and sequence >= run.first_poll
            and not any(running[m - 1] for m in run.motors)
        ):
            self.run = None

    def _check_none_running(self) -> None:
        run = self.run
        if run is not None:
            raise CommandRejected(
                f"a {run.kind} interpolation of motors "
                f"{'+'.join(map(str, run.motors))} is running (manual: 插补过程运行中不可调节): "
                "wait for it to end or call stop_interpolation"
            )


def wrong_pair_text(
    run: InterpolationRun, wrong: Sequence[int], coordinates: Sequence[float], reading: str
) -> str:
    """One line: which motor outside the configured pair moved, and what to do."""
    where = ", ".join(
        f"motor {m} {run.start_coordinates[m]:g} -> {coordinates[m - 1]:g}" for m in wrong
    )
    expected = "+".join(map(str, run.expected))
    return (
        f"a motor outside the pair moved ({where} units): interpolation_pair_reading "
        f"{reading} names motors {expected} for pair {run.pair}, the controller follows the "
        "other reading (docs/decisions/stepper.md hardware check)"
    )


def check_pair(pair: int) -> None:
    if pair not in INTERPOLATION_PAIRS:
        raise CommandRejected(
            f"interpolation pair {pair!r} refused: 1 (motors 1+2), 2 (1+3) or 3 (2+3)"
        )


def check_points(points: Sequence[tuple[str, tuple[float, float]]]) -> None:
    for what, point in points:
        if len(point) != 2:
            raise CommandRejected(f"{what} needs 2 coordinates, got {len(point)}")
        for value in point:
            check_finite(what, value)
            encode(STEPPER_MAP["line_start_a"], float(value))  # int32 x100 range


def same_point(p: tuple[float, float], q: tuple[float, float]) -> bool:
    return all(
        round(a * DISTANCE_SCALE) == round(b * DISTANCE_SCALE) for a, b in zip(p, q, strict=True)
    )


def collinear(p: tuple[float, float], q: tuple[float, float], r: tuple[float, float]) -> bool:
    cross = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
    scale = max(1.0, *(abs(v) for v in (*p, *q, *r)))
    return abs(cross) <= 1e-9 * scale * scale
