"""Description files: every field, good and bad files, errors that point at key and line."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from bridge_core.wire.codec import decode, encode
from bridge_core.wire.registers import Access, Table, ValueType, WordOrder
from modbus_bridge.description import DescriptionError, load
from xarm_bridge.registers import SETTABLE_STATES, XARM_MAP

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "config" / "devices").glob("*.yaml"))

# A file using every field; its line numbers are what the error tests expect.
GOOD = """\
device:
  name: pump
  manual: "Pump manual v1"
  link:
    tcp: {host: 127.0.0.1, port: 1502}
  unit_id: 3
registers:
  - {name: speed, table: holding, address: 10, type: i32, scale: 10, unit: rpm, access: RW, range: [-3000, 3000], manual: "s4.1"}
  - {name: angle, table: input, address: 0, type: f32, word_order: low_first, unit: deg, manual: "s4.2"}
  - {name: run, table: coil, address: 0, type: bool, access: RW, manual: "s5"}
  - {name: label, table: holding, address: 100, type: string, length: 4, manual: "s4.9"}
joints:
  - {name: shaft, position: {register: angle}, velocity: {register: speed, factor: 0.1}, sim: {command: speed}}
commands:
  triggers:
    - {name: start, writes: [{register: run, value: true}], starts_motion: false}
  values:
    - {name: set_speed, register: speed, starts_motion: false}
  coils:
    - {name: set_run, register: run, stop_on: false, starts_motion: false}
  topics:
    - {name: cmd_speed, register: speed, stop_value: 0, timeout_s: 0.5}
