"""The xArm's commissioning reads: the facts, the poll, and the read-only checks that the
rows of ``xarm_bridge/commission.py`` name (``bridge_commission xarm``,
docs/commissioning.md). The guided steps are in commission_guided.py.

They read through the bridge's own device (``XArmDevice``) and the row scan of the
read-only phase, so a check reads what the bridge reads. No ROS here. "xArm decision N"
is reading N of docs/decisions/xarm.md.
"""

from __future__ import annotations

from bridge_core.runtime.commission import Finding, Probe, Verdict
from bridge_core.runtime.units import (
    euler_xyz_deg_to_quaternion,
    quaternion_angle_deg,
    rotation_vector_deg_to_quaternion,
)
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import words_to_int
from bridge_core.wire.errors import DeviceException
from bridge_core.wire.registers import Register, Table, ValueType, WordOrder

from .arm_state import MODE_ADDRESS
from .device import XArmDevice
from .registers import (
    CONTROLLER_ANALOG_INPUT_VALID,
    CONTROLLER_DIGITAL_VALID,
    JOINT_COUNTS,
    JOINTS,
    ORIENTATION_MISMATCH_DEG,
    TOOL_ANALOG_INPUT_VALID,
    TOOL_DIGITAL_VALID,
    USER_COILS,
    XARM_MAP,
    error_text,
    mode_name,
    state_name,
    warning_text,
)

# Decision 4: what a scaled value may plausibly read on a working arm, by unit. Each
# bound is below 3276.8 (x10) / 32.768 (x1000), so a word of 0x8000 or more read unsigned
# is always beyond it: a negative value tells signed from unsigned.
PLAUSIBLE = {
    "deg": 720.0,  # joint angles (two turns), roll/pitch/yaw, rx/ry/rz
    "deg/s": 1000.0,  # joint speeds
    "mm": 3000.0,  # TCP position, offsets, load centre: reach and tool together
    "mm/s": 5000.0,  # TCP speed
    "kg": 20.0,  # TCP load
    "V": 12.0,  # analog inputs (0-10 V)
    "degC": 150.0,  # joint temperatures
}
# Decisions 1 and 11: a joint that is there reads a temperature in this range (degC).
TEMPERATURE_PLAUSIBLE_C = (1, 120)
LISTED_MAX = 6  # values named in one finding; the rest counted


def device(probe: Probe) -> XArmDevice:
    found = probe.device
    assert isinstance(found, XArmDevice), "setup() runs first"
    return found


def ping(io: RegisterIO) -> object:
    """One short read, timed for the reply times: mode and state (H32-33)."""
    return io.read_registers(MODE_ADDRESS, 2, priority=Priority.COMMAND)


def _user_coils(probe: Probe) -> range:
    first = int(probe.values.get("user_coil_first", USER_COILS.start))
    return range(first, first + int(probe.values.get("user_coil_count", 0)))


def setup(probe: Probe) -> None:
    """The bridge's device as the parameters make it, and the arm's facts (reads only)."""
    arm = XArmDevice(
        probe.io, int(probe.values.get("joint_count", JOINTS)), user_coils=_user_coils(probe)
    )
    probe.device = arm
    values = arm.read_named(
        "arm_mode", "arm_state", "error_code", "warning_code", "reduced_mode", "fence_mode"
    )
    mode, state = int(values["arm_mode"]), int(values["arm_state"])
    error, warning = int(values["error_code"]), int(values["warning_code"])
    probe.facts.update(
        {
            "firmware": "not offered over Modbus (the manual lists no version register)",
            "joint_count (parameter)": str(arm.joint_count),
            "mode (H32)": f"{mode} ({mode_name(mode)})",
            "state (H33)": f"{state} ({state_name(state)})",
            "error (I32)": f"{error} {error_text(error)}".rstrip(),
            "warning (I33)": f"{warning} {warning_text(warning)}".rstrip(),
            "reduced / fence mode (C142-143)": (
                f"{int(values['reduced_mode'])} / {int(values['fence_mode'])}"
            ),
            "watchdog": "none over Modbus: a running project keeps running if the host stops",
        }
    )


