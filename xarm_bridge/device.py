"""xArm device model: polls into typed snapshots, commands into checked writes (no ROS).

Every command validates all of its inputs before its first write, so a refused command
writes nothing; writes to channels the manual does not call valid never reach the wire.
The arm's joint count (5, 6 or 7) and the user coils it reads (a range of C256-511, or
none) are fixed when the device is made: they shape the poll and the snapshot. The
output writes are in outputs.py; what a stop, pause, start or task reads back to be done,
in arm_state.py. "xArm decision N" is reading N of docs/decisions/xarm.md.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from bridge_core.runtime.checks import check_index, check_whole_number
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S, PollGroups
from bridge_core.runtime.reads import read_blocks, read_named
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value
from bridge_core.wire.errors import (
    CommandRejected,
    ConfigurationError,
    DeviceException,
    LinkError,
    NotConfirmed,
)
from bridge_core.wire.planner import ReadRequest, plan_reads

from . import outputs
from .arm_state import (
    MODE_ADDRESS,
    STATE_ADDRESS,
    ArmReading,
    confirm,
    read_arm,
    signed,
)
from .registers import (
    COIL_FENCE_MODE,
    COIL_PAUSED,
    COIL_REDUCED_MODE,
    COIL_STOPPED,
    CONTROLLER_ANALOG_INPUT_VALID,
    CONTROLLER_DIGITAL_VALID,
    ENABLE_FIRST,
    JOINT_COUNTS,
    JOINTS,
    MOTION_MODES,
    OFFLINE_TASK_ADDRESS,
    OFFLINE_TASK_MAX,
    ROTATION_VECTOR,
    SET_STATE_PAUSE,
    SET_STATE_START,
    SET_STATE_STOP,
    SETTABLE_STATES,
    TOOL_ANALOG_INPUT_VALID,
    TOOL_DIGITAL_VALID,
    USER_COILS,
    WORLD,
    WRITABLE_ANALOG_OUTPUTS,
    XARM_MAP,
)

TASK_NUMBER_MIN = 1
TASK_NUMBER_MAX = 0xFFFF


@dataclass(frozen=True)
class XArmSnapshot:
    """One full poll in the manual's units (deg, deg/s, mm, mm/s, V, kg, degC).

    Per-joint tuples hold the arm's joints only (``joint_count`` of them, J1 first)."""

    read_time: float  # wall clock when the joint angles (read last) were requested
    slow_read_time: float  # wall clock when the slow group (xArm decision 18) was read
    mode: int
    state: int
    error_code: int
    warning_code: int
    joint_angles_deg: tuple[float, ...]
    joint_speeds_deg_s: tuple[float, ...]
    joint_temperatures_c: tuple[float, ...]
    tcp_pose: dict[str, float]  # x y z (mm), roll pitch yaw (deg)
    tcp_rotation_vector_deg: tuple[float, float, float]  # rx ry rz: axis times angle (deg)
    tcp_speed_mm_s: float
    counter: int
    brakes: tuple[bool, ...]
    enabled: tuple[bool, ...]
    reduced_mode: bool
    fence_mode: bool
    paused: bool
    stopped: bool
    motion_modes: tuple[bool, ...]
    digital_inputs: tuple[bool, ...]
    digital_outputs: tuple[bool, ...]
    tool_digital_inputs: tuple[bool, ...]
    tool_digital_outputs: tuple[bool, ...]
    analog_inputs: tuple[float, ...]
    tool_analog_inputs: tuple[float, ...]
    analog_outputs: tuple[float, ...]
    tcp_load_mass_kg: float
    tcp_load_center_mm: tuple[float, float, float]
    tcp_offset: dict[str, float]
    base_offset: dict[str, float]
    user_coils: tuple[bool, ...] = ()  # the configured range of C256-511, first coil first


def _joint_names(kind: str, joint_count: int) -> tuple[str, ...]:
    return tuple(f"{kind}_{j}" for j in range(1, joint_count + 1))


def _user_coil_names(coils: range) -> tuple[str, ...]:
    return tuple(f"user_coil_{address - USER_COILS.start}" for address in coils)


