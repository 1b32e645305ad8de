"""Action servers of the bridge nodes: motions that take time (docs/actions.md).

Part of the node base (imports rclpy). ``ActionHost`` puts ``bridge_core.runtime.goals`` behind
``rclpy.action.ActionServer``s with the rules every bridge action follows:

- **Rejected, nothing written**, under the service guards: node not active, ``read_only``,
  link down, or a goal the device layer refuses (out of range, unknown motor). A goal
  response carries no text in ROS 2, so the reason is a WARN on the console (and
  ``/rosout``): ``<action> goal rejected: <reason>``. A check that needs the device's
  state (e.g. the MOTEC drive's mode) runs when the goal starts: the goal is then aborted
  with outcome REFUSED and the reason, still having written nothing.
- **One goal per axis**: a new goal on an axis a running goal occupies preempts it; the
  old one is stopped (outcome PREEMPTED) before the new one writes anything.
- **Cancel = stop**: a cancel is always accepted; the goal's thread sends the motion's
  stop (tried on the wire even while the link is marked down) and the result says
  whether it was acknowledged. A timeout (``timeout_s`` > 0) and a link lost during the
  goal end it the same way; deactivate, exit and ``read_only`` stop it from the node's
  ``stop_motion`` (outcome HALTED).
- **Feedback** once per poll begun after the start was acknowledged; the result when the
  polls show the motion over (``Motion.judge``).

Goals run on executor threads of their own callback group (a goal's thread sleeps between
polls); the start is a command like a service's (the node's command guard), stops are
stops (``run_command(stop=True)``).
"""

from __future__ import annotations

import math
import threading
import time
import traceback
from collections.abc import Callable, Hashable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from rclpy.action.server import ActionServer, CancelResponse, GoalResponse, ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup

from ..runtime.checks import bounded_text
from ..runtime.goals import GoalRun, Motion, Outcome, Verdict, needs_stop
from ..runtime.parameters import GOAL_TIMEOUT_DEFAULT_S, GOAL_TIMEOUT_SPEC
from ..wire.errors import CommandRejected, LinkError
from .action_results import filled, finish_run, refuse_goal, result_of, send_result
from .node_services import Row, bound_rows, interface_type

if TYPE_CHECKING:
    from .node_base import BridgeNode

MadeT = TypeVar("MadeT")  # what an action's goal makes: a Motion, or Steps

# How long a new goal waits for the goal it preempts to have sent its stop. The stop is
# one transaction (bounded by the link's timeout); past this, the new goal is refused.
PREEMPT_WAIT_S = 5.0
# How long a goal's thread waits for another thread that ended the goal (``stop_motion``
# on deactivate / exit) to have sent its stop (one try, bounded by the link's timeout)
# before it reports the result anyway; and how long ``stop_all`` waits for a goal whose
# start was under way to have ended.
STOP_WAIT_S = 30.0
# Executor threads a node adds for its running goals: one per action server, at most this
# many, and one for a preempting goal (goals on one axis preempt each other, so few run at
# once).
MAX_GOAL_THREADS = 8


class Steps(Protocol):
    """A goal done in steps by the bridge itself (R6 point upload): each ``step`` is one
    command of its own; a cancel or timeout ends it between two steps."""

    what: str
    axes: frozenset[Hashable]
    total: int
    sent: int

    def step(self) -> None: ...
    def abandon(self) -> str: ...
    def feedback(self) -> dict[str, Any]: ...
    def result(self) -> dict[str, Any]: ...


