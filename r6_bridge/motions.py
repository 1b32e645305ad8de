"""The R6 bridge's action goals: ``~/run_cycle`` (``RunCycleMotion``).

No ROS here: the node's action server runs the motion (bridge_core.runtime.goals). The
``~/upload_points`` action's steps are in upload.py. "R6 decision N" is reading N of
docs/decisions/r6.md.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any

from bridge_core.runtime.goals import Motion, Outcome, Verdict
from bridge_core.wire.errors import CommandRejected

from .device import R6Device, R6Snapshot
from .program import MODE_AUTO, PROGRAM, check_program_command
from .registers import COMMANDS

# When this controller writes 2401 (R6 decision 23): seen by a run_cycle goal, None
# until one has seen it (every reconnect forgets it: the controller may differ).
CYCLE_TIME_AT_END = "end"
CYCLE_TIME_AT_START = "start"


class RunCycleMotion(Motion[R6Snapshot]):
    """``~/run_cycle``: single cycle (20002) or start (20003), followed through ``moving``
    (2470). Checked twice: against the last poll when the goal comes (rejected), and
    against rows read just before the command (REFUSED): auto mode, homed, no alarm, a
    global speed above 0. An alarm (2396) ends it as FAULT. A single cycle is REACHED
    only when the controller showed it running and then standing, and the last cycle
    time (2401, "上模周期") proves the cycle finished under either reading of when the
    controller writes it (R6 decision 23): it kept its value read before the start on
    every poll that saw the cycle running and changed after, to a time no shorter than
    the cycle was seen to run. A poll "saw the cycle running" when 2401 was read only if
    ``moving`` (read after it) or the next poll's counting says so, and the change proves
    an end only after a poll read 2401 unchanged while 2397 counted (or on a controller
    seen to write it at the end). A cycle no poll saw running is REACHED only on a
    controller seen (by an earlier goal) to write 2401 at a cycle's end. A goal sent while
    the program already ran is never REACHED (the cycle that ends began before it).
    Otherwise its end is STOPPED, and so is a continuous run's (it runs until stopped).
    Ends this goal causes (cancel, timeout, link loss, the node's halts) send pause
    (20001), which keeps the program's step, confirmed like ``~/pause`` (decision 29).
    Both kinds take the node's ``goal_timeout_s`` when the goal gives ``timeout_s`` 0, a
    continuous run too: a goal whose client vanished must not keep the robot cycling
    (decision 27)."""

    axes: frozenset[Hashable] = frozenset({PROGRAM})
    confirm_reached = True  # the result's last cycle time is read apart from `moving`

    def __init__(self, device: R6Device, last: R6Snapshot | None, *, single_cycle: bool) -> None:
        super().__init__()
        if last is not None:
            if last.mode != MODE_AUTO:
                raise CommandRejected(
                    f"the controller is in {last.mode_name} mode, not auto: switch to auto "
                    "on the pendant first"
                )
            if not last.homed:
                raise CommandRejected("the controller is not homed (2471 = 0)")
            if last.alarm_code:
                raise CommandRejected(
                    f"alarm {last.alarm_code} is active and blocks the program: clear it first"
                )
            if last.global_speed_percent <= 0:
                raise CommandRejected(
                    "the global speed is 0 %: the program would not move (set_global_speed)"
                )
        self.device = device
        self.single_cycle = single_cycle
        self.command = "single_cycle" if single_cycle else "start"
        self.what = f"run_cycle ({'single cycle' if single_cycle else 'continuous'})"
        self.stops_at_start = device.stops
        self.last_cycle_at_start: int | None = None
        self.cycle_ms: int | None = None  # the current cycle time of the previous poll
        # The current cycle time of the poll before the goal (a program counting since).
        self.cycle_ms_before = None if last is None else last.current_cycle_time_ms
        self.running_before = False  # the program ran when the start was written
        self.changed_while_running: int | None = None  # 2401 as a running poll read it
        # 2401 changed in the previous poll, which only counting (2397, read before 2401)
        # showed running: proved read while the cycle ran if this poll still counts.
        self.changed_if_counting: int | None = None
        self.unchanged_while_running = False  # a running poll read 2401 as before
        self.longest_ms = 0  # the longest current cycle time a running poll read

    def start(self) -> None:
        ready = check_program_command(self.device.io, self.command)
        if ready.global_speed_percent <= 0:
            raise CommandRejected(
                "the global speed is 0 %: the program would not move (set_global_speed)"
            )
        self.last_cycle_at_start = ready.last_cycle_time_ms
        self.running_before = ready.moving or (
            self.cycle_ms_before is not None and ready.current_cycle_time_ms > self.cycle_ms_before
        )
        self.stops_at_start = self.device.stops
        self.device.command(self.command)

    def stop(self) -> str:
        said = self.device.halt("pause")
        return f"pause (20001) sent: the program keeps its step ({said})"

    def running(self, snapshot: R6Snapshot) -> bool:
        """``moving``, or the current cycle time still counting: a program that waits in a
        step (a dwell, an input) may show ``moving`` 0 while its cycle goes on."""
        previous, self.cycle_ms = self.cycle_ms, snapshot.current_cycle_time_ms
        counting = previous is not None and snapshot.current_cycle_time_ms > previous
        running = snapshot.moving or counting
        changed_before, self.changed_if_counting = self.changed_if_counting, None
        if running:
            self.longest_ms = max(self.longest_ms, snapshot.current_cycle_time_ms)
            if counting and changed_before is not None:
                self._changed_while_running(changed_before)
            if snapshot.last_cycle_time_ms != self.last_cycle_at_start:
                # A poll reads 2397, then 2401, then 2470 (r6_bridge.device's plan): a
                # cycle that ends between the first two reads counting and a new 2401,
                # which an end-writer shows too. Only ``moving`` (read after 2401), or
                # the next poll still counting, shows the cycle ran on after 2401's read.
                if snapshot.moving:
                    self._changed_while_running(snapshot.last_cycle_time_ms)
                else:
                    self.changed_if_counting = snapshot.last_cycle_time_ms
            elif snapshot.current_cycle_time_ms > 0:
                self.unchanged_while_running = True
        return running

    def _changed_while_running(self, last_cycle_ms: int) -> None:
        if self.changed_while_running is None:
            self.changed_while_running = last_cycle_ms

    def fault(self, snapshot: R6Snapshot) -> Verdict | None:
        code = snapshot.alarm_code
        if not code:
            return None
        return Verdict(Outcome.FAULT, f"{self.what}: alarm {code}", code, f"alarm code {code}")

    def ended(self, snapshot: R6Snapshot) -> Verdict:
        last, before = snapshot.last_cycle_time_ms, self.last_cycle_at_start
        unproven = f"{self.what}: could not prove the cycle finished"
        if self.device.stops > self.stops_at_start:
            return Verdict(Outcome.STOPPED, f"{self.what}: stopped by a stop or pause command")
        read = (
            f"read moving (2470) {int(snapshot.moving)}, current cycle time (2397) "
            f"{snapshot.current_cycle_time_ms} ms, last cycle time (2401) {last} ms (was "
            f"{before} ms)"
        )
        if not self.seen_running and last == before:
            return Verdict(
                Outcome.STOPPED,
                f"{self.what}: the controller acknowledged the start but never showed moving "
                f"(2470): the cycle did not run (wrote {COMMANDS[self.command]} = 1 "
                f"({self.command}); {read})",
            )
        # Paused keeps the cycle's time (20001 resumes at the step), stopped resets it.
        how = (
            f"paused (current cycle time kept at {snapshot.current_cycle_time_ms} ms)"
            if snapshot.current_cycle_time_ms
            else "stopped or finished (current cycle time back to 0)"
        )
        if not self.single_cycle:
            return Verdict(Outcome.STOPPED, f"{self.what}: the program {how}")
        if self.running_before:
            return Verdict(
                Outcome.STOPPED,
                f"{unproven}: the program was already running when the goal came, so the "
                f"cycle that ended began before it ({read})",
            )
        if not self.seen_running:
            # A cycle shorter than a poll (or polls held up on a loaded host) can begin
            # and end between two polls. 2401 changed: at this cycle's end, or at its
            # start (a cycle stopped half-way reads the same); only a controller seen to
            # write 2401 at a cycle's end proves it finished (decision 23).
            if self.device.cycle_time_written_at == CYCLE_TIME_AT_END:
                return Verdict(
                    Outcome.REACHED,
                    f"{self.what}: the cycle ended between two polls (last cycle {last} ms, "
                    f"was {before} ms; no poll saw it moving; this controller writes 2401 "
                    "at a cycle's end)",
                )
            return Verdict(
                Outcome.STOPPED,
                f"{unproven}: no poll saw it running and 2401 changed, which a cycle "
                "stopped half-way does too on a controller that writes 2401 at a cycle's "
                f"start; not yet seen which this one does ({read})",
            )
        if self.changed_while_running is not None:
            self.device.cycle_time_written_at = CYCLE_TIME_AT_START
            return Verdict(
                Outcome.STOPPED,
                f"{unproven}: 2401 changed while the cycle ran (read "
                f"{self.changed_while_running} ms, was {before} ms): this controller writes "
                f"it at a cycle's start, so it cannot show this cycle's end ({read})",
            )
        if last == before:
            return Verdict(
                Outcome.STOPPED,
                f"{unproven}: moving ended but the last cycle time did not change "
                f"({last} ms): the program {how}; a cycle exactly as long as the last one "
                "reads the same as a stop from another client, the pendant or the program",
            )
        if last < self.longest_ms:
            return Verdict(
                Outcome.STOPPED,
                f"{unproven}: 2401 reads {last} ms, shorter than the {self.longest_ms} ms "
                f"the cycle was seen to run ({read})",
            )
        if (
            not self.unchanged_while_running
            and self.device.cycle_time_written_at != CYCLE_TIME_AT_END
        ):
            # No poll read 2401 while 2397 counted: its change may be this cycle's start
            # on a controller that writes it then (a poll that read 2401 just before the
            # start and ``moving`` just after, then a stop), so it proves no end.
            return Verdict(
                Outcome.STOPPED,
                f"{unproven}: 2401 changed, but no poll read it while the cycle counted "
                f"(2397 above 0), so it may have been written as the cycle began ({read})",
            )
        if self.unchanged_while_running:
            self.device.cycle_time_written_at = CYCLE_TIME_AT_END
        return Verdict(
            Outcome.REACHED,
            f"{self.what}: the cycle ended (last cycle {last} ms, was {before} ms)",
        )

    def feedback(self, snapshot: R6Snapshot) -> dict[str, Any]:
        return {
            "moving": snapshot.moving,
            "current_cycle_time_ms": snapshot.current_cycle_time_ms,
            "alarm_code": snapshot.alarm_code,
        }

    def result(self, snapshot: R6Snapshot | None) -> dict[str, Any]:
        return {"last_cycle_time_ms": 0 if snapshot is None else snapshot.last_cycle_time_ms}