def _poll_names(joint_count: int, user_coils: range) -> list[str]:
    names = [f"controller_do_{i}" for i in range(CONTROLLER_DIGITAL_VALID)]
    names += [f"tool_do_{i}" for i in range(TOOL_DIGITAL_VALID)]
    names += [f"controller_di_{i}" for i in range(CONTROLLER_DIGITAL_VALID)]
    names += [f"tool_di_{i}" for i in range(TOOL_DIGITAL_VALID)]
    names += _joint_names("brake", joint_count) + _joint_names("enable", joint_count)
    names += ["reduced_mode", "fence_mode", "paused", "stopped"]
    names += [f"motion_mode_{m}" for m in range(MOTION_MODES)]
    names += _user_coil_names(user_coils)
    names += [f"controller_ao_{i}" for i in WRITABLE_ANALOG_OUTPUTS]
    names += ["arm_mode", "arm_state", "error_code", "warning_code", "counter"]
    names += [f"controller_ai_{i}" for i in range(CONTROLLER_ANALOG_INPUT_VALID)]
    names += [f"tool_ai_{i}" for i in range(TOOL_ANALOG_INPUT_VALID)]
    names += [f"tcp_{a}" for a in (*WORLD, *ROTATION_VECTOR)]
    names += ["tcp_load_mass", "tcp_load_center_x", "tcp_load_center_y", "tcp_load_center_z"]
    names += [f"tcp_offset_{a}" for a in WORLD] + [f"base_offset_{a}" for a in WORLD]
    names += _joint_names("joint_angle", joint_count)
    names += _joint_names("joint_temperature", joint_count)
    names += _joint_names("joint_speed", joint_count)
    names += ["tcp_speed"]
    return names


def poll_plan(joint_count: int = JOINTS, user_coils: range = range(0)) -> list[ReadRequest]:
    """The requests of one poll: 8 (the reserved rows split the tables), one more for
    user coils. The joint angles last: their read time stamps joint_states, and a joint
    change then reaches the message soonest (latency figure of bench/bridge_bench.py)."""
    plan = plan_reads(XARM_MAP, XARM_MAP.select(_poll_names(joint_count, user_coils)))
    plan.sort(key=lambda request: XARM_MAP["joint_angle_1"] in request.registers)
    return plan


POLL_PLAN: list[ReadRequest] = poll_plan()  # a 7-joint arm, no user coils (the defaults)

ROTATION_VECTOR_NAMES = tuple(f"tcp_{a}" for a in ROTATION_VECTOR)
_MOTION_MODES = tuple(f"motion_mode_{m}" for m in range(MOTION_MODES))
_DI = tuple(f"controller_di_{k}" for k in range(CONTROLLER_DIGITAL_VALID))
_DO = tuple(f"controller_do_{k}" for k in range(CONTROLLER_DIGITAL_VALID))
_TOOL_DI = tuple(f"tool_di_{k}" for k in range(TOOL_DIGITAL_VALID))
_TOOL_DO = tuple(f"tool_do_{k}" for k in range(TOOL_DIGITAL_VALID))
_AI = tuple(f"controller_ai_{k}" for k in range(CONTROLLER_ANALOG_INPUT_VALID))
_TOOL_AI = tuple(f"tool_ai_{k}" for k in range(TOOL_ANALOG_INPUT_VALID))
_AO = tuple(f"controller_ao_{k}" for k in WRITABLE_ANALOG_OUTPUTS)
_TCP = tuple((a, f"tcp_{a}") for a in WORLD)
_TCP_OFFSET = tuple((a, f"tcp_offset_{a}") for a in WORLD)
_BASE_OFFSET = tuple((a, f"base_offset_{a}") for a in WORLD)


def check_user_coils(coils: range) -> range:
    """A configured user-coil range: consecutive, inside C256-511 (ConfigurationError)."""
    if coils.step != 1 or (
        len(coils) and (coils.start not in USER_COILS or coils[-1] not in USER_COILS)
    ):
        raise ConfigurationError(
            f"user coils {coils.start}-{coils.stop - 1} outside "
            f"{USER_COILS.start}-{USER_COILS.stop - 1} (the manual's user-defined coils)"
        )
    return coils