def requests_per_poll(probe: Probe) -> int:
    """The requests of one poll that reads no slow group (xArm decision 18)."""
    return len(device(probe).groups.fast)


def _index(name: str, prefix: str) -> int | None:
    tail = name.removeprefix(prefix)
    return int(tail) if tail != name and tail.isdigit() else None


def refusal_reason(reg: Register, probe: Probe) -> str | None:
    """Why the controller may refuse ``reg`` by the bridge's readings, or None."""
    for prefix in ("joint_angle_", "joint_speed_", "joint_temperature_", "brake_", "enable_"):
        joint = _index(reg.name, prefix)
        if joint is not None and joint > device(probe).joint_count:
            return f"J{joint} past joint_count {device(probe).joint_count} (decision 11)"
    if reg.name.startswith("tool_ao_"):
        return "tool AO has no valid channel (decision 8)"
    for prefix, valid in (
        ("controller_do_", CONTROLLER_DIGITAL_VALID),
        ("controller_di_", CONTROLLER_DIGITAL_VALID),
        ("tool_do_", TOOL_DIGITAL_VALID),
        ("tool_di_", TOOL_DIGITAL_VALID),
        ("controller_ai_", CONTROLLER_ANALOG_INPUT_VALID),
        ("tool_ai_", TOOL_ANALOG_INPUT_VALID),
    ):
        channel = _index(reg.name, prefix)
        if channel is not None and channel >= valid:
            return f"not one of the {valid} valid channels (decision 3)"
    coil = _index(reg.name, "user_coil_")
    if coil is not None and USER_COILS.start + coil not in _user_coils(probe):
        return "a user coil outside user_coil_first/user_coil_count (decision 14)"
    return None


def _listed(items: list[str]) -> str:
    shown = ", ".join(items[:LISTED_MAX])
    return shown + (f" and {len(items) - LISTED_MAX} more" if len(items) > LISTED_MAX else "")


def _in_use(reg: Register, joint_count: int) -> bool:
    """A row of a joint the arm has, or of a valid channel."""
    for prefix in ("joint_angle_", "joint_speed_", "joint_temperature_"):
        joint = _index(reg.name, prefix)
        if joint is not None:
            return joint <= joint_count
    for prefix, valid in (
        ("controller_ai_", CONTROLLER_ANALOG_INPUT_VALID),
        ("tool_ai_", TOOL_ANALOG_INPUT_VALID),
    ):
        channel = _index(reg.name, prefix)
        if channel is not None:
            return channel < valid
    return True


# ---------------------------------------------------------------- read-only checks
def signed_values(probe: Probe) -> Finding:
    """Decision 4: every signed 16-bit input row the scan read (scaled by 10 or 1000, and
    the temperatures) plausible as signed; the negative ones tell signed from unsigned."""
    assert probe.rows is not None
    joint_count = device(probe).joint_count
    negative: list[str] = []
    absurd: list[str] = []
    for reg in XARM_MAP:
        words = probe.rows.answered.get(reg.name)
        if reg.table is not Table.INPUT or reg.value_type is not ValueType.I16 or not words:
            continue
        bound = PLAUSIBLE.get(reg.unit)
        if bound is None or not _in_use(reg, joint_count):
            continue
        value = words_to_int(words, True, WordOrder.HIGH_FIRST) / reg.scale
        seen = f"{reg.name} {value:g} {reg.unit}"
        if abs(value) > bound:
            absurd.append(seen)
        elif value < 0:
            unsigned = words_to_int(words, False, WordOrder.HIGH_FIRST) / reg.scale
            negative.append(f"{seen} (unsigned: {unsigned:g})")
    if absurd:
        return Finding(
            Verdict.CONTRADICTED,
            f"values no arm reports, read as the manual's signed x10 / x1000: {_listed(absurd)}: "
            "this firmware sends these rows another way; do not trust the pose and joints "
            "the bridge publishes, tell us",
        )
    if not negative:
        return Finding(
            Verdict.UNCLEAR,
            "every signed row reads 0 or more, where signed and unsigned agree: move a joint "
            "to a negative angle and run this again",
        )
    return Finding(
        Verdict.CONFIRMED,
        f"{len(negative)} negative values, plausible only as signed: {_listed(negative)}",
    )


