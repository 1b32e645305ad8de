"""The stepper's hardware checks as data: ``bridge_commission stepper`` runs them and
``docs/decisions/stepper.md``'s "Hardware checks" list is rendered from them
(``bridge_commission --write-docs stepper``; tests/docs/test_commission_pages.py fails when
the page and these rows differ). Read-only checks run first, then the guided steps, each
after the operator's ``yes``; the manual ones are for a person with ``ros2`` (and a second
controller or a logic analyser). The read-only checks are in commission_steps.py, the
guided steps in commission_guided.py.
"Stepper decision N" is reading N of docs/decisions/stepper.md.
"""

from __future__ import annotations

from bridge_core.runtime.commission import Check, Commissioning, Guided

from . import commission_guided as guided
from . import commission_steps as steps
from .registers import STEPPER_MAP

CONTROLLER_STOP = "the controller's e-stop"
PAIR_LINE = Guided(
    moves="every motor's coordinate set to 0 (coil 00044), then a line of pair "
    f"{guided.PAIR_TRIED} from (0, 0) to ({guided.LINE_END_UNITS[0]:g}, "
    f"{guided.LINE_END_UNITS[1]:g}) units at {guided.LINE_RPM} rpm, followed as a `line_move` "
    "goal under `type_rows`: motors 1 and 3 (or 2 and 3 on a controller that follows the "
    "point rows, stopped at the first poll that shows motor 2 moved)",
    stop_how=CONTROLLER_STOP + "; the tool then sends the arc and line stops and the stop "
    "coils of motors 1-3",
    run=guided.pair_reading,
    send_stop=guided.stop_interpolation,
)
HOME_MOTOR_1 = Guided(
    moves=f"motor {guided.HOME_MOTOR} runs {guided.HOME_OFF_UNITS:g} units forward (a single "
    "run, as `move_by`), then homes (its home coil, as the `home` goal) in reverse until its "
    "home input, at its configured speed",
    stop_how=CONTROLLER_STOP + f"; the tool then sends motor {guided.HOME_MOTOR}'s stop coil",
    run=guided.zero_at_home,
    send_stop=guided.stop_motor_1,
)
FORWARD_THEN_STOP = Guided(
    moves=f"motor {guided.HOME_MOTOR} forward at its configured speed (read back as "
    f"`~/motor_1/forward`) for {guided.RUN_BEFORE_STOP_S:g} s, then its stop coil (read back as "
    "`~/motor_1/stop`); the line part of the check stays manual",
    stop_how=CONTROLLER_STOP,
    run=guided.stop_and_start,
    send_stop=guided.stop_motor_1,
)

