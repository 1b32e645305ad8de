"""The xArm's hardware checks as data: ``bridge_commission xarm`` runs them and
``docs/decisions/xarm.md``'s "Hardware checks" list is rendered from them
(``bridge_commission --write-docs xarm``; tests/docs/test_commission_pages.py fails when
the page and these rows differ). Read-only checks run first, then the guided steps, each
after the operator's ``yes``; the manual ones are for a person at the arm. The reads are
in commission_steps.py, the guided steps in commission_guided.py. "xArm decision N" is
reading N of docs/decisions/xarm.md.
"""

from __future__ import annotations

from bridge_core.runtime.commission import Check, Commissioning, Guided

from . import commission_guided as guided
from . import commission_steps as steps
from .registers import ORIENTATION_MISMATCH_DEG, XARM_MAP

CONTROL_BOX = "the control box's emergency stop"
STOP_STEP = Guided(
    moves=f"Blockly project {guided.PROJECT} as stored on the controller (FC 10 at 0x30, read "
    f"back in motion; a stopped arm is made ready first with H33 = 0) for "
    f"{guided.RUN_BEFORE_HALT_S:g} s, then C145 = 1 alone, H33 read back for 0.5 s, then "
    "the bridge's stop (C145 and H33 = 4): up to a second of the project's motion",
    stop_how=CONTROL_BOX,
    run=guided.stop_step,
    send_stop=guided.stop,
)
PAUSE_STEP = Guided(
    moves=f"Blockly project {guided.PROJECT} (as above) for {guided.RUN_BEFORE_HALT_S:g} s, "
    f"the bridge's pause (C144 and H33 = 3) held {guided.PAUSED_S:g} s, its resume (H33 = "
    "0), then its stop: under a second of the project's motion and a pause",
    stop_how=CONTROL_BOX,
    run=guided.pause_step,
    send_stop=guided.stop,
)
START_IN_ERROR_STEP = Guided(
    moves="only on an arm that shows an error and stands in state 4: the bridge's resume "
    f"(H33 = 0) and then project {guided.PROJECT} (FC 10 at 0x30), each read back for 0.5 s; "
    "an arm that takes one moves until the bridge's stop that follows",
    stop_how=CONTROL_BOX,
    run=guided.start_in_error,
    send_stop=guided.stop,
)
SAFETY_MODES_STEP = Guided(
    moves="nothing moves (the arm must stand): reduced mode (C142) and then fence mode "
    "(C143) switched on with the bridge's services' methods and read back, off refused "
    "without `confirm`, and switched off with it when it was off; a step cut short leaves "
    "a mode on (the safe side); then the bridge's stop, so the arm reads state 4",
    stop_how=CONTROL_BOX,
    run=guided.safety_modes,
    send_stop=guided.stop,
)