def counter_word_order(probe: Probe) -> Finding:
    """Decision 4: the counter I34-35 as the scan read it, and once more now. A counter
    that moved between the two changed its low word; one that stands is judged by which
    word is 0 (a count below 65536 read the other way is 65536 times larger)."""
    assert probe.rows is not None
    first = probe.rows.answered.get("counter")
    if not first:
        return Finding(Verdict.UNCLEAR, "the counter (I34-35) did not answer")
    reg = XARM_MAP["counter"]
    now = probe.io.read_registers(reg.address, reg.count, Table.INPUT, Priority.COMMAND)
    high = words_to_int(now, False, WordOrder.HIGH_FIRST)
    low = words_to_int(now, False, WordOrder.LOW_FIRST)
    read = f"I34-35 read {first[0]:#06x} {first[1]:#06x}, then {now[0]:#06x} {now[1]:#06x}"
    if now != first:
        if now[0] == first[0]:
            return Finding(Verdict.CONFIRMED, f"{read}: the second word counts (the low)")
        if now[1] == first[1]:
            return Finding(
                Verdict.CONTRADICTED,
                f"{read}: the first word counts, so the counter is low word first: the "
                "bridge's `counter` is wrong on this firmware; tell us",
            )
        return Finding(Verdict.UNCLEAR, f"{read}: both words changed")
    if now[0] == 0 and now[1] != 0:
        return Finding(
            Verdict.CONFIRMED, f"{read}: high word first reads {high}, low word first {low}"
        )
    if now[1] == 0 and now[0] != 0:
        return Finding(
            Verdict.CONTRADICTED,
            f"{read}: only low word first gives a count below 65536 ({low}; high word first "
            f"{high}): the bridge's `counter` is wrong on this firmware; tell us",
        )
    return Finding(
        Verdict.UNCLEAR,
        f"{read}: settles neither order; run a project that counts and run this again",
    )


def joints(probe: Probe) -> Finding:
    """Decisions 1 and 11: the joint temperatures at I96-102; the joints the arm has read
    a plausible temperature, the rows past them 0: how many joints the arm has."""
    assert probe.rows is not None
    low, high = TEMPERATURE_PLAUSIBLE_C
    read: list[int] = []
    for j in range(1, JOINTS + 1):
        words = probe.rows.answered.get(f"joint_temperature_{j}")
        read.append(words_to_int(words, True, WordOrder.HIGH_FIRST) if words else 0)
    shown = " ".join(str(t) for t in read)
    count = next((j for j in range(JOINTS, 0, -1) if read[j - 1] != 0), 0)
    given = device(probe).joint_count
    if count == 0:
        return Finding(Verdict.UNCLEAR, f"every joint temperature (I96-102) reads 0: {shown}")
    if any(not low <= t <= high for t in read[:count]):
        return Finding(
            Verdict.CONTRADICTED,
            f"I96-102 read {shown} degC: not the joints' temperatures (the manual's other "
            "row, 86, or another layout): tell us",
        )
    if count not in JOINT_COUNTS:
        return Finding(Verdict.UNCLEAR, f"I96-102 read {shown} degC: {count} joints, no xArm")
    if count != given:
        return Finding(
            Verdict.CONTRADICTED,
            f"I96-102 read {shown} degC: an arm of {count} joints, but joint_count is "
            f"{given}: set joint_count to {count} (check it against the arm's label)",
            {"joint_count": count},
        )
    return Finding(
        Verdict.CONFIRMED,
        f"I96-102 read {shown} degC: {count} joints, as joint_count",
        {"joint_count": count},
    )


