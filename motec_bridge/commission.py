"""The MOTEC hardware checks as data: every item of docs/decisions/motec.md's "Hardware
checks" (rendered from these rows: ``bridge_commission --write-docs motec``) and what
``bridge_commission motec`` does for each (read-only: commission_steps.py; guided:
commission_guided.py; manual: the prose only). No ROS here.

The tool commissions one drive of the bus: the bus node's and a drive node's parameters
are taken together (``COMMISSION_NODE``), the drive is the tool's ``--unit-id`` (default:
the first of ``unit_ids``), and the params file it writes is for every node of the process
(``PARAMS_NODE``: the block ``/**/*``, as config/motec.yaml's ``/**``).
"""

from __future__ import annotations

from bridge_core.runtime.commission import Check, Commissioning, Guided
from bridge_core.runtime.interface import NodeInterface, nodes

from . import commission_guided as guided
from . import commission_steps as steps
from .registers import MOTEC_MAP

CHECKS = (
    Check(
        "word_order",
        "32-bit counts are high word first",
        (2,),
        "Every 32-bit count that reads nonzero (the target 0x26, the setpoint 0xAA, the "
        "position 0xAC) decoded both ways. Expected: high word first gives plausible counts "
        "(within 10000 motor turns of `counts_per_rev`), low word first absurd ones. Fails "
        "if only low word first is plausible: every position, target and fault code the "
        "bridge reads or writes is wrong on this drive; do not run it, and tell us. All zero "
        "settles nothing: turn the shaft a few turns by hand while the drive is released, "
        "and run it again.",
        read=steps.word_order,
    ),
    Check(
        "unnamed_rows",
        "The poll may read through unnamed parameters",
        (3,),
        "The unnamed parameters 0x2A-0x2C and 0xC7 read alone, then every request of the "
        "bridge's poll (each reads through them). Expected: all answer (the table is "
        "contiguous, §2.7). Refused ones are harmless (the bridge reads without them from "
        "the first refusal on, logged once, with more requests per poll), but tell us.",
        read=steps.unnamed_rows,
    ),
    Check(
        "lifeguard_settings",
        "The drive's own lifeguard setting: `lifeguard_ms`",
        (9,),
        "0x112 and 0x114 as the drive holds them. The bridge takes the drive as armed "
        "unless 0x112 reads 0 and feeds it either way. Expected: 0 (off: the report "
        "recommends `lifeguard_ms` 1000, or the bus's floor if higher) or a time the bus "
        "can keep fed (the report keeps it). A drive armed by its own setting with a time "
        "shorter than the bus's floor would trip under a running bridge: the report "
        "recommends the floor. A drive armed in network mode trips while the tool only "
        "reads (nothing moves: it releases the motor); power-cycle it after.",
        read=steps.lifeguard_settings,
    ),
    Check(
        "table_end",
        "A number past the parameter table answers exception 02",
        (13,),
        "From Pr.276 (the last parameter the manual names) up to Pr.65535, single reads "
        "find where the table ends. Expected: Pr.65535 answers `ILLEGAL DATA ADDRESS` "
        "(exception 02) and the report names the last parameter that answers (the "
        "simulator's table ends after Pr.276). Fails if Pr.65535 answers: the drive answers "
        "numbers past its table, so `~/read_parameter` of a number the vendor tool does not "
        "show gives a value, not an error; trust only the numbers the vendor tool shows.",
        read=steps.table_end,
    ),
    Check(
        "position_stop",
        "0x29 = 0 stops a position move",
        (5, 18),
        "Start a long move, `ros2 service call /motec/motec_1/move msg_defs/srv/PositionMove "
        '"{position: 300.0, relative: true, max_velocity: 20.0}"`, then within a second `ros2 '
        "service call /motec/motec_1/stop std_srvs/srv/Trigger`. Expected: the reply says "
        "`move stopped (0x29 = 0; 0xAA ... 0xAF <speed> -> <lower> rpm)` and the motor ramps "
        "down while still enabled. If it says `0x29 = 0 did not stop the move (...): drive "
        "released (0x28 = 0, reads 0)`, the drive takes 0x29 as a start trigger only: every "
        "position stop of the bridge then releases the motor (it coasts), so report it and do "
        "not use `~/move` on a load that must be held.",
        guided=Guided(
            moves=f"network mode and position control (0x24 = 0, 0x25 = 2), enable (0x28 = 1), "
            f"then a relative move of {guided.MOVE_TURNS} motor turns at "
            f"{guided.MOVE_SPEED_RPM} rpm, stopped with 0x29 = 0 after "
            f"{guided.RUN_BEFORE_STOP_S:g} s and watched until it stands (released if it does "
            "not); released again after if it was released before",
            stop_how="the drive's enable input or its power",
            run=guided.position_stop,
            send_stop=guided.stop_and_restore,
        ),
    ),
    Check(
        "setpoint_in_a_move",
        "What 0xAA shows during a move, and a stop ramps into the band within 2 s",
        (22,),
        "Start a long move as in the check above and, while it runs, `ros2 topic echo "
        "/motec/motec_1/state --field position_setpoint` next to `--field position_actual` "
        "for two seconds. Expected (the simulator's reading): 0xAA advances with 0xAC. A 0xAA "
        "that holds the target (constant while 0xAC advances) is the other reading: the "
        "bridge does not rely on either, so it is a fact to report, not a failure. Then `ros2 "
        "service call /motec/motec_1/stop std_srvs/srv/Trigger`. Expected: success, `move "
        "stopped (0x29 = 0; 0xAC ... 0xAF <speed> -> <0..3> rpm ...)`. A failing result reads "
        "`0x29 = 0 did not stop the move (... 0xAF <speed> -> <about the same> rpm ...): "
        "drive released` (the drive does not take 0x29 = 0 as a stop: see the check above), "
        "or `not confirmed standing` after a release (the motor coasts longer than 2 s: a "
        "load with much inertia; report the figure), or `read 0x28 = 1` (the drive ignored "
        "the release: stop using the bridge on it and report it).",
        guided=Guided(
            moves=f"the same move ({guided.MOVE_TURNS} motor turns at {guided.MOVE_SPEED_RPM} "
            f"rpm), 0xAA and 0xAC read {guided.SETPOINT_SAMPLES} times "
            f"{guided.SETPOINT_PERIOD_S:g} s apart while it runs, then stopped with 0x29 = 0 "
            "and watched until it stands",
            stop_how="the drive's enable input or its power",
            run=guided.setpoint_in_a_move,
            send_stop=guided.stop_and_restore,
        ),
    ),
    Check(
        "standstill",
        'A resting servo is "standing"',
        (17,),
        "Enabled in position control, no move, watch `ros2 topic echo /motec/motec_1/state "
        "--field speed_actual_rpm` for 10 s. Expected: every value within ±3 rpm "
        "(`STANDSTILL_SPEED_RPM`), and `position_setpoint - position_actual` within "
        "`goal_tolerance_counts` (10). Then `ros2 action send_goal /motec/motec_1/move_to "
        'msg_defs/action/MoveTo "{position: 6.283, relative: true, max_velocity: 10.0}"` must '
        "end REACHED within about a second of the motor stopping. A drive that dithers more: "
        "raise `goal_tolerance_counts`, and report the figure (the band is a constant).",
        guided=Guided(
            moves="network mode and position control (0x24 = 0, 0x25 = 2) and enable (0x28 = "
            f"1), no move: the motor holds where it is while 0xAA-0xAF are read every "
            f"{guided.REST_READ_S:g} s for {guided.REST_WATCH_S:g} s; then the verified stop, "
            "and released again if it was released before (the `~/move_to` half is yours)",
            stop_how="the drive's enable input or its power",
            run=guided.standstill,
            send_stop=guided.stop_and_restore,
        ),
    ),
    Check(
        "move_time_limit",
        "The default time limit of `~/move_to` fits the drive's ramps",
        (17,),
        "The same goal with a tenth of the speed, `max_velocity: 1.0`: it must end REACHED, "
        "not TIMED_OUT. A drive with a very slow acceleration set in the vendor tool may need "
        "a larger `move_time_margin` (`ros2 param set /motec/motec_1 move_time_margin 5.0`).",
    ),
    Check(
        "new_target",
        "A new target with 0x29 = 1 while a move runs (`~/joint_commands` position streams)",
        (21,),
        "In position control, enabled, start a long move (`ros2 service call "
        '/motec/motec_1/move msg_defs/srv/PositionMove "{position: 60.0, relative: false, '
        'max_velocity: 6.28}"`); a second later write a nearer target with Pr.38 and Pr.41 = '
        "1 (`write_parameter` refuses 0x29: use `~/move` again with `position: 10.0`). "
        "Expected (the simulator's reading): the drive turns towards the new target from "
        "where it is and stops there (`~/state`: `position_actual` ends near 10 rad in "
        "counts, no reversal beyond it). A drive that ignores 0x29 = 1 while it reads 1 runs "
        "on to the first target: then `~/joint_commands` position streams must not be used on "
        "it (velocity streams are unaffected).",
        guided=Guided(
            moves=f"network mode and position control, enable, an absolute move "
            f"{guided.NEW_TARGET_FAR_TURNS} motor turns ahead at {guided.MOVE_SPEED_RPM} rpm, "
            f"after {guided.RUN_BEFORE_STOP_S:g} s a target {guided.NEW_TARGET_NEAR_TURNS} "
            "turn ahead of the start (0x2D = 1, 0x26, 0x29 = 1, read back), watched until it "
            "stands; then the verified stop, and released again if it was released before",
            stop_how="the drive's enable input or its power",
            run=guided.new_target,
            send_stop=guided.stop_and_restore,
        ),
    ),
    Check(
        "lifeguard_off",
        "Disarming with 0x112 = 0 turns the lifeguard off",
        (9,),
        "In network mode, `ros2 param set /motec/motec_1 lifeguard_ms 1000`, then `ros2 param "
        "set /motec/motec_1 lifeguard_ms 0`; stop the bridge with Ctrl-C and wait 3 s; start "
        "it again. Expected: `~/state` shows `fault_code: 0` and `lifeguard_time_ms: 0`. A "
        "fault there means the drive still watched with 0x112 = 0 (the manual says it does "
        "not).",
        guided=Guided(
            moves=f"network mode and position control (0x24 = 0, 0x25 = 2; nothing moves), the "
            f"lifeguard armed with {guided.LIFEGUARD_TEST_MS} ms and disarmed at once as the "
            "bridge does (0x112 = 0, then 0x114 = 0), then nothing written for "
            f"{guided.OFF_WATCH_FACTOR} x that time before the fault code is read (a drive "
            "that still watches trips: it releases the motor and needs a power cycle)",
            stop_how="the drive's power",
            run=guided.lifeguard_off,
            send_stop=guided.disarm,
        ),
    ),
    Check(
        "fault_halves",
        "Which half of 0xC8-0xC9 a fault fills",
        (7, 9),
        "Arm the lifeguard (`ros2 param set /motec/motec_1 lifeguard_ms 1000`) in network "
        "mode, then `kill -9` the bridge; after 2 s start it again. Expected (the simulator's "
        "reading of §4.3): `fault_flag: 1, fault_detail: 0`. `fault_flag: 0, fault_detail: 1` "
        "means the drive keeps the flag in 0xC9; either way diagnostics are ERROR. Recover "
        "with a power cycle.",
        guided=Guided(
            moves=f"network mode and position control (0x24 = 0, 0x25 = 2; nothing moves), the "
            f"lifeguard armed with {guided.LIFEGUARD_TEST_MS} ms (0x112, then 0x114 = 9999), "
            f"then nothing written: 0xC8-0xC9 and 0x28 read every {guided.TRIP_READ_S:g} s "
            "until the drive trips (it releases the motor and latches the fault until a "
            "power cycle: the time seen is in the report); then disarmed (0x112 = 0, "
            "0x114 = 0)",
            stop_how="the drive's power",
            run=guided.lifeguard_trip,
            send_stop=guided.disarm,
        ),
    ),
    Check(
        "line_glitch",
        "A short line glitch does not trip an armed drive",
        (9,),
        "Armed with `lifeguard_ms` 1000 and enabled, pull the RS-485 plug and push it back "
        "within about half a second. Expected: `~/connected` goes false and true again, "
        "`~/state` keeps `fault_code: 0` and `enabled: true`. What is guaranteed: a drive "
        "whose line answers again x after its last write is fed before it trips when x + 0.1 "
        "s (the next try while down) + 0.1 s (the feeding thread's wake-up) + one transaction "
        "on the line (0.124 s at the defaults) stays below 1000 ms, i.e. x up to about 0.67 "
        "s; a plug pushed back within half a second always is, later ones usually are. A "
        "failing result: `~/state` shows `fault_code` 65536 (`fault_flag: 1`) and `enabled: "
        "false` after a glitch of half a second or less: report the glitch's length and `ros2 "
        "topic echo /diagnostics` of the drive (the feeds then did not reach it in time). "
        "(The bridge tries a drive it sees as down 333 ms after its last write, then every "
        "0.1 s up to 1000 ms, then every 333 ms; `bench/motec_blackout.py` gives the figures "
        "on the emulated line.) Fails if `fault_code` turns non-zero or `enabled` false: the "
        "drive's lifeguard ran out during the glitch, so the feed did not reach it in time; "
        "recover with a power cycle, raise `lifeguard_ms` if such glitches must be ridden "
        "through, and report how long the plug was out.",
    ),
    Check(
        "disable_all",
        "`disable_all` reaches every drive",
        (15,),
        "With every drive enabled, `ros2 service call /motec/motec_bridge/disable_all "
        "std_srvs/srv/Trigger`. Expected: success, and the message reads `drive N: 0x28 = 0, "
        '...` for every drive, none with "missed the broadcast". A drive that misses '
        "broadcasts repeatedly has a wiring or termination fault.",
    ),
    Check(
        "start_all",
        "A broadcast start moves the setpoint at once",
        (15,),
        "Prepare a move on each drive (`ros2 service call /motec/motec_1/write_parameter "
        'msg_defs/srv/WriteParameter "{index: 38, value: 100000}"`, and Pr.45 = 0 for '
        "relative), then `ros2 service call /motec/motec_bridge/start_all "
        "std_srvs/srv/Trigger`. Expected: success and, per drive, `0xAA = <changed>, 0xAF = "
        "<non-zero> rpm`. Also read `ros2 service call /motec/motec_1/read_parameter "
        'msg_defs/srv/ReadParameter "{index: 41}"` after the move ends: 0 or 1 tells whether '
        "the drive clears 0x29 by itself (start_all does not rely on it either way). Fails if "
        'the reply is `success: false`, "drives [N] did not take the start" (the drives that '
        "did start are then stopped): drive N did not act on the broadcast 0x29 = 1. Check "
        "its prepared move (`read_parameter` 38 and 45; a zero-length move also counts as not "
        "started); if that is right, the drive ignores broadcasts: start it with its own "
        "`~/move` and tell us.",
    ),
    Check(
        "unlisted_parameters",
        "Unlisted parameters",
        (13,),
        '`ros2 service call /motec/motec_1/read_parameter msg_defs/srv/ReadParameter "{index: '
        '100}"` answers a value; increase the index until the reply is `ILLEGAL DATA '
        "ADDRESS`: that is the end of the drive's parameter table (the simulator's ends after "
        "Pr.276). With `-p allow_unlisted_parameters:=true`, writing a parameter the vendor "
        "tool shows with a value outside its range must answer `ILLEGAL DATA VALUE` "
        "(exception 03) and change nothing (read it back): the bridge relies on that check "
        "for unlisted numbers. Fails if the write answers `success: true` and the read back "
        "shows the out-of-range value: the drive does not check its range, so keep "
        "`allow_unlisted_parameters` false on it and put the parameter back with the vendor "
        "tool.",
    ),
)


def _commission_node() -> NodeInterface:
    """The bus node's parameters, then a drive node's (by name, each once): the tool
    takes config/motec.yaml's ``/**`` block as the bridge's process does."""
    listed = [n for n in nodes() if n.package == "motec_bridge"]
    bus = next(n for n in listed if n.node == "motec_bridge")
    drive = next(n for n in listed if n.node != "motec_bridge")
    names = {spec.name for spec in bus.parameters}
    specs = (
        *bus.parameters,
        *(spec for spec in drive.parameters if spec.name not in names),
    )
    return NodeInterface(bus.package, bus.executable, bus.node, bus.text, specs)


COMMISSION_NODE = _commission_node()
PARAMS_NODE = "*"  # the params file's block /**/*: the bus node and every drive node

COMMISSIONING = Commissioning(
    bridge="motec",
    node="motec_bridge",
    register_map=MOTEC_MAP,
    checks=CHECKS,
    ping=steps.ping,
    requests_per_poll=steps.requests_per_poll,
    setup=steps.setup,
    refusal_reason=steps.refusal_reason,
)