CHECKS = (
    Check(
        "signed_values",
        "Scaled values are signed 16-bit",
        (4,),
        (
            "Every signed input row of the joints the arm has and the valid channels (joint "
            "angles, speeds and temperatures, TCP pose and speed, rx/ry/rz, offsets, load, "
            "analog inputs), decoded as the manual's signed 16-bit x10 / x1000. Expected: "
            "every value plausible (angles within "
            f"±{steps.PLAUSIBLE['deg']:g}°, positions within "
            f"±{steps.PLAUSIBLE['mm'] / 1000:g} m, analog inputs within "
            f"±{steps.PLAUSIBLE['V']:g} V, temperatures within "
            f"±{steps.PLAUSIBLE['degC']:g} °C), and a negative one read as such (unsigned, "
            "a word of 0x8000 or more is beyond every bound). Fails if a value is beyond its "
            "bound: this firmware sends these rows another way (unsigned, another scale, "
            "float32), and the pose and joints the bridge publishes are wrong; tell us. "
            "Every value 0 or more settles nothing: move a joint to a negative angle and run "
            "it again."
        ),
        read=steps.signed_values,
    ),
    Check(
        "counter_word_order",
        "The counter I34-35 is high word first",
        (4,),
        (
            'The counter ("0x22 存储计数器的高16位") as the row scan read it and once more '
            "after. Expected: if it moved, the second word (I35) changed; if it stands, the "
            "first word is 0 (a count below 65536 read high word first; low word first it "
            "is 65536 times larger). Fails if the first word counts, or only the second is "
            "0: `counter` in `~/state` is wrong on this firmware; tell us. Both words 0, "
            "or both nonzero and standing, settle nothing: run a project that counts."
        ),
        read=steps.counter_word_order,
    ),
    Check(
        "joints",
        "The joint temperatures are at I96-102, one per joint: `joint_count`",
        (1, 11),
        (
            "The seven temperature rows I96-102 (the hex column of the manual's "
            '"86 ~ 102 | 0x60~0x66"). Expected: the joints the arm has read '
            f"{steps.TEMPERATURE_PLAUSIBLE_C[0]}-{steps.TEMPERATURE_PLAUSIBLE_C[1]} °C, the "
            "rows past them 0 (as the simulator takes it, decision 16; the manual says "
            "nothing of arms with fewer joints), so the count of joints is the last row "
            "that is not 0: the report recommends it as `joint_count`. Fails if a joint "
            "reads a temperature beyond the range (these rows hold something else on this "
            "firmware: tell us) or the count is not `joint_count` (set it to the arm's; "
            "the controller does not report its joint count, so check the recommendation "
            "against the arm's label). All 0 settles nothing."
        ),
        read=steps.joints,
    ),
    Check(
        "reserved_rows",
        "Reserved rows are refused",
        (2,),
        (
            "The first address of every gap between the map's rows, read alone: holding "
            "11 and 34, input 11 and 36 (the reserved 36-63), coils 40 and 160. Expected: "
            "each refused with exception 0x02, as the bridge plans its reads (never one "
            "across a gap). Addresses that answer are harmless (the bridge's reads stay as "
            "they are), but the manual's table does not hold on this firmware: tell us."
        ),
        read=steps.reserved_rows,
    ),
    Check(
        "rotation_vector",
        "rx/ry/rz and roll/pitch/yaw describe one orientation",
        (13,),
        (
            "Roll/pitch/yaw (I67-69) as `~/tcp_pose` reads them (about the fixed axes) and "
            "the rotation vector rx/ry/rz (I70-72). Expected: the two orientations within "
            f"{ORIENTATION_MISMATCH_DEG:g}° (the node's diagnostics WARN above it). Fails if "
            "they differ: roll/pitch/yaw follow another convention on this firmware (the "
            "report says whether the moving axes match), so `~/tcp_pose`'s orientation is "
            "wrong; use `tcp_rotation_vector` of `~/state`, and tell us. An orientation "
            "with at most one of roll, pitch, yaw off 0 and 180 reads alike either way and "
            "settles nothing: turn the tool and run it again."
        ),
        read=steps.rotation_vector,
    ),
    Check(
        "stop",
        "C145 and H33 stop the arm; H33 shows it",
        (6, 19),
        (
            "Run a Blockly project (`ros2 service call /xarm/xarm_bridge/run_offline_task "
            'msg_defs/srv/RunOfflineTask "{projects: [1]}"`), then `ros2 service call '
            '/xarm/xarm_bridge/stop std_srvs/srv/Trigger "{}"`. Expected: the arm stops at '
            'once, `success: true`, message "stop: done (wrote C145 = 1 and H33 = 4; reads mode '
            '0 (position), state 4 (stopped), error 0, C144 paused 0, C145 stopped 1)". Then '
            "`ros2 topic echo --once /xarm/xarm_bridge/state` a few seconds later: `state: 4`, "
            "and `stopped` as the coil reads. A failing result: the arm keeps moving, or "
            '`success: false` with "not confirmed: … reads … state 1 (in motion)" (neither the '
            "coil nor H33 stopped it: use the pendant's stop and tell us); \"C145 = 1 (refused: "
            '…)" means this firmware answers the coil with an exception (H33 stopped it). To '
            "tell which of the two writes stops the arm: write only the coil from a Modbus "
            "client (`05 0091 FF00`) while a project runs and read H33 (`03 0021 0001`): 4 "
            "means the coil works; 1 and the arm moving means this firmware ignores C145 (the "
            "bridge's H33 stops it); C145 reading 1 while H33 reads 1 means the coil is kept as "
            "written (why decision 19 takes only H33 as proof)."
        ),
        guided=STOP_STEP,
    ),
    Check(
        "pause",
        "C144 and H33 pause it",
        (6, 19),
        (
            "As above with `ros2 service call /xarm/xarm_bridge/pause std_srvs/srv/Trigger "
            '"{}"`. Expected: the arm halts, "wrote C144 = 1 and H33 = 3; reads … state 3 '
            '(paused) …"; then `ros2 service call /xarm/xarm_bridge/resume std_srvs/srv/Trigger '
            '"{}"` continues the project from where it halted ("wrote H33 = 0; reads … state 1 '
            '(in motion)"). A failing result: the pause answers `success: false` "… state 2 '
            "(sleeping)\" while the project was moving (this firmware's pause reads 2: tell us), "
            'or the resume answers "not confirmed … state 3 (paused), … C144 paused 1" (C144 '
            "kept at 1 holds the arm: this firmware needs C144 = 0 to resume; tell us). After "
            "the resume C144 reads 0 again; 1 while H33 reads 1 means the coils keep the value "
            "last written, not the arm's state (`paused` and `stopped` in `~/state` then show "
            "the last write; the bridge takes only H33 as proof): tell us."
        ),
        guided=PAUSE_STEP,
    ),
    Check(
        "start_in_error",
        "A start on an arm in error is refused and said so",
        (20,),
        (
            "Press the control box's emergency stop, release it, and do not clear the error; "
            'then `ros2 service call /xarm/xarm_bridge/resume std_srvs/srv/Trigger "{}"`. '
            'Expected: `success: false`, "resume: not confirmed: wrote H33 = 0; reads … state 4 '
            '(stopped), error 1 (…)" (or the error code the box shows), and the arm does not '
            'move. The same for `run_offline_task` ("not confirmed: wrote projects 1 at H48 '
            '…"). After clearing the error (UFACTORY Studio) `resume` answers done with state '
            "2. A failing result: done while the error shows in `~/state` (the firmware reports "
            "a state other than 4 in error: tell us), or `run_offline_task` of a project that "
            'moves the arm for seconds answers "not confirmed … state 2" (this firmware does '
            "not show a running project as state 1: tell us, the check of decision 20 is then "
            "wrong for tasks)."
        ),
        guided=START_IN_ERROR_STEP,
    ),
    Check(
        "safety_modes",
        "Safety modes off need a confirmation",
        (17,),
        (
            "`ros2 service call /xarm/xarm_bridge/set_reduced_mode msg_defs/srv/SetSafetyMode "
            '"{data: true}"` gives "C142 reads 1" and `~/state` shows `reduced_mode: true`; '
            "`ros2 service call /xarm/xarm_bridge/set_reduced_mode msg_defs/srv/SetSafetyMode "
            '"{data: false}"` is refused ("send confirm: \'set_reduced_mode\'") and the mode '
            "stays on; `ros2 service call /xarm/xarm_bridge/set_reduced_mode "
            'msg_defs/srv/SetSafetyMode "{data: false, confirm: set_reduced_mode}"` gives "C142 '
            'reads 0". The same for `set_fence_mode` and C143. Fails if a call answers '
            '`success: false`, "not confirmed: C142: wrote 1, reads 0" (or wrote 0, reads 1): '
            "the controller refused the change in its current state, and the mode is as it "
            "read; or if the reply and `~/state` agree but the pendant shows the other mode: "
            "the coil is kept without effect on this firmware; tell us either way."
        ),
        guided=SAFETY_MODES_STEP,
    ),
)

COMMISSIONING = Commissioning(
    bridge="xarm",
    node="xarm_bridge",
    register_map=XARM_MAP,
    checks=CHECKS,
    ping=steps.ping,
    requests_per_poll=steps.requests_per_poll,
    setup=steps.setup,
    refusal_reason=steps.refusal_reason,
)
