"""The xArm's guided commissioning steps (``bridge_commission xarm``, after the
operator's ``yes``): a Blockly project runs and is stopped, or paused and resumed, each
written with the bridge's own device methods and judged by what H33 reads back (xArm
decisions 19 and 20). The step's stop, sent on every way out by the runner, is the
bridge's stop (C145 and H33 = 4 at once, read back). No ROS here. "xArm decision N" is
reading N of docs/decisions/xarm.md.
"""

from __future__ import annotations

from collections.abc import Callable

from bridge_core.runtime.commission import Finding, Probe, Verdict
from bridge_core.wire.errors import CommandRejected, DeviceException, NotConfirmed

from .arm_state import STATE_IN_MOTION, STATE_READY, ArmReading, confirm
from .commission_steps import device
from .registers import COIL_STOPPED, SET_STATE_PAUSE, SET_STATE_STOP

PROJECT = 1  # the Blockly project the steps run (as the page's checks: projects [1])
RUN_BEFORE_HALT_S = 0.5  # the project runs this long before the stop or the pause
PAUSED_S = 0.3  # a pause is held this long before the resume


def stop(probe: Probe) -> str:
    """The steps' stop: the bridge's (C145 = 1 and H33 = 4 at once, H33 read back)."""
    try:
        return device(probe).stop()
    except NotConfirmed as err:
        return f"not confirmed: {err}: stop the arm on the control box"


def _start(probe: Probe) -> Finding | None:
    """Project ``PROJECT`` started and read back in motion (decision 20), from an arm that
    stands without an error (a stopped arm made ready first by H33 = 0); None once it
    runs, else why the step does not go on."""
    arm = device(probe)
    seen = arm.read_arm()
    if seen.error_code:
        return Finding(Verdict.NOT_RUN, f"the arm shows an error, clear it first: {seen}")
    if seen.state == STATE_IN_MOTION:
        return Finding(Verdict.NOT_RUN, f"the arm moves, stop it first: {seen}")
    if seen.state not in (STATE_READY, SET_STATE_STOP):
        return Finding(Verdict.NOT_RUN, f"the arm is neither ready nor stopped: {seen}")
    try:
        if seen.state == SET_STATE_STOP:
            arm.start()
        arm.run_offline_task([PROJECT])
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused, nothing written: {err}")
    except NotConfirmed as err:
        return Finding(Verdict.UNCLEAR, f"project {PROJECT} did not start: {err}")
    if probe.wait(RUN_BEFORE_HALT_S):
        return Finding(Verdict.UNCLEAR, "stopped by the operator while the project ran")
    return None


def _coil_alone(probe: Probe) -> tuple[str, ArmReading | None]:
    """C145 = 1 alone (FC 05), H33 read back for 0.5 s: what the coil does by itself."""
    arm = device(probe)
    try:
        arm.io.write_coil(COIL_STOPPED, True)
    except DeviceException as err:
        return f"C{COIL_STOPPED} = 1 alone refused ({err}): H33 stops the arm", None
    try:
        said = confirm(arm.io, "stop", f"C{COIL_STOPPED} = 1 alone")
    except NotConfirmed as err:
        seen = arm.read_arm()
        note = f"the coil alone did not stop it ({err}): this firmware ignores C145"
        if seen.stopped and seen.state != SET_STATE_STOP:
            note += f"; C145 reads 1 while H33 reads {seen.state}: the coil is kept as written"
        return note, seen
    return f"the coil alone stopped it ({said})", None


def stop_step(probe: Probe) -> Finding:
    """Decisions 6 and 19: the project runs; C145 = 1 alone, then the bridge's stop (C145
    and H33 = 4), done only when H33 reads 4."""
    if (failed := _start(probe)) is not None:
        return failed
    coil, _ = _coil_alone(probe)
    try:
        stopped = device(probe).stop()
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"{coil}; the bridge's stop not confirmed: {err}: neither the coil nor H33 "
            "stopped it; use the control box's stop, tell us",
        )
    return Finding(Verdict.CONFIRMED, f"{coil}; the bridge's stop: {stopped}")


