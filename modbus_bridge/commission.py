"""modbus_bridge's hardware checks as data: ``bridge_commission modbus --ros-args -p
device_file:=FILE ...`` runs them against the device FILE describes, and
``docs/decisions/modbus.md``'s "Hardware checks" list is rendered from them
(``bridge_commission --write-docs modbus``; tests/docs/test_commission_pages.py fails when
the page and these rows differ). Read-only checks run first (commission_steps.py), then
the guided steps, each after the operator's ``yes`` (commission_guided.py); the manual
ones need the drive's panel, a tachometer or a bus of devices. The node, its parameters'
defaults and the rows read come from the file (``Described``); "decision N" is reading N
of docs/decisions/modbus.md.
"""

from __future__ import annotations

from bridge_core.runtime.commission import Check, Commissioning, Described, Guided
from bridge_core.wire.registers import RegisterMap

from . import commission_file as file
from . import commission_guided as guided
from . import commission_steps as steps
from .description_commands import ANY_FRAME_POLLS_PER_PERIOD
from .interface import DEVICE_FILE_SPEC, NODE_NAME

PANEL = "the drive's panel (its stop key or e-stop)"
# A keepalive the tool feeds only while a step runs: a drive it armed trips after the step.
FED_DURING = (
    "; a `require_keepalive` file's keepalive is fed while the step runs and not after it, "
    "so a drive whose watchdog the feeds armed shows its communication-loss fault a "
    "watchdog time later, as after the bridge exits: reset it at the panel"
)
RUN_FORWARD = Guided(
    moves="the file's first `starts_motion` trigger (the VFD's `run_forward`: control_word "
    "= 1), read back, at the setpoint the drive holds (the tool writes no setpoint), for "
    f"at most {guided.RUN_LIMIT_S:g} s until a joint's velocity reads motion, then the "
    "trigger's stop (`stop`: control_word = 5), read back" + FED_DURING,
    stop_how=PANEL,
    run=guided.run_forward,
    send_stop=guided.stop,
)
WATCHDOG = Guided(
    moves="the start trigger as above, the keepalive fed for one watchdog time while the "
    "drive runs at the setpoint it holds, then no feed: the drive must slow by a fifth "
    f"within the watchdog time and {guided.STOP_GRACE_S:g} s; then the stop trigger "
    "(the drive is then in its communication-loss fault: reset it at the panel)",
    stop_how=PANEL,
    run=guided.watchdog,
    send_stop=guided.stop,
)
FRAME_WATCHDOG = Guided(
    moves="the start trigger as above, the drive read until it turns and for one watchdog "
    f"time, then no frame at all for {guided.SILENCE_OVER:g} watchdog times, then reads: it "
    f"must have slowed by a fifth within {guided.STOP_GRACE_S:g} s more; then the stop "
    "trigger",
    stop_how=PANEL,
    run=guided.frame_watchdog,
    send_stop=guided.stop,
)
READ_BACK = Guided(
    moves="the start trigger (control_word = 1 on the VFD) and at once its stop trigger "
    "(control_word = 5), each read back: the drive may start for a moment" + FED_DURING,
    stop_how=PANEL,
    run=guided.read_back,
    send_stop=guided.stop,
)