"""  # noqa: E501


def write(tmp_path: Path, text: str, name: str = "device.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_good_file_builds_bridge_core_types(tmp_path: Path) -> None:
    description = load(write(tmp_path, GOOD))
    device = description.device
    assert device.name == "pump" and device.unit_id == 3
    assert device.link is not None and device.link.transport == "tcp"
    assert device.link.tcp is not None and device.link.tcp.port == 1502
    speed = device.register_map["speed"]
    assert (speed.table, speed.address, speed.value_type) == (Table.HOLDING, 10, ValueType.I32)
    assert (speed.scale, speed.unit, speed.access) == (10.0, "rpm", Access.READ_WRITE)
    assert (speed.minimum, speed.maximum, speed.doc) == (-3000, 3000, "s4.1")
    assert speed.word_order is WordOrder.HIGH_FIRST  # the device default
    angle = device.register_map["angle"]
    assert angle.word_order is WordOrder.LOW_FIRST and angle.value_type is ValueType.F32
    assert decode(angle, encode(angle, 90.0)) == 90.0
    assert device.register_map["label"].count == 4
    (joint,) = device.joints
    assert joint.position is not None and joint.position.to_si == pytest.approx(math.pi / 180)
    assert joint.velocity is not None
    assert joint.velocity.to_si == pytest.approx(2 * math.pi / 60 * 0.1)
    assert joint.motion is not None and joint.motion.command == "speed"
    assert joint.motion.mode == "velocity" and joint.motion.to_si == pytest.approx(math.pi / 30)
    assert device.state_names == ("speed", "angle", "run", "label")
    limits = device.register_map.limits
    assert limits.function_codes == frozenset({1, 2, 3, 4, 5, 6, 15, 16})
    assert limits.max_read_registers == 125 and not limits.read_undefined_ok


def test_device_fields_reach_the_limits(tmp_path: Path) -> None:
    text = GOOD.replace(
        "  unit_id: 3\n",
        "  unit_id: 3\n  word_order: low_first\n  max_read_registers: 49\n"
        "  max_write_registers: 40\n  max_read_bits: 100\n  max_write_bits: 50\n"
        "  function_codes: [1, 3, 5, 6, 15, 16, 4]\n  read_undefined: true\n  max_gap: 3\n"
        "  reply_delay_s: 0.035\n  poll_rate_hz: 5\n  state: [speed, run]\n  title: A pump\n",
    )
    device = load(write(tmp_path, text)).device
    limits = device.register_map.limits
    assert (limits.max_read_registers, limits.max_write_registers) == (49, 40)
    assert (limits.max_read_bits, limits.read_undefined_ok, limits.max_gap) == (100, True, 3)
    assert limits.reply_delay_s == 0.035
    assert device.spec.device.max_write_bits == 50 and device.spec.device.poll_rate_hz == 5.0
    assert device.state_names == ("speed", "run")
    assert device.register_map["speed"].word_order is WordOrder.LOW_FIRST


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda p: p.name)
def test_examples_load(example: Path) -> None:
    assert load(example).devices


# What config/devices/xarm.yaml leaves out of xarm_bridge's map (its header, modbus_bridge
# decision 2 of docs/decisions/modbus.md): the user coils C256-511, tool AO H7-10
# ("当前仅0路有效"), the offline-task rows H48-63 (xarm_bridge's ~/run_offline_task).
XARM_LEFT_OUT = {
    **{f"user_coil_{i}": (Table.COIL, 256 + i) for i in range(256)},
    **{f"tool_ao_{i}": (Table.HOLDING, 7 + i) for i in range(4)},
    **{f"offline_task_{i}": (Table.HOLDING, 48 + i) for i in range(16)},
}


def test_xarm_example_is_xarm_bridges_map() -> None:
    """The xArm description is xarm_bridge's map, both ways and field by field: every
    row of the file is xarm_bridge's, and every row of xarm_bridge's is in the file
    except exactly the documented left-out set."""
    device = load(ROOT / "config" / "devices" / "xarm.yaml").device
    names = {register.name for register in device.register_map}
    theirs_names = {register.name for register in XARM_MAP}
    assert names - theirs_names == set()
    assert theirs_names - names == set(XARM_LEFT_OUT)
    for name, (table, address) in XARM_LEFT_OUT.items():
        assert (XARM_MAP[name].table, XARM_MAP[name].address) == (table, address), name
    for register in device.register_map:
        theirs = XARM_MAP[register.name]
        assert (register.table, register.address, register.value_type) == (
            theirs.table,
            theirs.address,
            theirs.value_type,
        ), register.name
        assert (register.scale, register.offset, register.word_order, register.unit) == (
            theirs.scale,
            theirs.offset,
            theirs.word_order,
            theirs.unit,
        ), register.name
        assert register.doc == theirs.doc, register.name
        limits = (register.minimum, register.maximum)
        if not register.access.writable:
            assert limits == (None, None), register.name  # no write range on a read-only row
        elif register.name == "arm_state":
            # xarm_bridge has no range on H33 and checks set_state against its states; the
            # file gives their span and the states themselves.
            assert limits == (min(SETTABLE_STATES), max(SETTABLE_STATES))
            assert device.allowed_values["arm_state"] == SETTABLE_STATES
        else:
            assert theirs.access.writable, register.name
            assert limits == (theirs.minimum, theirs.maximum), register.name
    assert set(device.allowed_values) == {"arm_state"}
    assert device.register_map.limits.function_codes == XARM_MAP.limits.function_codes
    names_of_joints = [joint.name for joint in device.joints]
    assert names_of_joints == [f"joint{j}" for j in range(1, 8)]


def test_values_are_the_only_writes_allowed(tmp_path: Path) -> None:
    text = GOOD.replace("range: [-3000, 3000], manual", "values: [-1500, 0, 1500.5], manual")
    device = load(write(tmp_path, text)).device
    assert device.allowed_values == {"speed": (-1500.0, 0.0, 1500.5)}
    assert device.allows("speed", 1500.5) and device.allows("speed", -1500)
    assert not device.allows("speed", 1500.4) and not device.allows("speed", 1)
    assert device.allows("angle", 7.0)  # no values: any
    bad = text.replace("values: [-1500, 0, 1500.5]", "values: [-1500, 1500.5]")
    with pytest.raises(DescriptionError, match=r":22: commands.topics\[0\].stop_value: speed"):
        load(write(tmp_path, bad))
    trigger = GOOD.replace(
        "[{register: run, value: true}]",
        "[{register: run, value: true}, {register: speed, value: 7}]",
    ).replace("range: [-3000, 3000], manual", "values: [0, 5], manual")
    with pytest.raises(DescriptionError) as caught:
        load(write(tmp_path, trigger))
    assert caught.value.lines() == [
        f"{tmp_path / 'device.yaml'}:16: commands.triggers[0].writes[1].value: "
        "speed takes one of 0, 5, not 7"
    ]


def test_rtu_multidrop_example() -> None:
    description = load(ROOT / "config" / "devices" / "rtu_multidrop.yaml")
    assert description.line is not None and description.line.rtu is not None
    assert len(description.devices) == 2
    assert len({d.unit_id for d in description.devices}) == 2
    assert all(d.link is None for d in description.devices)


# (replace this, with this, key path, line, words the message must hold)
BAD = [
    ("  name: pump\n", "  name: 9pump\n", "device.name", 2, "pattern"),
    ('  manual: "Pump manual v1"\n', "", "device.manual", 1, "missing (required)"),
    (
        "    tcp: {host: 127.0.0.1, port: 1502}\n",
        "    tcp: {port: 70000}\n",
        "device.link.tcp.port",
        5,
        "less than or equal to 65535",
    ),
    (
        "    tcp: {host: 127.0.0.1, port: 1502}\n",
        "    tcp: {prot: 1}\n",
        "device.link.tcp.prot",
        5,
        "unknown key: did you mean `port`? (allowed: host, port, max_in_flight)",
    ),
    (
        "    tcp: {host: 127.0.0.1, port: 1502}\n",
        "    udp: {}\n",
        "device.link.udp",
        5,
        "allowed: tcp, rtu, timeout_s",
    ),
    (
        "    tcp: {host: 127.0.0.1, port: 1502}\n",
        "    tcp: {}\n    rtu: {}\n",
        "device.link",
        4,
        "exactly one of tcp and rtu",
    ),
    (
        "    tcp: {host: 127.0.0.1, port: 1502}\n",
        "    rtu: {parity: X}\n",
        "device.link.rtu.parity",
        5,
        "parity is N, E or O (or none, even, odd; any case), not 'X'",
    ),
    (
        "    tcp: {host: 127.0.0.1, port: 1502}\n",
        "    rtu: {baudrate: 9600.5}\n",
        "device.link.rtu.baudrate",
        5,
        "integer",
    ),
    ("  unit_id: 3\n", "  unit_id: 300\n", "device.unit_id", 6, "less than or equal to 247"),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  word_order: middle\n",
        "device.word_order",
        7,
        "'high_first' or 'low_first'",
    ),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  max_read_registers: 126\n",
        "device.max_read_registers",
        7,
        "125",
    ),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  max_write_registers: 0\n",
        "device.max_write_registers",
        7,
        "greater than or equal to 1",
    ),
    ("  unit_id: 3\n", "  unit_id: 3\n  max_read_bits: 2001\n", "device.max_read_bits", 7, "2000"),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  max_write_bits: 1969\n",
        "device.max_write_bits",
        7,
        "1968",
    ),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  function_codes: [3, 7]\n",
        "device.function_codes[1]",
        7,
        "22 or 23",
    ),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  function_codes: [1, 2, 4, 5, 6, 15, 16]\n",
        "registers[0].table",
        9,
        "function code 3",
    ),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  function_codes: [1, 2, 3, 4, 15]\n",
        "registers[0].access",
        9,
        "6 or 16",
    ),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  read_undefined: maybe\n",
        "device.read_undefined",
        7,
        "boolean",
    ),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  reply_delay_s: -1\n",
        "device.reply_delay_s",
        7,
        "greater than or equal to 0",
    ),
    ("  unit_id: 3\n", "  unit_id: 3\n  poll_rate_hz: 0\n", "device.poll_rate_hz", 7, "0.1"),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  state: [speed, nothing]\n",
        "device.state[1]",
        7,
        "not a readable register",
    ),
    ("  unit_id: 3\n", "  unit_id: 3\n  unit_id: 4\n", "device.unit_id", 7, "key given twice"),
    (
        "name: speed, table: holding",
        "name: speed, table: holdings",
        "registers[0].table",
        8,
        "'coil', 'discrete_input', 'holding' or 'input'",
    ),
    (
        "address: 10, type: i32",
        "address: 65535, type: i32",
        "registers[0].address",
        8,
        "runs past 65535",
    ),
    (
        "address: 10, type: i32",
        "address: -1, type: i32",
        "registers[0].address",
        8,
        "greater than or equal to 0",
    ),
    (
        "address: 10, type: i32",
        "address: 10, type: i24",
        "registers[0].type",
        8,
        "'f64' or 'string'",
    ),
    ("address: 0, type: bool", "address: 0, type: u16", "registers[2].type", 10, "allowed: bool"),
    (
        "name: angle, table: input, address: 0, type: f32",
        "name: angle, table: discrete_input, address: 0, type: f32",
        "registers[1].type",
        9,
        "allowed: bool",
    ),
    ("type: string, length: 4", "type: string", "registers[3].length", 11, "needs its length"),
    (
        "type: i32, scale: 10",
        "type: i32, length: 2, scale: 10",
        "registers[0].length",
        8,
        "only a string",
    ),
    (
        "type: string, length: 4",
        "type: string, length: 200",
        "registers[3].length",
        11,
        "less than or equal to 125",
    ),
    ("scale: 10, unit: rpm", "scale: 0, unit: rpm", "registers[0].scale", 8, "greater than 0"),
    ("scale: 10, unit: rpm", "scale: .nan, unit: rpm", "registers[0].scale", 8, "finite"),
    ("scale: 10, unit: rpm", "scale: 10, offset: x, unit: rpm", "registers[0].offset", 8, "number"),
    (
        "type: bool, access: RW",
        "type: bool, scale: 2, access: RW",
        "registers[2]",
        10,
        "no scale, offset or range",
    ),
    (
        "unit: deg, manual",
        "unit: deg, access: RW, manual",
        "registers[1].access",
        9,
        "read-only input table",
    ),
    (
        "unit: deg, manual",
        "unit: deg, access: X, manual",
        "registers[1].access",
        9,
        "'R', 'RW' or 'W'",
    ),
    ("range: [-3000, 3000]", "range: [3000, -3000]", "registers[0].range", 8, "minimum > maximum"),
    ("range: [-3000, 3000]", "range: [-3000, 300000000]", "registers[0].range", 8, "does not fit"),
    ("range: [-3000, 3000]", "range: [1, 2, 3]", "registers[0].range", 8, "at most 2 items"),
    (', manual: "s4.9"', "", "registers[3].manual", 11, "missing (required)"),
    (', manual: "s4.9"', ', manual: ""', "registers[3].manual", 11, "empty: cite the manual"),
    (
        "name: label, table: holding, address: 100",
        "name: label, table: holding, address: 11",
        "registers[3].address",
        11,
        "overlaps speed at holding 11",
    ),
    ("name: label,", "name: speed,", "registers[3].name", 11, "defined twice"),
    (
        "name: label,",
        "name: label, colour: red,",
        "registers[3].colour",
        11,
        "unknown key (allowed: name, table, address",
    ),
    (
        "position: {register: angle}",
        "position: {register: angel}",
        "joints[0].position.register",
        13,
        "no register named 'angel'",
    ),
    (
        "position: {register: angle}",
        "position: {register: run}",
        "joints[0].position.register",
        13,
        "not a readable number",
    ),
    (
        "position: {register: angle}",
        "position: {register: speed}",
        "joints[0].position.register",
        13,
        "REP 103 rad; allowed units: rad, mrad, deg, rev",
    ),
    (
        "{name: shaft,",
        "{name: shaft, kind: prismatic,",
        "joints[0].position.register",
        13,
        "REP 103 m;",
    ),
    (
        "{name: shaft,",
        "{name: shaft, kind: spherical,",
        "joints[0].kind",
        13,
        "'revolute' or 'prismatic'",
    ),
    (
        "velocity: {register: speed, factor: 0.1}",
        "velocity: {register: speed, factor: 0.1}, effort: {register: speed}",
        "joints[0].effort.register",
        13,
        "REP 103 N.m",
    ),
    (
        "{name: shaft, position: {register: angle}, velocity: {register: speed, factor: 0.1}, ",
        "{name: shaft, ",
        "joints[0]",
        13,
        "needs a position or a velocity register",
    ),
    (
        "writes: [{register: run, value: true}]",
        "writes: []",
        "commands.triggers[0].writes",
        16,
        "at least 1 item",
    ),
    (
        "writes: [{register: run, value: true}]",
        "writes: [{register: run, value: 5}]",
        "commands.triggers[0].writes[0].value",
        16,
        "allowed: true or false",
    ),
    (
        "writes: [{register: run, value: true}]",
        "writes: [{register: speed, value: 4000}]",
        "commands.triggers[0].writes[0].value",
        16,
        "outside -3000.0..3000.0",
    ),
    (
        "writes: [{register: run, value: true}]",
        "writes: [{register: angle, value: 1}]",
        "commands.triggers[0].writes[0].register",
        16,
        "read only",
    ),
    (
        "{name: set_speed, register: speed,",
        "{name: set_speed, register: run,",
        "commands.values[0].register",
        18,
        "coils go under commands.coils",
    ),
    (
        "{name: set_speed, register: speed,",
        "{name: read, register: speed,",
        "commands.values[0].name",
        18,
        "reserved",
    ),
    (
        "{name: set_speed, register: speed,",
        "{name: start, register: speed,",
        "commands.values[0].name",
        18,
        "given twice",
    ),
    (
        "{name: set_run, register: run,",
        "{name: set_run, register: speed,",
        "commands.coils[0].register",
        20,
        "not a coil",
    ),
    (
        "range: [-3000, 3000], manual",
        "range: [100, 3000], manual",
        "commands.topics[0].stop_value",
        22,
        "stop value does not fit",
    ),
    (
        "stop_value: 0, timeout_s: 0.5",
        "stop_value: 0, timeout_s: 0",
        "commands.topics[0].timeout_s",
        22,
        "0.05",
    ),
    (
        "stop_value: 0, timeout_s: 0.5",
        "stop_value: 0, rate_hz: 1000",
        "commands.topics[0].rate_hz",
        22,
        "100",
    ),
    (
        "  topics:\n",
        "  streams:\n",
        "commands.streams",
        21,
        "allowed: triggers, values, coils, topics",
    ),
    ("joints:\n", "joint:\n", "joint", 12, "allowed: device, registers, joints, commands"),
    ("sim: {command: speed}", "sim: {command: sped}", "joints[0].sim.command", 13, "no register"),
    ("sim: {command: speed}", "sim: {command: angle}", "joints[0].sim.command", 13, "read only"),
    (
        "sim: {command: speed}",
        "sim: {command: speed, mode: position}",
        "joints[0].sim.command",
        13,
        "not a revolute position (rad; allowed units: rad, mrad, deg, rev)",
    ),
    (
        "sim: {command: speed}",
        "sim: {command: speed, speed: 1}",
        "joints[0].sim.speed",
        13,
        "speed is for mode position",
    ),
    (
        "sim: {command: speed}",
        "sim: {command: speed, mode: x}",
        "joints[0].sim.mode",
        13,
        "'velocity'",
    ),
]


BAD += [
    (
        "{name: cmd_speed, register: speed",
        "{name: poll, register: speed",
        "commands.topics[0].name",
        22,
        "'poll' would declare poll_rate_hz, a parameter of the node's own",
    ),
    (
        "{name: start, writes",
        "{name: connected, writes",
        "commands.triggers[0].name",
        16,
        "'connected' is the node's own (reserved: connected, joint_commands, read, state, write)",
    ),
    (
        "velocity: {register: speed, factor: 0.1}",
        "velocity: {register: speed, factor: 0}",
        "joints[0].velocity.factor",
        13,
        "0 would make every value 0 (allowed: non-zero)",
    ),
    (
        "  unit_id: 3\n",
        "  unit_id: 3\n  reply_delay_s: 0.5\n",
        "device.reply_delay_s",
        7,
        "0.5 s is not below the link's timeout_s 0.5 s (every reply would time out)",
    ),
    (
        "stop_value: 0,",
        "stop_value: 5,",
        "commands.topics[0].stop_value",
        22,
        "5: a command topic stops at 0 (allowed: 0)",
    ),
    (
        "stop_value: 0,",
        "stop_value: -0.5,",
        "commands.topics[0].stop_value",
        22,
        "-0.5: a command topic stops at 0 (allowed: 0)",
    ),
    (
        "range: [-3000, 3000], manual",
        "range: [-3000, 3000], values: [0, 4000], manual",
        "registers[0].values",
        8,
        "4000 cannot be written: speed: 4000.0 rpm is outside -3000.0..3000.0 rpm",
    ),
    (
        'access: RW, manual: "s5"',
        'access: RW, values: [1], manual: "s5"',
        "registers[2].values",
        10,
        "a bool has no values",
    ),
    (
        'unit: deg, manual: "s4.2"',
        'unit: deg, values: [1], manual: "s4.2"',
        "registers[1].values",
        9,
        "for access W or RW",
    ),
    (
        "range: [-3000, 3000], manual",
        "range: [-3000, 3000], values: [100, 200.5], manual",
        "commands.topics[0].stop_value",
        22,
        "speed takes one of 100, 200.5, not 0",
    ),
    (
        'unit: deg, manual: "s4.2"',
        'unit: deg, poll: slow, manual: "s4.2"',
        "registers[1].poll",
        9,
        "slow, but joint 'shaft' reads it (joints are fast)",
    ),
    (
        'access: RW, manual: "s5"',
        'access: W, poll: slow, manual: "s5"',
        "registers[2].poll",
        10,
        "slow: a write-only register is never polled",
    ),
    (
        'length: 4, manual: "s4.9"',
        'length: 4, poll: sometimes, manual: "s4.9"',
        "registers[3].poll",
        11,
        "'fast', 'slow' or 'never'",
    ),
]


def test_poll_groups_split_the_plan_and_never_leaves_state(tmp_path: Path) -> None:
    from modbus_bridge.device import poll_plan

    text = GOOD.replace('length: 4, manual: "s4.9"', 'length: 4, poll: slow, manual: "s4.9"')
    text = text.replace('access: RW, manual: "s5"', 'access: RW, poll: never, manual: "s5"')
    device = load(write(tmp_path, text)).device
    assert device.slow_names == ("label",)
    assert "run" not in device.state_names and "label" in device.state_names
    fast, slow, stamp = poll_plan(device)
    assert [sorted(r.names) for r in slow] == [["label"]]
    assert all("label" not in r.names and "run" not in r.names for r in fast)
    assert stamp == "angle"
    # A state list may not name a register that is never polled.
    listed = text.replace("  unit_id: 3\n", "  unit_id: 3\n  state: [speed, run]\n")
    with pytest.raises(DescriptionError, match=r"device\.state\[1\]: 'run' has poll: never"):
        load(write(tmp_path, listed))


@pytest.mark.parametrize(("old", "new", "key", "line", "words"), BAD)
def test_bad_files_name_file_line_key_and_what_is_allowed(
    tmp_path: Path, old: str, new: str, key: str, line: int, words: str
) -> None:
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(DescriptionError) as caught:
        load(path)
    error = caught.value
    assert "\n" not in str(error)
    expected = f"{path}:{line}: {key}: "
    assert any(text.startswith(expected) and words in text for text in error.lines()), error.lines()


def test_every_problem_is_listed_and_the_first_is_the_message(tmp_path: Path) -> None:
    text = GOOD.replace("port: 1502", "port: 0").replace("unit_id: 3", "unit_id: -1")
    path = write(tmp_path, text)
    with pytest.raises(DescriptionError) as caught:
        load(path)
    assert len(caught.value.problems) == 2
    assert str(caught.value).startswith(f"{path}:5: device.link.tcp.port: ")
    assert str(caught.value).endswith("(and 1 more problem(s))")


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ("device: [1\n", 2, "not valid YAML"),
        ("- 1\n- 2\n", 1, "must be a mapping"),
    ],
)
def test_not_a_description(tmp_path: Path, text: str, line: int, words: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(DescriptionError, match=f"^{path}:{line}: .*{words}"):
        load(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(DescriptionError, match="cannot read: No such file"):
        load(tmp_path / "nothing.yaml")


BUS = """\
line:
  rtu: {serial_port: /dev/ttyUSB1, baudrate: 19200}
