"""The R6's hardware checks as data: ``bridge_commission r6`` runs them and
``docs/decisions/r6.md``'s "Hardware checks" list is rendered from them
(``bridge_commission --write-docs r6``; tests/docs/test_commission_pages.py fails when the
page and these rows differ). Read-only checks run first, then the guided steps, each
after the operator's ``yes``; the manual ones are for a person with the pendant. The
steps themselves are in commission_steps.py. "R6 decision N" is reading N of
docs/decisions/r6.md.
"""

from __future__ import annotations

from bridge_core.runtime.commission import Check, Commissioning, Guided

from . import commission_steps as steps
from .registers import R6_MAP

PENDANT = "the pendant's stop (or its e-stop)"
CYCLE_TIME_2401 = Guided(
    moves="one single cycle (20002) of the loaded program from the step it is at, at the "
    "global speed the controller shows, a second if the first leaves 2401 unchanged; the "
    "tool follows each as a `run_cycle` goal and reads 2401 on every poll",
    stop_how=PENDANT + "; the tool then sends pause (20001)",
    run=steps.cycle_time_2401,
    send_stop=steps.pause,
)
STOP_SHOWS_IN_2470 = Guided(
    moves="the program runs (start 20003, checked and read back as `~/start`) for "
    f"{steps.RUN_BEFORE_PAUSE_S:g} s, then pause (20001), read back as `~/pause`",
    stop_how=PENDANT,
    run=steps.stop_shows_in_2470,
    send_stop=steps.pause,
)