CHECKS = (
    Check(
        "gaps_served",
        "Does the device serve reads through the gaps the plan reads through",
        (10, 11),
        (
            "`read_undefined: true` or reads through unwanted registers. Start the bridge and "
            "watch its log for one minute: `modbus_bridge --ros-args -p device_file:=FILE 2>&1 "
            '| grep "refused the merged read"`. Nothing: every merged read is served. A line '
            "`the device refused the merged read of holding A+N (ILLEGAL DATA ADDRESS): "
            "reading it as ...` names a read the device refuses; the bridge reads it in parts "
            "from then on, but set `read_undefined: false` (or a `max_gap`) in the file so "
            "the plan does not try it at every start. The tool reads each request of the "
            "file's plan that reads through rows it does not want, as the bridge plans it "
            "(a request holding a row refused alone is left to the addresses check); a plan "
            "that reads through no gap is confirmed."
        ),
        read=steps.gaps_served,
    ),
    Check(
        "plan_speed",
        "Is the fewest-requests plan also the fastest on your line",
        (10,),
        (
            "RTU. Note the poll rate the bridge reaches, then cap the gaps and compare: `ros2 "
            "topic hz /modbus_bridge/state` with the file as it is, then with `max_gap: 4` "
            "under `device`. Keep the setting with the higher rate; on TCP expect no "
            "difference, on RTU at 9600 baud a long gap may cost more than the request it "
            "saves. The tool polls the file's plan and the plan with `max_gap: "
            f"{steps.CAPPED_GAP}` {steps.PLAN_POLLS} times each, alternately, when they "
            "differ, and recommends the cap only when its median poll is more than "
            f"{steps.PLAN_MARGIN:.0%} shorter (a key of the file: the report says where)."
        ),
        read=steps.plan_speed,
    ),
    Check(
        "addresses",
        "Are the addresses the manual's",
        (8,),
        (
            "And hex notation. Print the table and compare it row by row with the manual's "
            "register list, in the manual's notation: `modbus_doc FILE | grep '^| '`. Each "
            "address shows as decimal and hex (`8448 (0x2100)`); one off by one means the "
            "manual counts from 1 (PLC numbering 40001): subtract 1 in the file. The tool "
            "reads every readable row alone; a row refused is read again one address below "
            "and above, and when every refused row answers one off, the report names the "
            "shift. Every row answering is confirmed, but only you can compare the names "
            "with the manual."
        ),
        read=steps.addresses,
    ),
    Check(
        "parity",
        "Parity on the wire",
        (15, 24),
        (
            "`parity: even` in the file, `-p parity:=...` on the command line: `modbus_bridge "
            "--ros-args -p device_file:=FILE -p \"parity:='E'\"`; you should see `connected "
            "to ...` within a second. A `-p parity:=N` without the quotes is refused at start "
            "with the hint to quote it (ROS reads `N` as the boolean false). Fails if the log "
            "shows `cannot reach ...: ...; retrying` instead of `connected to ...`: the "
            "device is not set to this parity (or baud rate); set the file's `parity` and "
            "`baudrate` to what the device uses. The tool takes the same parameters: a "
            "device that answers its first read answers at this framing (confirmed); one "
            "that never answers ends the run with `error: no reply from the device` (exit "
            "1). Over TCP there is nothing to check."
        ),
        read=steps.parity,
    ),
    Check(
        "keepalive_settings",
        "The watchdog the file names can be fed",
        (13, 21, 22),
        (
            "A register keepalive: its register (and a `period_from` register) answers "
            "alone, and a watchdog time read from the device is above 0 (0: the watchdog is "
            "off, and nothing stops the device when the bridge dies: write its time first). "
            "Mode `any_frame`: `poll_rate_hz` sends at least "
            f"{ANY_FRAME_POLLS_PER_PERIOD} polls within `period_s`, and one poll of "
            "the file's plan takes less than a third of it on this line. Fails if a "
            "register is refused (every feed fails: check its address), the time reads 0, "
            "or the polls are too few (the report recommends `poll_rate_hz`) or too slow "
            "(the line cannot carry them: set a longer time-out on the drive and in "
            "`period_s`). A file without a keepalive: not run."
        ),
        read=steps.keepalive_settings,
    ),
    Check(
        "run_forward",
        "VFD control word values",
        (16,),
        (
            "The example's 1 = run forward, 5 = stop. `ros2 service call "
            "/modbus_bridge/run_forward std_srvs/srv/Trigger`, then `ros2 service call "
            '/modbus_bridge/read msg_defs/srv/ReadRegisters "{names: [status_word, '
            "output_frequency]}\"`: the status word's running bit is set and the output "
            "frequency rises to the setpoint; `ros2 service call /modbus_bridge/stop "
            "std_srvs/srv/Trigger` brings it back to 0. Fails if the running bit stays clear "
            "and the output frequency at 0, the motor turns in reverse, or stop leaves it "
            "running (stop it at the panel): your drive's control word values are not the "
            "example's (decision 16); put your manual's in `control_word`'s `values` and the "
            "`run_forward` and `stop` writes. A drive whose run source is not set to "
            "communication ignores the word. The tool's step is confirmed when the start "
            "reads back and a joint's velocity reads motion, contradicted when the start "
            "does not read back; no motion (a setpoint of 0, a run source elsewhere) could "
            "not tell. The direction is yours to watch."
        ),
        guided=RUN_FORWARD,
    ),
    Check(
        "watchdog",
        "VFD communication watchdog",
        (13, 16),
        (
            "The register fed and its 2 s: run forward, then `kill -9` the bridge process: "
            "the drive stops within the drive's communication timeout and shows its "
            "communication-loss fault; with the bridge running it never does. Fails if the "
            "drive runs on after the kill (stop it at the panel): its communication timeout "
            "is off or watches another register; set it in the drive and point "
            "`keepalive`'s `register` at the one your manual names. A communication-loss "
            "fault while the bridge runs: the drive wants a shorter feed than `period_s` or "
            "another `mode`. The tool's step feeds the keepalive as the bridge does, then "
            "stops feeding (the kill) and reads the joints: slowed by a fifth within the "
            "watchdog time and the grace, confirmed; still at its speed, contradicted; "
            "slowing less, could not tell (a long ramp: watch it)."
        ),
        guided=WATCHDOG,
    ),
    Check(
        "frequency_scale",
        "VFD frequency scale",
        (16,),
        (
            "0.01 Hz. `ros2 service call /modbus_bridge/set_frequency msg_defs/srv/SetValue "
            '"{value: 12.34}"` and run: the drive\'s panel shows 12.34 Hz and `~/state` '
            "output_frequency 12.34. Fails if the panel shows 123.4 Hz (or the drive's "
            "maximum) or 1.23 Hz, or `~/state` differs from the panel: the drive counts in "
            "another unit (decision 16); set the `scale` of `frequency_setpoint` and "
            "`output_frequency` to your manual's (`raw = value × scale`: 10 for 0.1 Hz). "  # noqa: RUF001
            "Manual: only the panel can tell (the device reads back its own unit)."
        ),
    ),
    Check(
        "per_revolution",
        "per_revolution",
        (16,),
        (
            "2 for a 4-pole motor. Run at 50 Hz and measure the shaft with a tachometer: "
            "about 1500 rpm less slip; `joint_states` velocity 157.1 rad/s. Fails if the "
            "tachometer reads about 3000 or 1000 rpm (a 2- or 6-pole motor): `joint_states` "
            "is then off by that factor; set `per_revolution` under the joint's `velocity` "
            "to the motor's pole pairs (1, 3)."
        ),
    ),
    Check(
        "word_order",
        "Inverter word orders",
        (1, 16),
        (
            "CDAB monitors, ABCD setpoints. With the motor stopped, `ros2 service call "
            '/modbus_bridge/read msg_defs/srv/ReadRegisters "{names: [dc_bus_voltage, '
            'motor_position]}"`: the DC bus reads about 1.35 × the mains voltage (540 V on '  # noqa: RUF001
            "400 V); a wrong word order reads as a tiny or huge number, not an error: then "
            "set that register's `word_order` to the other one (`high_first` / `low_first`). "
            "The tool decodes every 32/64-bit row that reads nonzero in the file's word order "
            "and in the other: plausible means within the row's `range`, a float of 0 "
            f"or between {steps.FLOAT_PLAUSIBLE[0]:g} and {steps.FLOAT_PLAUSIBLE[1]:g} in "
            "magnitude, an integer without a range of at most "
            f"{steps.INT_PLAUSIBLE_MAX:,} raw that is no multiple of 65536. A row plausible "
            "only the other way is contradicted, with the key to change; all zero settles "
            "nothing: run the device and check again."
        ),
        read=steps.word_order,
    ),
    Check(
        "adapter_8e1",
        "8E1 on a real adapter",
        (15,),
        (
            'The bridge log has no "does not keep the parity bit" INFO line for '
            "`/dev/ttyUSB0` (a UART keeps PARENB); a device set to 8E1 answers. Fails if "
            "that line names `/dev/ttyUSB0`: the adapter's driver drops the parity bit, "
            "frames go out without it and an 8E1 device does not answer (`cannot reach "
            "...`); use another adapter."
        ),
    ),
    Check(
        "motec_lifeguard",
        "MOTEC lifeguard as a keepalive",
        (3, 13),
        (
            "`config/devices/rtu_multidrop.yaml`. `ros2 service call "
            '/drive_1/set_lifeguard_time msg_defs/srv/SetValue "{value: 500}"`, then '
            "`/drive_1/set_lifeguard_mode` with 9999; `kill -9` the `modbus_bus` process: the "
            'drive faults (fault code 1, "有故障") and releases the motor within 0.5 s. Fails '
            "if the drive keeps the motor enabled without a fault: the lifeguard is not "
            "armed; read `lifeguard_time` and `lifeguard_mode` back (`/drive_1/read`: 500 and "
            "9999 expected) and tell us if they hold those. A fault while `modbus_bus` runs "
            "means the feed (decision 13) does not reach the drive: tell us. Manual: the tool "
            "takes a file of one device (`modbus_bridge`'s), not a line."
        ),
    ),
    Check(
        "frame_watchdog",
        "A watchdog any frame resets",
        (22,),
        (
            "`keepalive: {mode: any_frame, period_s: T}`. Set the drive's communication "
            "time-out to `T`, start the bridge and run the motor; it keeps running while the "
            "bridge polls. Then `kill -9` the bridge process: the drive stops within `T` and "
            "shows its communication-loss fault. Fails if the drive faults while the bridge "
            "runs (it wants frames more often, or only writes reset it: use a register "
            "keepalive instead) or runs on after the kill (its time-out is off: stop it at "
            "the panel and set it). The tool's step sends no frame for `T` and the grace "
            "(the kill), then reads the joints."
        ),
        guided=FRAME_WATCHDOG,
    ),
    Check(
        "read_back",
        "A command's read-back",
        (19,),
        (
            '`ros2 service call /modbus_bridge/write msg_defs/srv/WriteRegister "{name: '
            "control_word, value: 1}\"` (the VFD; your file's start register and value), then "
            "the same with the stop value. Each answers `success: true` and `control_word = "
            "1: done` only if the drive holds the value: a drive that keeps its command word "
            "answers so. Fails if it answers `not confirmed: wrote control_word = 1, read back "
            "control_word = 0 (sent, not confirmed)` while the drive runs: the drive clears "
            "its command word (or shows another value) once it took it, and every command on "
            'it will read "not confirmed"; read the manual for the register that shows the '
            "state and tell us (the description has no key for such a confirmation yet). If "
            "it answers so and the drive does not run, the drive ignored the write: its run "
            "source is not communication. The tool's step sends the file's start trigger and "
            "its stop trigger, each read back as the bridge reads it back."
        ),
        guided=READ_BACK,
    ),
)

COMMISSIONING = Commissioning(
    bridge="modbus",
    node=NODE_NAME,
    register_map=RegisterMap("described by device_file", ()),  # bind() gives the file's
    checks=CHECKS,
    ping=file.ping_placeholder,
    requests_per_poll=file.requests_per_poll,
    setup=file.setup,
    refusal_reason=file.refusal_reason,
    described=Described((DEVICE_FILE_SPEC,), file.node_of, file.bind),
)