devices:
  - device: {name: left, manual: m, unit_id: 1}
    registers:
      - {name: level, table: holding, address: 0, type: u16, manual: m}
  - device: {name: right, manual: m, unit_id: 2}
    registers:
      - {name: level, table: holding, address: 0, type: u16, manual: m}
"""


def test_bus_file(tmp_path: Path) -> None:
    description = load(write(tmp_path, BUS))
    assert description.line is not None and description.line.rtu is not None
    assert description.line.rtu.baudrate == 19200
    assert [d.name for d in description.devices] == ["left", "right"]


@pytest.mark.parametrize(
    ("old", "new", "key", "line", "words"),
    [
        (
            "name: right, manual: m, unit_id: 2",
            "name: right, manual: m, unit_id: 1",
            "devices[1].device.unit_id",
            7,
            "devices[0]'s too",
        ),
        ("name: right,", "name: left,", "devices[1].device.name", 7, "devices[0]'s too"),
        (
            "unit_id: 2}",
            "unit_id: 2, link: {rtu: {}}}",
            "devices[1].device.link",
            7,
            "no link of its own",
        ),
        ("unit_id: 2}", "unit_id: 0}", "devices[1].device.unit_id", 7, "broadcast"),
        (
            "  rtu: {serial_port: /dev/ttyUSB1, baudrate: 19200}\n",
            "  tcp: {}\n",
            "line.tcp",
            2,
            "unknown key",
        ),
        (
            "type: u16, manual: m}\n  - device",
            "type: u17, manual: m}\n  - device",
            "devices[0].registers[0].type",
            6,
            "'u16'",
        ),
    ],
)
def test_bad_bus_files(tmp_path: Path, old: str, new: str, key: str, line: int, words: str) -> None:
    assert old in BUS
    path = write(tmp_path, BUS.replace(old, new, 1))
    with pytest.raises(DescriptionError) as caught:
        load(path)
    expected = f"{path}:{line}: {key}: "
    assert any(t.startswith(expected) and words in t for t in caught.value.lines()), (
        caught.value.lines()
    )


def test_max_in_flight_per_device(tmp_path: Path) -> None:
    """``link: tcp: {max_in_flight: N}`` is the default of the node's ``max_in_flight``
    (1 when absent); outside 1..16 the file is refused with the line."""
    from modbus_bridge.interface import defaults_of

    tcp = "    tcp: {host: 127.0.0.1, port: 1502}\n"
    assert defaults_of(load(write(tmp_path, GOOD)).device).max_in_flight == 1
    pipelined = GOOD.replace(tcp, "    tcp: {host: 127.0.0.1, port: 1502, max_in_flight: 13}\n")
    assert defaults_of(load(write(tmp_path, pipelined)).device).max_in_flight == 13
    too_many = GOOD.replace(tcp, "    tcp: {host: 127.0.0.1, port: 1502, max_in_flight: 17}\n")
    with pytest.raises(DescriptionError, match=r"device\.link\.tcp\.max_in_flight"):
        load(write(tmp_path, too_many))