def reserved_gaps() -> list[tuple[Table, int]]:
    """The first address of every gap between the rows of each table of the map (the
    reserved rows, decision 2's I36-63 among them)."""
    gaps: list[tuple[Table, int]] = []
    for table in Table:
        rows = sorted((r for r in XARM_MAP if r.table is table), key=lambda r: r.address)
        end = rows[0].end if rows else 0
        for reg in rows[1:]:
            if reg.address > end:
                gaps.append((table, end))
            end = max(end, reg.end)
    return gaps


def reserved_rows(probe: Probe) -> Finding:
    """Decision 2: the first register (or coil) of every gap between the map's rows, read
    alone; the controller refuses each (0x02), as the bridge plans its reads."""
    answered: list[str] = []
    gaps = reserved_gaps()
    for table, address in gaps:
        try:
            if table.is_bit:
                probe.io.read_bits(address, 1, table, Priority.COMMAND)
            else:
                probe.io.read_registers(address, 1, table, Priority.COMMAND)
        except DeviceException:
            continue
        answered.append(f"{table.value} {address}")
    if answered:
        return Finding(
            Verdict.CONTRADICTED,
            f"{len(answered)} of {len(gaps)} reserved addresses answered: {_listed(answered)} "
            "(harmless: the bridge never reads across them), tell us",
        )
    return Finding(
        Verdict.CONFIRMED, f"the first address of each of the {len(gaps)} reserved gaps refused"
    )


def rotation_vector(probe: Probe) -> Finding:
    """Decision 13: the orientation of roll/pitch/yaw (fixed axes, as ``~/tcp_pose``) and
    of rx/ry/rz agree within ``ORIENTATION_MISMATCH_DEG``; settled only where the other
    reading (moving axes) gives another orientation."""
    pose = device(probe).read_named(
        *(f"tcp_{a}" for a in ("roll", "pitch", "yaw", "rx", "ry", "rz"))
    )
    roll, pitch, yaw, rx, ry, rz = (float(v) for v in pose.values())
    fixed = euler_xyz_deg_to_quaternion(roll, pitch, yaw)
    moving = euler_xyz_deg_to_quaternion(-roll, -pitch, -yaw)  # R = Rx Ry Rz, inverted
    moving = (-moving[0], -moving[1], -moving[2], moving[3])
    vector = rotation_vector_deg_to_quaternion(rx, ry, rz)
    off = quaternion_angle_deg(fixed, vector)
    other = quaternion_angle_deg(moving, vector)
    read = (
        f"roll/pitch/yaw {roll:g} {pitch:g} {yaw:g}, rx/ry/rz {rx:g} {ry:g} {rz:g}: "
        f"{off:.1f} deg apart (about the moving axes: {other:.1f} deg)"
    )
    if quaternion_angle_deg(fixed, moving) <= 2 * ORIENTATION_MISMATCH_DEG:
        return Finding(
            Verdict.UNCLEAR,
            f"{read}: this orientation reads alike either way; turn the tool so that two of "
            "roll, pitch, yaw are off 0 and 180, and run this again",
        )
    if off <= ORIENTATION_MISMATCH_DEG:
        return Finding(Verdict.CONFIRMED, read)
    if other <= ORIENTATION_MISMATCH_DEG:
        return Finding(
            Verdict.CONTRADICTED,
            f"{read}: roll/pitch/yaw are about the moving axes on this firmware: "
            "~/tcp_pose's orientation is wrong; use `tcp_rotation_vector` of ~/state, tell us",
        )
    return Finding(Verdict.CONTRADICTED, f"{read}: neither reading matches rx/ry/rz; tell us")