def pause_step(probe: Probe) -> Finding:
    """Decisions 6, 19, 20: the project runs; the bridge's pause (C144 and H33 = 3) read
    back, then its resume (H33 = 0) read back in motion, and C144 must read 0 again: the
    pause coil reads the arm, not the value last written."""
    if (failed := _start(probe)) is not None:
        return failed
    arm = device(probe)
    try:
        paused = arm.pause()
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"the pause not confirmed: {err}: this firmware's pause reads otherwise; tell us",
        )
    if probe.wait(PAUSED_S):
        return Finding(Verdict.UNCLEAR, f"stopped by the operator while paused ({paused})")
    try:
        resumed = arm.resume()
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"pause: {paused}; the resume not confirmed: {err} (C144 kept at 1 holds the "
            "arm: this firmware needs C144 = 0 to resume); tell us",
        )
    seen = arm.read_arm()
    said = f"pause: {paused}; resume: {resumed}"
    if seen.paused and seen.state != SET_STATE_PAUSE:
        return Finding(
            Verdict.CONTRADICTED,
            f"{said}; then C144 reads 1 while H33 reads {seen.state}: the coils keep the "
            "value last written, not the arm's state (~/state's `paused` and `stopped` "
            "show the last write; the bridge takes only H33 as proof, decision 19); tell us",
        )
    return Finding(Verdict.CONFIRMED, f"{said}; C144 reads {int(seen.paused)} after it")


def _refused(probe: Probe, what: str, start: Callable[[], str]) -> str | None:
    """A start on an arm in error: None when the bridge says "not confirmed" and H33
    reads 4 (stopped), else what shows that the arm took it."""
    try:
        said = start()
    except NotConfirmed:
        seen = device(probe).read_arm()
        if seen.state == SET_STATE_STOP:
            return None
        return f"{what}: not confirmed, but the arm reads {seen}"
    return f"{what}: done while the error shows ({said})"


def start_in_error(probe: Probe) -> Finding:
    """Decision 20: on an arm that shows an error, the bridge's resume (H33 = 0) and its
    offline task (project ``PROJECT``) are each not confirmed, and H33 stays 4."""
    arm = device(probe)
    seen = arm.read_arm()
    if not seen.error_code:
        return Finding(
            Verdict.NOT_RUN,
            "no error shows: press the control box's emergency stop, release it, leave the "
            f"error, and run this again ({seen})",
        )
    if seen.state != SET_STATE_STOP:
        return Finding(Verdict.NOT_RUN, f"the arm shows an error but is not stopped: {seen}")
    starts: tuple[tuple[str, Callable[[], str]], ...] = (
        ("resume", arm.resume),
        (f"project {PROJECT}", lambda: arm.run_offline_task([PROJECT])),
    )
    for what, start in starts:  # the first one taken ends the step (and its stop goes out)
        if (took := _refused(probe, what, start)) is not None:
            return Finding(
                Verdict.CONTRADICTED,
                f"{took}: this firmware takes a start in error (the state is not 4), so "
                "decision 20's check cannot tell an arm that refused it; tell us",
            )
    return Finding(
        Verdict.CONFIRMED,
        f"error {seen.error_code}: the resume and project {PROJECT} both not confirmed, H33 "
        "reads 4 (stopped) after each",
    )


SAFETY_MODES = ("set_reduced_mode", "set_fence_mode")  # the device methods, as the services


def safety_modes(probe: Probe) -> Finding:
    """Decision 17: on an arm that stands, each safety mode switched on with the bridge's
    method (the coil read back), off refused without ``confirm``, then back off with it
    when it was off; a change the coil does not read back is the controller's refusal."""
    arm = device(probe)
    seen = arm.read_arm()
    if seen.state == STATE_IN_MOTION:
        return Finding(Verdict.NOT_RUN, f"the arm moves, stop it first: {seen}")
    before = arm.read_named("reduced_mode", "fence_mode")
    said: list[str] = []
    for name, was in zip(SAFETY_MODES, before.values(), strict=True):
        switch: Callable[..., str] = getattr(arm, name)
        try:
            said.append(f"{name} on: {switch(True)}")
            try:
                switch(False)
            except CommandRejected as err:
                said.append(f"off without confirm refused ({err})")
            else:
                return Finding(Verdict.CONTRADICTED, f"{name} off without confirm went out")
            if not was:
                said.append(f"off with confirm: {switch(False, name)}")
        except NotConfirmed as err:
            return Finding(
                Verdict.CONTRADICTED,
                f"{'; '.join(said)}; {name}: not confirmed: {err}: the controller refused "
                "the change in its current state, and the mode is as it read; tell us",
            )
        if probe.stop_requested():
            return Finding(Verdict.UNCLEAR, f"stopped by the operator: {'; '.join(said)}")
    return Finding(Verdict.CONFIRMED, "; ".join(said))