CHECKS = (
    Check(
        "word_order",
        "32-bit values are low word first",
        (1,),
        (
            "The baud rate (40213-40214), a 32-bit value whose every setting the manual lists "
            "(4800, 9600, 19200, 38400), decoded both ways, the leads (40007+) listed beside "
            "it. Expected: low word first (the note under the manual's §6 examples) gives one "
            "of them, high word first an absurd value. Fails if only high word first gives "
            "one: every lead, run distance, coordinate and interpolation point the bridge reads "
            "and writes is wrong on this controller; do not run it, and tell us."
        ),
        read=steps.word_order,
    ),
    Check(
        "pair_reading",
        "Which motors interpolation pairs 2 and 3 drive: `interpolation_pair_reading`",
        (19,),
        (
            "Start the bridge with `interpolation_pair_reading:=type_rows`, zero the "
            "coordinates (`ros2 service call /stepper/stepper_bridge/zero_coordinates "
            "std_srvs/srv/Trigger`), then run a 2 x 4 mm line of pair 2 from where the motors "
            "stand: `ros2 action send_goal /stepper/stepper_bridge/line_move "
            'msg_defs/action/LineMotion "{pair: 2, start: [0.0, 0.0], end: [0.002, 0.004], '
            'speed_rpm: 30, timeout_s: 30.0}"` (real device only: the demo runs with pairs 2 '
            "and 3 refused). A controller that follows the type rows ends SUCCEEDED with "
            '"motors moved: 1+3 (coordinates read back)": keep `type_rows`. One that follows '
            'the point rows moves motor 2: the goal ends ABORTED, HALTED, "a motor outside the '
            'pair moved (motor 2 0 -> … units)", and the stop coils are sent: restart with '
            "`interpolation_pair_reading:=point_rows` and run the same goal again (it must end "
            'SUCCEEDED with "motors moved: 2+3"). Until then pairs 2 and 3 are refused. The '
            "tool recommends the reading the line showed (`type_rows` when it ends on its "
            "target with motors 1+3, `point_rows` when motor 2 moved); any other end says "
            "nothing and recommends nothing."
        ),
        guided=PAIR_LINE,
    ),
    Check(
        "zero_at_home",
        "Whether homing zeroes the coordinate, and that home is the reverse limit input: "
        "`zero_after_home`",
        (20,),
        (
            "Check the wiring first: `ros2 topic echo --once /stepper/stepper_bridge/state "
            "--field negative_limit_input` and `--field home_input` (the manual wires both to "
            "one input). Move motor 1 off home (`ros2 action send_goal "
            "/stepper/stepper_bridge/motor_1/move_by msg_defs/action/StepperMoveBy "
            '"{distance: 0.005, timeout_s: 30.0}"`), then home it: `ros2 action send_goal '
            "/stepper/stepper_bridge/motor_1/home msg_defs/action/StepperRun "
            '"{timeout_s: 60.0}"`. You should see SUCCEEDED with "home input on (motor 1 IN2 '
            'on at coordinate X)". X = 0: the controller zeroes at home, leave '
            "`zero_after_home` false. X ≠ 0: it does not; if your sequences need 0 at home, "
            "set `zero_after_home:=true` (it zeroes every motor's coordinate) and repeat: the "
            'result must end "coordinates zeroed (coil 00044 …)". An ABORTED STOPPED "home '
            'input IN2 off" means the motor stopped elsewhere: check the input assignment '
            "(`~/motor_1/set_limit_inputs`). The tool recommends `zero_after_home: false` "
            "when the coordinate reads 0 at home and `true` when it does not (the safe "
            "reading for sequences that start from 0; set it back to false if yours do not)."
        ),
        guided=HOME_MOTOR_1,
    ),
    Check(
        "reply_rule",
        "Which reading of the 35 ms rule the controller follows, and the reply timeout floor",
        (7,),
        (
            "Start the bridge at the line's baud rate with `timeout_s:=` the floor (0.15 at "
            "9600, 0.26 at 4800, 0.10 at 19200, 0.07 at 38400) and watch `ros2 topic echo "
            '/diagnostics --field status` for a minute: "transaction latency max (ms)" should '
            "stay below the floor (at 9600 baud each request of a poll shows ~50-80 ms: 35 ms "
            'or more of reply delay plus the frames) and "timeouts" at 0. Timeouts that stop '
            "with `frame_gap_s:=0.035` mean the controller wants 35 ms of silence before each "
            "request (the other reading): keep that setting. The tool times "
            f"{steps.REPLY_PINGS} one-register reads: the median within the floor at the "
            "`baudrate` given confirms the reading; a median above it is contradicted (the "
            "controller answers later than the floor allows for: a single slow reply is "
            "taken as the host's or the line's, not the controller's); a lost reply says "
            "nothing (the other reading, or a timeout_s too short: it says which settings to "
            "try). `timeout_s` is recommended as 3 x the slowest reply, never below the floor."
        ),
        read=steps.reply_rule,
    ),
    Check(
        "undefined_rows",
        "The undefined rows are refused",
        (7, 21),
        (
            "Every undefined range of the map (40051-40080, 40096-40107, 40118-40123, "
            "40137-40147, 40160-40167, 40173-40176, 40215-40299), read whole (at most 49 "
            "registers a read), each alone. Expected: each refused with exception 0x02, as the "
            "bridge plans its reads (never one across them). A range that answers is harmless "
            "(the bridge never reads it), but the manual's table does not hold on this "
            "controller: tell us. Those between the poll's blocks (40118-40123, 40137-40147, "
            "40160-40167) answering would let a poll read the coordinates and inputs, or the "
            "inputs, outputs and running flags, in one request (decision 21): the report says "
            "so."
        ),
        read=steps.undefined_rows,
    ),
    Check(
        "unit_ids",
        "Unit ids above 247",
        (17,),
        (
            '`stepper_bus --ros-args -p "unit_ids:=[250]"` must exit 2 with one line, "unit id '
            '250 outside 1-247". A controller whose 40212 reads 248-255 cannot be addressed by '
            "any Modbus RTU master: set it to 1-247 with the vendor tool. Fails if "
            "`stepper_bus` starts a `stepper_250` node or exits with a traceback instead of "
            "that line: tell us."
        ),
    ),
    Check(
        "shared_line_stop",
        "How long a stop waits on a shared line",
        (18,),
        (
            "With two controllers wired and one of them unpowered, start `stepper_bus` with "
            "both ids, jog a motor of the powered one (`ros2 service call "
            "/stepper_1/motor_1/forward std_srvs/srv/Trigger`, names per your namespace) and "
            "stop it (`time ros2 service call /stepper_1/motor_1/stop std_srvs/srv/Trigger`) "
            "ten times: the motor should stop within `timeout_s` plus about 0.05 s of the "
            "call each time (a stop that meets a probe of the unpowered controller waits it "
            "out, decision 18; one that does not, within about a quarter second; the CLI's own "
            "start-up adds its time to `time`'s figure; a logic analyser on the A/B pair shows "
            "the stop frame at most `timeout_s` + ≈ 0.02 s after the previous request at 9600 "
            "baud). Fails if a stop takes longer than that, or the motor runs on: tell us. To "
            "shorten the worst case, set `timeout_s` to what the slowest controller needs and "
            "keep `reconnect_max_s` long."
        ),
    ),
    Check(
        "stop_and_start",
        "A stop shows in the running flag within 0.5 s, and a start within 0.5 s",
        (23,),
        (
            "Run motor 1 forward at 60 rpm (`ros2 service call "
            "/stepper/stepper_bridge/motor_1/forward std_srvs/srv/Trigger`): the reply must be "
            '`success: true`, "…; read motor 1 running (40168) = 1". Then stop it (`ros2 '
            "service call /stepper/stepper_bridge/motor_1/stop std_srvs/srv/Trigger`): "
            '`success: true`, "…; read motor 1 running (40168) = 0". Repeat at the highest '
            'speed you use. A failing result is `success: false` with "not confirmed: … '
            'running (40168) = 1 0.5 s after" while the motor did stop: the controller '
            "decelerates (or sets the flag) slower than 0.5 s, so `STOP_CONFIRM_S` in "
            '`stepper_bridge/confirm.py` must grow to the time you see; "not confirmed" on '
            "the forward call while the motor runs means the flag comes later than 0.5 s "
            "(`START_CONFIRM_S`). Then start a pair-1 line with `ros2 service call "
            "/stepper/stepper_bridge/line_move msg_defs/srv/LineMove "
            '"{pair: 1, start: [0.0, 0.0], end: [0.05, 0.05], speed_rpm: 30}"` and stop it '
            "with `~/stop_interpolation`: `success: true` and the flags of motors 1 and 2 read "
            "0; a line that keeps moving after the reply is a failing result (report it: the "
            "motors' stop coils did not stop it either)."
        ),
        guided=FORWARD_THEN_STOP,
    ),
)

COMMISSIONING = Commissioning(
    bridge="stepper",
    node="stepper_bridge",
    register_map=STEPPER_MAP,
    checks=CHECKS,
    ping=steps.ping,
    requests_per_poll=steps.requests_per_poll,
    setup=steps.setup,
)