CHECKS = (
    Check(
        "word_order",
        "32-bit values are high word first",
        (1,),
        (
            "Every 32/64-bit row that reads nonzero (axis positions, world X to W, the "
            "cycle times) decoded both ways. Expected: high word first gives plausible "
            f"values (positions and U, V, W within ±{steps.POSITION_PLAUSIBLE_DEG:g}°, X, Y, "
            f"Z within ±{steps.WORLD_PLAUSIBLE_MM / 1000:g} m, cycle times under a day), low "
            "word first absurd ones. Fails if only low word first is plausible: every "
            "position, pose and cycle time the bridge publishes is wrong on this controller; "
            "do not run it, and tell us. All zero settles nothing: move the arm off its "
            "origin and run it again."
        ),
        read=steps.word_order,
    ),
    Check(
        "counts",
        "Only the axes and IO boards in use answer",
        (8,),
        (
            "The axis count (2267) and IO board count (2186), then every axis position and "
            "board row, each read alone. Expected: the counts within 0-8 and 0-5, the rows of "
            "the axes and boards in use answered, the rows past them refused (exception "
            "0x02), as the bridge plans its poll. Fails if a row in use is refused (every "
            "poll fails: tell us the counts); rows past the counts that answer are harmless "
            "(the bridge reads only the rows in use), but tell us."
        ),
        read=steps.counts,
    ),
    Check(
        "undefined_rows",
        "Registers outside the map are refused",
        (11,),
        (
            "The first register of every gap between the map's rows, the rows the host does "
            "not offer among them (65-129, 2472-2537, 20059-20071, 22130-22131), read alone. "
            "Expected: each refused with exception 0x02, as the bridge plans its reads (never "
            "one across a gap). Registers that answer are harmless (the bridge's reads stay "
            "as they are), but the manual's notes do not hold on this controller: tell us."
        ),
        read=steps.undefined_rows,
    ),
    Check(
        "m_boards",
        "The M boards' rows answer or not: `m_boards`",
        (21,),
        (
            "The M boards' rows (2197-2202, 2237-2242) and coils (160-255). Answered: the "
            "controller offers M values, and the report recommends `m_boards: true`; refused "
            '(the handheld network-port version, "手控网口版本暂时不支持"): `m_boards: false`. '
            "Either way the reading holds (off by default, a parameter turns them on); some "
            "answered and some refused: tell us."
        ),
        read=steps.m_boards,
    ),
    Check(
        "cycle_time_2401",
        "When 2401 is written, and only a finished cycle proves it",
        (23,),
        (
            "With a program of a few seconds in auto mode, beside `ros2 topic echo "
            "/r6/r6_bridge/state --field last_cycle_time_ms`: `ros2 action send_goal --feedback "
            '/r6/r6_bridge/run_cycle msg_defs/action/RunCycle "{single_cycle: true}"`. Expected: '
            "`last_cycle_time_ms` keeps its value while the arm moves and changes when it stops; "
            'the goal SUCCEEDED, "the cycle ended (last cycle N ms, was M ms)", N close to the '
            "cycle's duration. Send it again and press stop on the pendant half-way. Expected: "
            'ABORTED, outcome STOPPED, "could not prove the cycle finished: moving ended but the '
            'last cycle time did not change … the program stopped or finished". Fails if '
            '`last_cycle_time_ms` changes as the arm starts (and the goal ends STOPPED, "2401 '
            "changed while the cycle ran … writes it at a cycle's start\"): this controller writes "
            "2401 at a cycle's start, and `run_cycle` can never prove a single cycle on it (every "
            'goal ends STOPPED, "could not prove"); watch the arm instead, and tell us. Fails too '
            'if the goal ends STOPPED "did not change" after a cycle that finished (2401 not '
            "written at all). A REACHED after a pendant stop would be a failure of the bridge: "
            "2401 changed although the cycle did not finish; it can only come from a controller "
            "that writes 2401 on a stop, and says the arm may stand mid-program; tell us at once."
        ),
        guided=CYCLE_TIME_2401,
    ),
    Check(
        "waiting_step",
        "The cycle time counts through a step that waits",
        (23,),
        (
            "Give the program a step that waits 3 s for a timer or an input, then `ros2 topic "
            "echo /r6/r6_bridge/state --field current_cycle_time_ms` beside `ros2 topic echo "
            "/r6/r6_bridge/state --field moving` while a single-cycle goal runs. Expected: "
            "`current_cycle_time_ms` keeps rising while `moving` is false, and the goal goes on "
            "(no STOPPED during the wait). Fails if `current_cycle_time_ms` stands still during "
            'the wait: the goal then ends ABORTED, STOPPED, "moving ended but the last cycle time '
            'did not change" while the program goes on, so `run_cycle` cannot follow a program '
            "with waiting steps on this controller; tell us."
        ),
    ),
    Check(
        "pause_keeps_step",
        "Pause keeps the step, stop starts over",
        (17, 23),
        (
            "Start `ros2 action send_goal /r6/r6_bridge/run_cycle msg_defs/action/RunCycle "
            '"{single_cycle: false}"` (real device only: a continuous run ends only when stopped, '
            "here by you), press Ctrl-C in the middle of the second step (the bridge sends pause "
            '20001), then `ros2 service call /r6/r6_bridge/start std_srvs/srv/Trigger "{}"`. '
            "Expected: the arm continues the second step, and `current_cycle_time_ms` continues "
            "from where it was. Fails if the arm goes back to the first step or "
            "`current_cycle_time_ms` starts again from 0: pause 20001 acts as a stop on this "
            "controller, and every goal end the bridge causes (cancel, timeout, link loss) "
            "restarts the program from step 1; tell us."
        ),
    ),
    Check(
        "starts_outside_auto",
        "Starts outside auto mode are refused",
        (23,),
        (
            "Switch the pendant to manual, then `ros2 service call /r6/r6_bridge/start "
            'std_srvs/srv/Trigger "{}"`. Expected: `success: false`, "the controller is in manual '
            'mode (2185 = 1), not auto", and the arm does not move. The same with an axis whose '
            'origin is not set: "not homed (2471 = 0)". Fails if the reply is `success: true` '
            "(the arm may move: stop it on the pendant) or names another 2185 value: this "
            "controller does not report manual as 2185 = 1 (decision 2), or not-homed as 2471 = "
            "0, so the bridge cannot tell; tell us what `~/state` shows in `mode` and `homed`."
        ),
    ),
    Check(
        "clear_alarm_and_next",
        "clear_alarm_and_next needs its flag",
        (23,),
        (
            "With an alarm active, `ros2 service call /r6/r6_bridge/clear_alarm_and_next "
            'msg_defs/srv/ClearAlarmAndNext "{skip_failed_step: false}"`. Expected: refused, the '
            "alarm stays. With `skip_failed_step: true` the alarm clears and the program "
            "continues with the instruction after the one that raised it. Fails if, with `true`, "
            "the same `alarm_code` returns at once (20005 retried the failed instruction, as "
            "20006 does) or `moving` stays false with the alarm cleared (20005 only clears the "
            "code): decision 18's reading of 20005 is wrong on this controller; tell us which."
        ),
    ),
    Check(
        "masked_board_write",
        "A masked board write keeps the program's outputs",
        (24,),
        (
            "Let the program switch output 0 of board 0 on, then `ros2 service call "
            '/r6/r6_bridge/set_board_outputs msg_defs/srv/SetOutputBoard "{board: 0, bits: 4, '
            'mask: 4}"`. Expected: the reply "read 0x…1, wrote 0x…5", and `ros2 topic echo --once '
            "/r6/r6_bridge/state --field io_board_outputs` shows bits 0 and 2 set. Fails if the "
            "reply reads 0x…0 although output 0 is on, or bit 0 is off afterwards (or the output "
            "that switched on is not output 2): the board's word does not read back as it is "
            "written (decision 19's bit numbering), and a partial mask switches the program's "
            "outputs off; do not use partial masks on this controller and tell us."
        ),
    ),
    Check(
        "writes_read_back",
        "Boards past the count, unknown counters, parameter writes",
        (24,),
        (
            "With 2186 = 1: `ros2 service call /r6/r6_bridge/set_output msg_defs/srv/SetOutput "
            '"{board: 2, index: 0, state: true}"` gives "IO board 2 is not in use"; `ros2 service '
            'call /r6/r6_bridge/set_counter msg_defs/srv/SetCounter "{id: 4000000000, value: 1}"` '
            'gives "counter 4000000000 is not one the controller lists (…)"; `ros2 service call '
            '/r6/r6_bridge/write_parameter msg_defs/srv/WriteParameter "{index: 10, value: 5}"` '
            'on a parameter the program may change gives "parameter 10 reads 5". A controller '
            'that acknowledges a write it does not apply shows as "not confirmed: parameter 10: '
            'wrote 5, reads …".'
        ),
    ),
    Check(
        "clear_frame",
        "A clear frame with a count of 0 empties a data source",
        (25,),
        (
            "Upload 200 points: `ros2 action send_goal --feedback /r6/r6_bridge/upload_points "
            'msg_defs/action/PointUpload "{data_source_id: 9, values_per_point: 6, axis_mask: 63, '
            'values: [...]}"` (real device only: fill in your 1200 values) and press Ctrl-C after '
            'a few frames. Expected: the result says "source 9 cleared" and `ros2 service call '
            '/r6/r6_bridge/read_data_source msg_defs/srv/ReadDataSource "{source_id: 9}"` answers '
            "`points: 0`. Nonzero points: this controller ignores a 0-count clear; do not run the "
            "program on that source until it is uploaded whole."
        ),
    ),
    Check(
        "stop_shows_in_2470",
        "A stop shows in 2470 within 1 s",
        (29,),
        (
            "While a continuous program runs at 100 % global speed, `ros2 service call "
            '/r6/r6_bridge/pause std_srvs/srv/Trigger "{}"`. Expected: `success: true`, "… read '
            'moving (2470) 0, current cycle time (2397) N ms, not counting: the program stands", '
            'the arm still. The same for `stop` and `stop_button`, and `start` answers "… the '
            'program runs". Fails if the arm stops but the reply is "not confirmed … read moving '
            '(2470) 1": this controller takes longer than `HALT_CONFIRM_S` to clear 2470 (or '
            "never clears it while the program is loaded); tell us the time the arm takes to "
            "stand. Fails badly if the reply is `success: true` while the arm still moves: 2470 "
            "does not follow the motion; stop on the pendant and tell us."
        ),
        guided=STOP_SHOWS_IN_2470,
    ),
    Check(
        "pose_and_joints",
        "Pose and joints are read one request apart",
        (26,),
        (
            "While the arm moves, `ros2 topic echo /r6/r6_bridge/tcp_pose --field header.stamp` "
            "next to `ros2 topic echo /r6/joint_states --field header.stamp`. Expected: the "
            "pose's stamp a few milliseconds (one transaction) before the joints' of the same "
            "poll, never more than one poll period apart. Fails if the pose's stamp is after the "
            "joints' or tens of milliseconds before them: pose and joints no longer come one "
            "request apart, and a moving arm's pose does not match its joints; tell us, with the "
            "transaction latency `/diagnostics` shows."
        ),
    ),
)

COMMISSIONING = Commissioning(
    bridge="r6",
    node="r6_bridge",
    register_map=R6_MAP,
    checks=CHECKS,
    ping=steps.ping,
    requests_per_poll=steps.requests_per_poll,
    setup=steps.setup,
    refusal_reason=steps.refusal_reason,
)