class XArmDevice:
    """The xArm controller behind one Modbus channel: an arm of ``joint_count`` joints
    (5, 6 or 7), reading the ``user_coils`` range of C256-511 with every poll (none by
    default)."""

    def __init__(
        self,
        io: RegisterIO,
        joint_count: int = JOINTS,
        user_coils: range = range(0),
        slow_period_s: float = SLOW_POLL_PERIOD_DEFAULT_S,
    ) -> None:
        if isinstance(joint_count, bool) or joint_count not in JOINT_COUNTS:
            raise ConfigurationError(
                f"joint_count {joint_count!r} outside "
                f"{JOINT_COUNTS.start}-{JOINT_COUNTS.stop - 1} (xArm 5, xArm 6 / Lite 6, xArm 7)"
            )
        self.io = io
        self.joint_count = joint_count
        self.user_coils = check_user_coils(user_coils)
        self.plan = poll_plan(joint_count, user_coils)
        # The slow group (xArm decision 18): the analog outputs (H3-4) and the user
        # coils (C256-511) change only by writes, which refresh them at the next poll. The
        # digital outputs stay fast: an offline task the arm runs may switch them.
        slow_names = {*_AO, *_user_coil_names(user_coils)}
        slow = [r for r in self.plan if r.names <= slow_names]
        self.groups = PollGroups(
            [r for r in self.plan if r not in slow], slow, period_s=slow_period_s
        ).follow(io)
        self._angles = _joint_names("joint_angle", joint_count)
        self._speeds = _joint_names("joint_speed", joint_count)
        self._temperatures = _joint_names("joint_temperature", joint_count)
        self._brakes = _joint_names("brake", joint_count)
        self._enables = _joint_names("enable", joint_count)
        self._user_coils = _user_coil_names(user_coils)

    # ------------------------------------------------------------------ polling
    def read_plan(
        self, plan: Sequence[ReadRequest], priority: Priority, stamp: str | None = None
    ) -> tuple[dict[str, Value], float]:
        """Values of a plan, and the wall-clock time the block holding ``stamp`` was read."""
        return read_blocks(self.io, plan, priority, stamp)

    def read_named(self, *names: str) -> dict[str, Value]:
        return read_named(self.io, XARM_MAP, names)

    def poll(self) -> XArmSnapshot:
        # The angles are read last (a change reaches joint_states soonest) and stamp it.
        read = self.groups.read(self.io, self._angles[0])
        v = read.values

        def floats(names: tuple[str, ...]) -> tuple[float, ...]:
            return tuple(float(v[n]) for n in names)

        def bools(names: tuple[str, ...]) -> tuple[bool, ...]:
            return tuple(bool(v[n]) for n in names)

        def pose(names: tuple[tuple[str, str], ...]) -> dict[str, float]:
            return {axis: float(v[name]) for axis, name in names}

        rx, ry, rz = floats(ROTATION_VECTOR_NAMES)
        return XArmSnapshot(
            read_time=read.read_time,
            slow_read_time=read.slow_read_time,
            mode=int(v["arm_mode"]),
            state=int(v["arm_state"]),
            error_code=int(v["error_code"]),
            warning_code=int(v["warning_code"]),
            joint_angles_deg=floats(self._angles),
            joint_speeds_deg_s=floats(self._speeds),
            joint_temperatures_c=floats(self._temperatures),
            tcp_pose=pose(_TCP),
            tcp_rotation_vector_deg=(rx, ry, rz),
            tcp_speed_mm_s=float(v["tcp_speed"]),
            counter=int(v["counter"]),
            brakes=bools(self._brakes),
            enabled=bools(self._enables),
            reduced_mode=bool(v["reduced_mode"]),
            fence_mode=bool(v["fence_mode"]),
            paused=bool(v["paused"]),
            stopped=bool(v["stopped"]),
            motion_modes=bools(_MOTION_MODES),
            digital_inputs=bools(_DI),
            digital_outputs=bools(_DO),
            tool_digital_inputs=bools(_TOOL_DI),
            tool_digital_outputs=bools(_TOOL_DO),
            analog_inputs=floats(_AI),
            tool_analog_inputs=floats(_TOOL_AI),
            analog_outputs=floats(_AO),
            tcp_load_mass_kg=float(v["tcp_load_mass"]),
            tcp_load_center_mm=(
                float(v["tcp_load_center_x"]),
                float(v["tcp_load_center_y"]),
                float(v["tcp_load_center_z"]),
            ),
            tcp_offset=pose(_TCP_OFFSET),
            base_offset=pose(_BASE_OFFSET),
            user_coils=bools(self._user_coils),
        )

    # ------------------------------------------------------------------ commands
    def set_mode(self, mode: int) -> None:
        """H32 with FC 06, as the manual's FC 06 example (mode 6). As with the xArm SDK, a
        new mode takes effect after set_state 0."""
        if not isinstance(mode, int) or not 0 <= mode < MOTION_MODES:
            raise CommandRejected(f"mode {mode!r} outside 0-{MOTION_MODES - 1}")
        self.io.write_register(MODE_ADDRESS, mode)

    def set_state(self, state: int) -> tuple[int, int]:
        """Write H33 (0 start, 3 pause, 4 stop) and read H32-33 back (FC 0x17), once: what
        the state machine does with it is for ``command_state`` to confirm."""
        if state not in SETTABLE_STATES:
            raise CommandRejected(
                f"state {state!r} refused: the controller takes 0 (start), 3 (pause), 4 (stop)"
            )
        mode_now, state_now = self.io.read_write_registers(MODE_ADDRESS, 2, STATE_ADDRESS, [state])
        return signed(mode_now), signed(state_now)

    def read_arm(self) -> ArmReading:
        """H32-33, the error code I32 and the coils C144-145, at command priority."""
        return read_arm(self.io)

    def halt(self, kind: str) -> str:
        """``stop`` / ``pause``: the coil the manual names (C145 "停止运动控制", C144
        "暂停运动控制", FC 05 = 1) and at once, without waiting for the arm, H33 = 4 / 3
        (the xArm SDK's set_state, FC 0x17), so a firmware that ignores the coil stops
        one round trip later, not after a wait (xArm decision 19). Done only when H33
        read back shows it (4 stopped; a pause 3, or 4): the coils are not proof, a
        firmware may keep them as written. A coil the controller refuses (an exception
        reply), or whose reply is lost, does not hold back H33."""
        coil, state = (
            (COIL_STOPPED, SET_STATE_STOP) if kind == "stop" else (COIL_PAUSED, SET_STATE_PAUSE)
        )
        refused = ""
        lost: LinkError | None = None
        try:
            self.io.write_coil(coil, True)
        except DeviceException as err:
            refused = f" (refused: {err})"
        except LinkError as err:  # no reply to the coil: H33 is still tried at once
            lost, refused = err, f" (no reply: {err})"
        try:
            self.set_state(state)
        except LinkError:
            if lost is not None:
                raise lost from None
            raise
        return confirm(self.io, kind, f"C{coil} = 1{refused} and H33 = {state}")

    def pause(self) -> str:
        return self.halt("pause")

    def stop(self) -> str:
        return self.halt("stop")

    def start(self) -> str:
        """H33 = 0 (the SDK's set_state 0: resume a paused task, make a stopped arm ready,
        put a new mode in force), done only when the state read back shows the arm
        ready or moving with no error (xArm decision 20): an arm in error stays in
        state 4 and does not move."""
        self.set_state(SET_STATE_START)
        return confirm(self.io, "start", f"H33 = {SET_STATE_START}")

    def resume(self) -> str:
        return self.start()

    def command_state(self, state: int) -> str:
        """``~/set_state``: 0 as ``start``, 3 and 4 written to H33 alone (as asked) and
        confirmed as a pause / stop (xArm decisions 19, 20)."""
        if state == SET_STATE_START:
            return self.start()
        self.set_state(state)
        return confirm(self.io, "stop" if state == SET_STATE_STOP else "pause", f"H33 = {state}")

    def set_joint_enable(self, joint: int, enable: bool) -> str:
        """Enable or disable joint ``joint`` (1..joint_count, coil 134 + joint, FC 05), or
        with 0 every joint of the arm (C135.., one FC 0F). The brake coils C128-134 are
        never written (xArm decision 12). Done only when the enable coils read back
        ("关节的使能状态") show it (a disable ends motion: xArm decision 20)."""
        check_index("joint", joint, range(0, self.joint_count + 1))
        first, count = (
            (ENABLE_FIRST, self.joint_count)
            if joint == 0
            else (
                ENABLE_FIRST + joint - 1,
                1,
            )
        )
        if joint == 0:
            self.io.write_coils(ENABLE_FIRST, [bool(enable)] * self.joint_count)
        else:
            self.io.write_coil(ENABLE_FIRST + joint - 1, bool(enable))
        seen = self.io.read_bits(first, count, priority=Priority.COMMAND)
        wrote = f"wrote C{first}{f'-{first + count - 1}' if count > 1 else ''} = {int(enable)}"
        reads = " ".join(str(int(bit)) for bit in seen)
        if any(bool(bit) != bool(enable) for bit in seen):
            raise NotConfirmed(f"{wrote}, reads {reads}")
        return f"{wrote}, reads {reads}"

    # ------------------------------------------------------------------ outputs (outputs.py)
    def set_digital_output(self, index: int, on: bool) -> None:
        """Controller DO 0-15 (FC 05 to coil ``index``)."""
        outputs.set_digital_output(self.io, index, on)

    def set_tool_digital_output(self, index: int, on: bool) -> None:
        """Tool DO 0-1 (FC 05 to coil 32 + ``index``)."""
        outputs.set_tool_digital_output(self.io, index, on)

    def write_digital_outputs(self, first: int, values: Sequence[bool]) -> None:
        """Consecutive controller DOs in one FC 0F write."""
        outputs.write_digital_outputs(self.io, first, values)

    def set_digital_outputs(self, indexes: Sequence[int], states: Sequence[bool]) -> str:
        """Controller DOs ``indexes[k]`` to ``states[k]``, a run of consecutive indexes
        per FC 0F write (xArm decision 9); returns what was written."""
        return outputs.set_digital_outputs(self.io, indexes, states)

    def set_user_coils(self, addresses: Sequence[int], states: Sequence[bool]) -> str:
        """User coils within the configured range, written like ``set_digital_outputs``."""
        return outputs.set_user_coils(self.io, self.user_coils, addresses, states)

    def change_digital_outputs(self, changes: Mapping[int, bool]) -> None:
        """Several controller DOs in one FC 0x16 mask write to H0 (device layer only)."""
        outputs.change_digital_outputs(self.io, changes)

    def set_analog_output(self, channel: int, volts: float) -> None:
        """Controller AO 0-1 in volts (x1000, signed 16-bit, FC 06)."""
        outputs.set_analog_output(self.io, channel, volts)

    def set_analog_outputs(self, volts: Sequence[float]) -> None:
        """Controller AO 0.. in one FC 10 write."""
        outputs.set_analog_outputs(self.io, volts)

    def set_reduced_mode(self, on: bool, confirm: str = "") -> str:
        return self._set_safety_mode("set_reduced_mode", COIL_REDUCED_MODE, on, confirm)

    def set_fence_mode(self, on: bool, confirm: str = "") -> str:
        return self._set_safety_mode("set_fence_mode", COIL_FENCE_MODE, on, confirm)

    def _set_safety_mode(self, name: str, coil: int, on: bool, confirm: str) -> str:
        """C142 / C143 "(0关闭, 1开启)". Switching a safety mode off runs only when
        ``confirm`` repeats the service's name (xArm decision 17), like the
        stepper's destructive coils; the coil is read back and the reply says what it
        holds."""
        if not on and confirm != name:
            raise CommandRejected(
                f"switching {name.removeprefix('set_').replace('_', ' ')} off lifts a safety "
                f"limit: send confirm: {name!r} to mean it"
            )
        self.io.write_coil(coil, bool(on))
        (seen,) = self.io.read_bits(coil, 1, priority=Priority.COMMAND)
        if bool(seen) != bool(on):
            raise NotConfirmed(f"C{coil}: wrote {int(on)}, reads {int(seen)}")
        return f"C{coil} reads {int(seen)}"

    def run_offline_task(self, projects: Sequence[int]) -> str:
        """Up to 16 Blockly project numbers with FC 10 at 0x30 (the only way the manual
        allows), done only when the state read back shows the arm in motion with no
        error (xArm decision 20)."""
        if not 1 <= len(projects) <= OFFLINE_TASK_MAX:
            raise CommandRejected(f"give 1-{OFFLINE_TASK_MAX} project numbers, not {len(projects)}")
        for number in projects:
            check_whole_number("project number", number, TASK_NUMBER_MIN, TASK_NUMBER_MAX)
        self.io.write_registers(OFFLINE_TASK_ADDRESS, list(projects))
        listed = " ".join(str(p) for p in projects)
        return confirm(self.io, "task", f"projects {listed} at H{OFFLINE_TASK_ADDRESS}")