class ActionHost:
    """The action servers of one bridge node and the goals they run."""

    def __init__(self, node: BridgeNode[Any]) -> None:
        self.node = node
        self.group = ReentrantCallbackGroup()
        self.servers: list[ActionServer] = []
        self._lock = threading.Lock()
        self._runs: dict[bytes, GoalRun[Any]] = {}  # goal id -> its run, while running
        self._steps: dict[bytes, StepsRun] = {}
        self.goal_timeout_s = GOAL_TIMEOUT_DEFAULT_S  # the node's parameter, once declared

    def _declare_goal_timeout(self) -> None:
        """``goal_timeout_s``, with the first action server (a node without actions has
        no such parameter: it would do nothing)."""
        if self.servers:
            return
        value = self.node.declare_specs([GOAL_TIMEOUT_SPEC])["goal_timeout_s"]
        self.goal_timeout_s = float(value)
        self.node.on_parameter("goal_timeout_s", self._set_goal_timeout)

    def _set_goal_timeout(self, value: float) -> None:
        self.goal_timeout_s = float(value)

    # ------------------------------------------------------------------ servers
    def create(
        self,
        rows: Sequence[Row],
        makers: Mapping[str, Callable[..., Any]],
        expansion: Mapping[str, Sequence[object]] | None = None,
    ) -> None:
        """An action server per name of each ``Action`` row of ``<bridge>/interface.py``
        (``expansion``: each placeholder's values), of the row's type: its goal makes a
        ``Motion`` the polls follow, or ``Steps`` the bridge carries out, through the maker
        its row's name has in ``makers`` (a pattern's: a function of its placeholders that
        returns the maker). Rows and makers must match (``node_services.bound_rows``)."""
        for row, name, make in bound_rows(rows, makers, expansion or {}):
            self.add(interface_type(row.type), name, make)

    def add(self, action_type: Any, name: str, make: Callable[[Any], Motion[Any] | Steps]) -> None:
        """An action whose goal starts a motion or steps (``goal.timeout_s``)."""

        def run(handle: ServerGoalHandle, made: Motion[Any] | Steps) -> Any:
            if isinstance(made, Motion):
                return self._execute_motion(action_type, name, made, handle)
            return self._execute_steps(action_type, name, made, handle)

        self._server(action_type, name, make, run)

    def _guarded(
        self, action_type: Any, name: str, handle: ServerGoalHandle, execute: Callable[[], Any]
    ) -> Any:
        """A bug in a goal's thread: every motion stopped, the goal aborted with the error
        (never an empty result), the traceback on the console."""
        try:
            return execute()
        except Exception as err:
            self.node.get_logger().error(f"{name} failed: {err}\n{traceback.format_exc()}")
            self.node.stop_motion(f"{name} failed: internal error")
            if handle.is_active:
                handle.abort()
            message = f"{name} failed: internal error: {err}"
            return result_of(action_type, Verdict(Outcome.HALTED, message), message)

    def _server(
        self,
        action_type: Any,
        name: str,
        make: Callable[[Any], MadeT],
        run: Callable[[ServerGoalHandle, MadeT], Any],
    ) -> None:
        """The action server: goals refused by the node's state and ``make`` (its checks,
        nothing written); an accepted goal's motion or steps made again in its thread and
        ``run`` there, guarded (``_guarded``)."""
        self._declare_goal_timeout()

        def start(handle: ServerGoalHandle) -> Any:
            try:
                made = make(handle.request)
            except CommandRejected as err:  # the device's state changed since the goal came
                return refuse_goal(self.node, action_type, handle, f"{name} refused: {err}")
            return run(handle, made)

        def execute(handle: ServerGoalHandle) -> Any:
            return self._guarded(action_type, name, handle, lambda: start(handle))

        def goal_callback(goal: Any) -> GoalResponse:
            reason = self._refusal(goal, make)
            if reason is None:
                return GoalResponse.ACCEPT
            self.node.get_logger().warn(f"{name} goal rejected: {reason}")
            return GoalResponse.REJECT

        self.servers.append(
            ActionServer(
                self.node,
                action_type,
                name,
                execute,
                callback_group=self.group,
                goal_callback=goal_callback,
                cancel_callback=self._cancel,
            )
        )

    def _refusal(self, goal: Any, check: Callable[[Any], object]) -> str | None:
        """Why a goal is rejected before anything is written (None: accepted)."""
        node = self.node
        if not node.active:
            return "the node is not active (lifecycle)"
        if node.read_only:
            return "read_only is set, nothing was written"
        if not node.channel.connected:
            return f"not connected to {node.channel.describe()}"
        with self._lock:
            goals = len(self._runs) + len(self._steps)
        if goals >= self.threads:
            return f"{goals} goals already run or wait on this node, the most it takes at once"
        timeout_s = float(getattr(goal, "timeout_s", 0.0))
        if not math.isfinite(timeout_s) or timeout_s < 0:
            return (
                f"timeout_s {timeout_s} must be 0 (the node's goal_timeout_s) or a positive "
                "number of seconds"
            )
        try:
            check(goal)
        except CommandRejected as err:
            return bounded_text(str(err))
        return None

    def _cancel(self, handle: ServerGoalHandle) -> CancelResponse:
        key = bytes(handle.goal_id.uuid)
        with self._lock:
            run = self._runs.get(key)
            steps = self._steps.get(key)
        if run is not None:
            run.cancel()
        if steps is not None:
            steps.end(Outcome.CANCELLED, f"{steps.steps.what}: cancelled")
        return CancelResponse.ACCEPT

    # ------------------------------------------------------------------ motions
    def _execute_motion(
        self,
        action_type: Any,
        name: str,
        motion: Motion[Any],
        handle: ServerGoalHandle,
    ) -> Any:
        goal = handle.request
        key = bytes(handle.goal_id.uuid)
        timeout_s = float(goal.timeout_s) or motion.default_timeout_s(self.goal_timeout_s)
        run: GoalRun[Any] = GoalRun(motion, timeout_s=timeout_s)
        run.thread = threading.current_thread()
        if reason := self._take_axes(key, run):
            return refuse_goal(self.node, action_type, handle, reason)
        try:
            self._start(run, handle, name)
            self._follow(run, handle, action_type)
        except Exception:
            # A bug in this goal's thread: its own motion is stopped before anything else.
            verdict = Verdict(Outcome.HALTED, f"{motion.what}: stopped, internal error")
            if run.claim(verdict):
                if run.started_at is not None:
                    self._end(run, verdict)
                else:
                    run.finish()
            raise
        finally:
            with self._lock:
                self._runs.pop(key, None)
        return finish_run(
            self.node, run, handle, action_type, name, motion.result(run.last_snapshot)
        )

    def _start(self, run: GoalRun[Any], handle: ServerGoalHandle, name: str) -> None:
        """Write the motion's start unless the goal ended first; a start the link lost
        half-way may have started the motion: it is stopped (LINK_LOST)."""
        node = self.node
        motion = run.motion
        if handle.is_cancel_requested:
            run.cancel()
        if (ending := run.requested_ending()) is not None:  # before anything was written
            if run.claim(ending):
                run.finish()
            return

        link_failed = threading.Event()

        def start_unless_ended() -> None:
            # Its turn may come after a cancel, a halt or a newer goal: then nothing goes out.
            if (ending := run.requested_ending()) is not None:
                raise CommandRejected(ending.message)
            run.starting = True
            try:
                motion.start()
            except LinkError:
                link_failed.set()  # part of the start may have gone out
                raise

        ok, message, _ = node.run_command(motion.what, start_unless_ended)
        if ok:
            run.started(time.monotonic())
            node.get_logger().info(f"{name}: goal started ({motion.what})")
        elif not run.starting:  # refused before its first write: nothing to stop
            if run.claim(run.requested_ending() or Verdict(Outcome.REFUSED, message)):
                run.finish()
        elif link_failed.is_set() or not node.channel.connected:
            run.started(time.monotonic())  # the start may have gone out: stop it
            if run.claim(Verdict(Outcome.LINK_LOST, message)):
                self._end(run, Verdict(Outcome.LINK_LOST, message))
        elif run.claim(Verdict(Outcome.REFUSED, message)):
            run.finish()

    def _take_axes(self, key: bytes, run: GoalRun[Any]) -> str | None:
        """Register ``run``; preempt and wait out the goals on its axes."""
        with self._lock:
            older = [old for old in self._runs.values() if old.motion.axes & run.motion.axes]
            self._runs[key] = run
        for old in older:
            old.preempt(run.motion.what)
        for old in older:
            if not old.done.wait(PREEMPT_WAIT_S):
                with self._lock:
                    self._runs.pop(key, None)
                return (
                    f"{run.motion.what} refused: the goal it preempts ({old.motion.what}) "
                    f"did not stop within {PREEMPT_WAIT_S:g} s"
                )
        return None

    def _follow(self, run: GoalRun[Any], handle: ServerGoalHandle, action_type: Any) -> None:
        """The goal's thread: feedback per fresh snapshot until something ends the goal."""
        node = self.node
        while not run.ended:
            run.wake.wait(run.wait_s())
            run.wake.clear()
            snapshot = run.take_snapshot()
            if run.ended:
                break
            verdict = run.next_ending(node.channel.connected, snapshot)
            if snapshot is not None:  # every poll's, the one that ends the goal too
                handle.publish_feedback(
                    filled(action_type.Feedback(), run.motion.feedback(snapshot))
                )
            if verdict is None:
                continue
            if run.claim(verdict):
                self._end(run, verdict)
                return
        # Ended by another thread (stop_motion): its stop may still be on the wire.
        run.done.wait(STOP_WAIT_S)

    def _end(self, run: GoalRun[Any], verdict: Verdict) -> None:
        """Send the stop the outcome needs (one try, even while the link is down)."""
        if not needs_stop(verdict.outcome):
            run.finish()
            return
        node = self.node
        ok, message, result = node.run_command(
            f"{run.motion.what}: stop", run.motion.stop, stop=True, own_motion=True
        )
        run.finish(ok, str(result or "stop sent") if ok else message)
        if not ok:
            node.get_logger().error(f"{verdict.message}; {message}")

    def stop_all(self, reason: str) -> None:
        """Stop every running goal's motion now (deactivate, exit, read_only)."""
        with self._lock:
            runs = list(self._runs.values())
            steps = list(self._steps.values())
        for run in runs:
            run.halt(reason)  # a goal not started yet never starts; its thread ends it
            verdict = Verdict(Outcome.HALTED, f"{run.motion.what}: stopped, {reason}")
            if run.started_at is not None and run.claim(verdict):
                self._end(run, verdict)
                self.node.get_logger().info(f"{run.motion.what}: stopped ({reason})")
        for steps_run in steps:
            steps_run.end(Outcome.HALTED, f"{steps_run.steps.what}: stopped, {reason}")
        # A start that was on the wire when the halt came: its thread stops it at once;
        # wait for that (the link must still be open), bounded by STOP_WAIT_S. Not for a
        # goal still waiting for its turn (it will not start), nor on a goal's own thread.
        deadline = time.monotonic() + STOP_WAIT_S
        for run in runs:
            if run.starting and run.thread is not threading.current_thread():
                run.done.wait(max(0.0, deadline - time.monotonic()))

    def offer(self, snapshot: Any, poll_started: float) -> None:
        """A published snapshot (the poller's publisher thread)."""
        with self._lock:
            runs = list(self._runs.values())
        for run in runs:
            run.offer(snapshot, poll_started)

    def wake_all(self) -> None:
        """The link changed: let every goal look at it now."""
        with self._lock:
            runs = list(self._runs.values())
        for run in runs:
            run.wake.set()

    def occupied(self, axis: Hashable) -> str | None:
        """The running goal that occupies ``axis`` (None: no goal does), for services that
        must not write between its steps."""
        with self._lock:
            for run in self._runs.values():
                if axis in run.motion.axes:
                    return run.motion.what
            for steps_run in self._steps.values():
                if axis in steps_run.steps.axes:
                    return steps_run.steps.what
        return None

    @property
    def threads(self) -> int:
        """Executor threads for goals: one per server (at most MAX_GOAL_THREADS) and one
        for a goal that waits for the one it preempts; a goal past them is rejected, so
        goals never take the threads of the stop services."""
        if not self.servers:
            return 0
        return min(len(self.servers), MAX_GOAL_THREADS) + 1

    @property
    def running(self) -> list[str]:
        with self._lock:
            return [run.motion.what for run in self._runs.values()]

    # ------------------------------------------------------------------ steps
    def _execute_steps(
        self,
        action_type: Any,
        name: str,
        steps: Steps,
        handle: ServerGoalHandle,
    ) -> Any:
        goal = handle.request
        key = bytes(handle.goal_id.uuid)
        run = StepsRun(steps, float(goal.timeout_s) or self.goal_timeout_s)
        with self._lock:
            older = [old for old in self._steps.values() if old.steps.axes & steps.axes]
            self._steps[key] = run
        for old in older:
            old.end(Outcome.PREEMPTED, f"{old.steps.what}: preempted by {steps.what}")
        for old in older:
            if not old.done.wait(PREEMPT_WAIT_S):
                with self._lock:
                    self._steps.pop(key, None)
                return refuse_goal(
                    self.node,
                    action_type,
                    handle,
                    f"{steps.what} refused: the goal it preempts ({old.steps.what}) did not "
                    f"end within {PREEMPT_WAIT_S:g} s",
                )
        undo = ""
        try:
            while steps.sent < steps.total:
                if handle.is_cancel_requested:
                    run.end(Outcome.CANCELLED, f"{steps.what}: cancelled")
                elif time.monotonic() >= run.deadline:
                    run.end(Outcome.TIMED_OUT, f"{steps.what}: not done within {run.timeout_s:g} s")
                if run.verdict is not None:
                    break
                ok, message, _ = self.node.run_command(steps.what, steps.step)
                if not ok:
                    outcome = Outcome.REFUSED if steps.sent == 0 else Outcome.STOPPED
                    if not self.node.channel.connected:
                        outcome = Outcome.LINK_LOST
                    run.end(outcome, message)
                    break
                handle.publish_feedback(filled(action_type.Feedback(), steps.feedback()))
            run.end(Outcome.REACHED, f"{steps.what}: done")
            ended = run.verdict
            if ended is not None and ended.outcome is not Outcome.REACHED and steps.sent:
                # Undo the part that went out, before the axis is free (a goal that
                # preempted this one waits for it); tried even while the link is down,
                # like a stop. If that fails too, the result says what stays.
                ok, said, undone = self.node.run_command(
                    f"{steps.what}: undo", steps.abandon, stop=True, own_motion=True
                )
                undo = f"; {undone}" if ok else f"; {said}"
        finally:
            with self._lock:
                self._steps.pop(key, None)
            run.done.set()
        verdict = run.verdict or Verdict(Outcome.REACHED, f"{steps.what}: done")
        message = f"{verdict.message} ({steps.sent} of {steps.total} sent){undo}"
        return send_result(
            self.node, action_type, handle, name, verdict, message, False, steps.result()
        )


class StepsRun:
    """One goal of a steps action: the first ending set wins (thread-safe)."""

    def __init__(self, steps: Steps, timeout_s: float) -> None:
        self.steps = steps
        self.timeout_s = timeout_s
        self.deadline = time.monotonic() + timeout_s if timeout_s else math.inf
        self.verdict: Verdict | None = None
        self.done = threading.Event()
        self._lock = threading.Lock()

    def end(self, outcome: Outcome, message: str) -> None:
        with self._lock:
            if self.verdict is None:
                self.verdict = Verdict(outcome, message)


__all__ = ["PREEMPT_WAIT_S", "STOP_WAIT_S", "ActionHost", "Steps", "StepsRun"]
