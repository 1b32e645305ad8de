"""Simulator of the xArm controller's Modbus TCP interface, on the shared simulator base.

Behaviour:
- serves the appendix tables; reserved rows answer 0x02, function codes other than
  01 02 03 04 05 06 0F 10 16 17 answer 0x01 (the manual's exception list);
- an arm of ``joints`` joints (5, 6 or 7; ``--joints``): the rows of the joints it lacks
  read 0 and their enable coils stay 0;
- offline tasks (FC 10 at 0x30 only, at most 16 registers) put the arm in motion
  (state 1) for ``TASK_SECONDS`` per project: its joints move, speeds and TCP pose follow
  (roll/pitch/yaw and the rotation vector rx/ry/rz describe one orientation);
- H33 (set_state) 3 pauses, 4 stops (cancels the task), 0 resumes a paused task or makes
  a stopped arm ready (2); the pause/stop coils C144/C145 mirror the state and act alike;
- mode H32 0-13 takes effect at the next accepted set_state 0, as the xArm SDK says of
  set_mode: until then H32 and the mode coils C146-159 read the mode in force;
- brakes and enables follow their coils (C128-134 brake, 1 = released, the xArm SDK's
  reading; C135-141 enable): enabling a joint releases its brake, disabling it engages
  it; the arm moves only with every joint enabled and released (the SDK's "ready"), so a
  start (set_state 0, an offline task) is refused with state 4 otherwise, and a joint
  disabled or braked in motion stops the arm (state 4, the task cancelled);
- DO coils and the H0/H2 words stay consistent (bit n of the word = output n);
- error injection (``set_error``) stops the arm until cleared.

Personalities (docs/tools.md, "Device personalities"): ``--ignore NAME,...`` (the motion
writes of ``IGNORABLE``: acknowledged, nothing stored, no motion) and
``--coils-as-written`` (``coils_as_written``): C144 / C145 read back what was last
written to them, ignored writes too, not the arm's state (a firmware that stores the coil
and leaves the arm as it is). The other readings that ``bridge_commission xarm`` tells
apart (xarm_bridge/commission.py): ``--counter-low-first`` (``counter_low_first``: the
counter I34-35 low word first, decision 4), ``--answer-reserved`` (``answer_reserved``:
reserved rows answer 0, not 0x02, decision 2) and ``--euler-moving-axes``
(``euler_moving_axes``: roll/pitch/yaw about the moving axes, so rx/ry/rz describe
another orientation than the bridge's fixed-axis reading, decision 13) and
``--starts-in-error`` (``starts_in_error``: a start, H33 = 0 or an offline task, is taken
while an error shows, and the error stays shown, decision 20) and ``--safety-modes-fixed``
(``safety_modes_fixed``: writes to C142-143 are acknowledged and not applied, a controller
that refuses the change in its state, decision 17).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

from bridge_core.runtime.units import (
    DEG,
    euler_xyz_deg_to_quaternion,
    quaternion_to_rotation_vector_deg,
)
from bridge_core.sim.command_line import add_tcp_arguments, serve_tcp_until_signalled
from bridge_core.sim.logs import WriteRecord
from bridge_core.sim.personality import add_ignore_argument
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import (
    FUNCTION_TABLES,
    ILLEGAL_ADDRESS,
    ILLEGAL_FUNCTION,
    ILLEGAL_VALUE,
    SimulatedDevice,
)
from bridge_core.wire.registers import Table

from .registers import (
    BRAKE_FIRST,
    COIL_PAUSED,
    COIL_REDUCED_MODE,
    COIL_STOPPED,
    CONTROLLER_DIGITAL_CHANNELS,
    ENABLE_FIRST,
    FIRST_TOOL_DIGITAL,
    JOINT_COUNTS,
    JOINTS,
    MOTION_MODES,
    OFFLINE_TASK_ADDRESS,
    OFFLINE_TASK_MAX,
    TOOL_DIGITAL_CHANNELS,
    XARM_MAP,
)

IN_MOTION, SLEEPING, PAUSED, STOPPED = 1, 2, 3, 4
TASK_SECONDS = 5.0
AMPLITUDE_DEG = 40.0
PERIOD_S = 6.0


class XArmSimDevice(SimulatedDevice):
    # The motion writes xarm_bridge sends (xarm_bridge/device.py), for ``--ignore``; a
    # write may be several of them (C145 = 1 is ``stop_coil`` and ``stop``).
    IGNORABLE: ClassVar[Mapping[str, str]] = {
        "stop": "every stop: C145 = 1 and H33 = 4",
        "stop_coil": "C145, the stop coil (any value)",
        "stop_state": "H33 = 4 (set_state stop)",
        "pause": "every pause: C144 = 1 and H33 = 3",
        "pause_coil": "C144, the pause coil (any value)",
        "pause_state": "H33 = 3 (set_state pause)",
        "start": "H33 = 0 (resume, set_state 0)",
        "mode": "H32 (set_mode)",
        "enable": "C135-141, the joint enables",
        "run_offline_task": "FC 10 at 0x30 (an offline task)",
    }

    def __init__(self, unit_id: int = 1, joints: int = JOINTS) -> None:
        if joints not in JOINT_COUNTS:
            raise ValueError(f"joints {joints} outside {JOINT_COUNTS.start}-{JOINTS}")
        super().__init__(XARM_MAP, unit_id)
        self.joints = joints
        self.task_seconds_left = 0.0
        self.arm_state = SLEEPING  # the truth; H33 and C144/C145 mirror it
        self.mode = 0  # the mode in force; H32 and C146-159 mirror it
        self.pending_mode: int | None = None  # written to H32, in force after set_state 0
        self.enabled = [j <= joints for j in range(1, JOINTS + 1)]  # as the coils were
        self.phase = 0.0
        self.tasks_started: list[list[int]] = []
        # ``--coils-as-written``: C144 / C145 hold what was last written, not the state.
        self.coils_as_written = False
        # The other readings bridge_commission tells apart (xArm decisions 4, 2, 13).
        self.counter_low_first = False  # ``--counter-low-first``: I34-35 low word first
        self.answer_reserved = False  # ``--answer-reserved``: reserved rows answer 0
        self.euler_moving_axes = False  # ``--euler-moving-axes``: rx/ry/rz of R = Rx Ry Rz
        self.starts_in_error = False  # ``--starts-in-error``: starts taken, the error shown
        self.safety_modes_fixed = False  # ``--safety-modes-fixed``: C142-143 not changed
        self._safety_modes: list[int] = []  # C142-143 before a write, while fixed
        self.write_guards.append(self._guard)
        self.write_hooks.append(self._on_write)
        self.set_state(SLEEPING)
        self._set_mode(0)
        for j in range(1, joints + 1):
            self.set(f"enable_{j}", True)
            self.set(f"brake_{j}", True)  # released
            self.set(f"joint_temperature_{j}", 30 + j)
        self.set("tcp_load_mass", 0.5)
        self.set("tcp_load_center_z", 30.0)
        self.set("tcp_offset_z", 60.0)
        self._pose_from_joints()

    # ------------------------------------------------------------ controls for tests
    def set_state(self, state: int) -> None:
        with self.lock:
            self.arm_state = state
            self.set("arm_state", state)
            if not self.coils_as_written:
                self.set("paused", state == PAUSED)
                self.set("stopped", state == STOPPED)

    def set_error(self, code: int) -> None:
        with self.lock:
            self.set("error_code", code)
            if code:
                self.task_seconds_left = 0.0
                self.set_state(STOPPED)

    def set_warning(self, code: int) -> None:
        self.set("warning_code", code)

    def ready(self) -> bool:
        """Every joint of the arm enabled with its brake released (the SDK's is_ready)."""
        with self.lock:
            return all(
                self.get(f"enable_{j}") and self.get(f"brake_{j}")
                for j in range(1, self.joints + 1)
            )

    def set_input(self, index: int, on: bool) -> None:
        """Controller DI 0-31 or tool DI (32-39), with the DI words kept consistent."""
        with self.lock:
            tool = index >= FIRST_TOOL_DIGITAL
            name = f"tool_di_{index - FIRST_TOOL_DIGITAL}" if tool else f"controller_di_{index}"
            self.set(name, on)
            self._sync_words("controller_di", "controller_di_word", "tool_di", "tool_di_word")

    # ------------------------------------------------------------ Modbus behaviour
    def read(self, function_code: int, address: int, count: int) -> list[int] | int:
        """The read personalities: ``answer_reserved`` (a read of reserved rows only
        answers 0, not 0x02) and ``counter_low_first`` (the counter's words swapped)."""
        words = super().read(function_code, address, count)
        table = FUNCTION_TABLES[function_code]
        span = range(address, address + count)
        if isinstance(words, int):
            if self.answer_reserved and all(self.map.owner_at(table, a) is None for a in span):
                return [0] * count
            return words
        first = XARM_MAP["counter"].address
        if self.counter_low_first and table is Table.INPUT and first in span and first + 1 in span:
            k = first - address
            words[k], words[k + 1] = words[k + 1], words[k]
        return words

    def write_names(self, record: WriteRecord) -> frozenset[str]:
        """Which of ``IGNORABLE`` this write is."""
        names: set[str] = set()
        for address, value in zip(
            range(record.address, record.address + len(record.values)), record.values, strict=True
        ):
            if record.table is Table.COIL:
                if address == COIL_STOPPED:
                    names |= {"stop_coil", "stop"} if value else {"stop_coil"}
                elif address == COIL_PAUSED:
                    names |= {"pause_coil", "pause"} if value else {"pause_coil"}
                elif ENABLE_FIRST <= address < ENABLE_FIRST + JOINTS:
                    names.add("enable")
            elif record.table is Table.HOLDING:
                if address == 32:
                    names.add("mode")
                elif address == 33:
                    names |= _STATE_WRITE_NAMES.get(_signed(value), set())
                elif address == OFFLINE_TASK_ADDRESS:
                    names.add("run_offline_task")
        return frozenset(names)

    def _guard(self, record: WriteRecord) -> int | None:
        code = self._check_write(record)
        if self.safety_modes_fixed and record.table is Table.COIL:
            self._safety_modes = self.get_words(Table.COIL, COIL_REDUCED_MODE, 2)
        if code is None and self.coils_as_written and self.ignores(record):
            # Ignored (no motion), and still stored: the coil reads what was written.
            for address, value in zip(
                range(record.address, record.address + len(record.values)),
                record.values,
                strict=True,
            ):
                if record.table is Table.COIL and address in (COIL_PAUSED, COIL_STOPPED):
                    self.set_words(Table.COIL, address, [value])
        return code

    def _check_write(self, record: WriteRecord) -> int | None:
        span = range(record.address, record.address + len(record.values))
        if record.table is Table.HOLDING:
            if OFFLINE_TASK_ADDRESS in span or any(48 <= a <= 63 for a in span):
                if record.function_code != 16:
                    return ILLEGAL_FUNCTION
                if record.address != OFFLINE_TASK_ADDRESS or len(record.values) > OFFLINE_TASK_MAX:
                    return ILLEGAL_ADDRESS
            if 32 in span and not 0 <= _signed(record.values[32 - record.address]) < MOTION_MODES:
                return ILLEGAL_VALUE
            if 33 in span and _signed(record.values[33 - record.address]) not in (0, 3, 4):
                return ILLEGAL_VALUE
        return None

    def _on_write(self, record: WriteRecord) -> None:
        span = range(record.address, record.address + len(record.values))
        if record.table is Table.COIL:
            if self.safety_modes_fixed and self._safety_modes:
                # Acknowledged, not applied: the modes read as before the write.
                self.set_words(Table.COIL, COIL_REDUCED_MODE, self._safety_modes)
            if any(a < FIRST_TOOL_DIGITAL + TOOL_DIGITAL_CHANNELS for a in span):
                self._sync_words("controller_do", "controller_do_word", "tool_do", "tool_do_word")
            if any(BRAKE_FIRST <= a < ENABLE_FIRST + JOINTS for a in span):
                self._follow_joint_coils()
            if COIL_PAUSED in span:
                self._apply_state(3 if self.get("paused") else 0)
            if COIL_STOPPED in span and self.get("stopped"):
                self._apply_state(4)
            return
        if any(a in (0, 1, 2) for a in span):
            self._sync_bits()
        if 32 in span:
            # Taken, in force after the next accepted set_state 0 (maybe in this write).
            self.pending_mode = int(self.get("arm_mode"))
            self.set("arm_mode", self.mode)
        if 33 in span:
            self._apply_state(int(self.get("arm_state")))
        if record.address == OFFLINE_TASK_ADDRESS:
            projects = [v for v in record.values if v]
            self.tasks_started.append(projects)
            if (
                not self._refuses_starts()
                and self.arm_state in (IN_MOTION, SLEEPING)
                and self.ready()
            ):
                self.task_seconds_left += TASK_SECONDS * len(projects)
                self.set_state(IN_MOTION)
        # Controller AI read back what AO drives, so a demo shows the loop closed.
        for k in range(2):
            self.set(f"controller_ai_{k}", float(self.get(f"controller_ao_{k}")))

    def _apply_state(self, requested: int) -> None:
        """What the controller does with a set_state request, from its current state."""
        if requested == 3:
            self.set_state(PAUSED if self.arm_state in (IN_MOTION, PAUSED) else self.arm_state)
        elif requested == 4:
            self.task_seconds_left = 0.0
            self.set_state(STOPPED)
        elif requested == 0:
            if self._refuses_starts() or not self.ready():
                self.set_state(STOPPED)
            else:
                if self.pending_mode is not None:
                    self._set_mode(self.pending_mode)
                    self.pending_mode = None
                self.set_state(IN_MOTION if self.task_seconds_left > 0 else SLEEPING)

    def _refuses_starts(self) -> bool:
        """An error refuses a start, unless ``starts_in_error`` (the error still shown)."""
        return bool(int(self.get("error_code"))) and not self.starts_in_error

    def _set_mode(self, mode: int) -> None:
        self.mode = mode
        self.set("arm_mode", mode)
        for m in range(MOTION_MODES):
            self.set(f"motion_mode_{m}", m == mode)

    def _follow_joint_coils(self) -> None:
        """After a write to C128-141: a joint whose enable coil changed has its brake
        follow (released when enabled, engaged when disabled); a joint the arm lacks keeps
        0 in both; an arm in motion that is no longer ready stops."""
        for j in range(1, JOINTS + 1):
            if j > self.joints:
                self.set(f"enable_{j}", False)
                self.set(f"brake_{j}", False)
                continue
            enabled = bool(self.get(f"enable_{j}"))
            if enabled != self.enabled[j - 1]:
                self.enabled[j - 1] = enabled
                self.set(f"brake_{j}", enabled)
        if self.arm_state in (IN_MOTION, PAUSED) and not self.ready():
            self.task_seconds_left = 0.0
            self.set_state(STOPPED)

    def _sync_words(self, bits: str, words: str, tool_bits: str, tool_word: str) -> None:
        """Keep the DI/DO words (H/I 0-2) equal to the bit tables."""
        table = XARM_MAP[f"{words}_0"].table
        for w in range(2):
            word = sum(1 << k for k in range(16) if self.get(f"{bits}_{16 * w + k}"))
            self.set_words(table, w, [word])
        tool = sum(1 << k for k in range(TOOL_DIGITAL_CHANNELS) if self.get(f"{tool_bits}_{k}"))
        self.set_words(table, 2, [tool])

    def _sync_bits(self) -> None:
        words = self.get_words(Table.HOLDING, 0, 3)
        for k in range(CONTROLLER_DIGITAL_CHANNELS):
            self.set(f"controller_do_{k}", bool(words[k // 16] >> (k % 16) & 1))
        for k in range(TOOL_DIGITAL_CHANNELS):
            self.set(f"tool_do_{k}", bool(words[2] >> k & 1))

    def _pose_from_joints(self) -> None:
        q = [float(self.get(f"joint_angle_{j}")) for j in range(1, JOINTS + 1)]
        self.set("tcp_x", round(300.0 + 2.0 * q[0], 1))
        self.set("tcp_y", round(0.0 + 2.0 * q[1], 1))
        self.set("tcp_z", round(400.0 + 2.0 * q[2], 1))
        self.set_orientation(180.0, q[3] / 4.0, q[0])

    def set_orientation(self, roll: float, pitch: float, yaw: float) -> None:
        """The TCP orientation both ways the manual gives it (I67-69 and I70-72)."""
        with self.lock:
            roll, pitch, yaw = round(roll, 1), round(pitch, 1), round(yaw, 1)
            self.set("tcp_roll", roll)
            self.set("tcp_pitch", pitch)
            self.set("tcp_yaw", yaw)
            if self.euler_moving_axes:
                orientation = _moving_axes_quaternion(roll, pitch, yaw)
            else:
                orientation = euler_xyz_deg_to_quaternion(roll, pitch, yaw)
            rotation = quaternion_to_rotation_vector_deg(orientation)
            for axis, value in zip(("rx", "ry", "rz"), rotation, strict=True):
                self.set(f"tcp_{axis}", round(value, 1))

    def tick(self, dt: float) -> None:
        with self.lock:
            moving = self.arm_state == IN_MOTION
            previous = [float(self.get(f"joint_angle_{j}")) for j in range(1, JOINTS + 1)]
            if moving:
                self.phase += dt
                self.task_seconds_left -= dt
                for j in range(1, self.joints + 1):
                    angle = AMPLITUDE_DEG / j * math.sin(2 * math.pi * self.phase / PERIOD_S + j)
                    self.set(f"joint_angle_{j}", round(angle, 1))
                self.set("counter", int(self.get("counter")) + 1)
                if self.task_seconds_left <= 0:
                    self.task_seconds_left = 0.0
                    self.set_state(SLEEPING)
            for j in range(1, JOINTS + 1):
                moved = float(self.get(f"joint_angle_{j}")) - previous[j - 1]
                speed = moved / dt if moving and dt > 0 else 0.0
                self.set(f"joint_speed_{j}", round(max(-3000.0, min(3000.0, speed)), 1))
            self._pose_from_joints()
            self.set("tcp_speed", 50.0 if moving else 0.0)


Quaternion = tuple[float, float, float, float]


def _about(axis: int, angle_deg: float) -> Quaternion:
    q = [0.0, 0.0, 0.0, math.cos(angle_deg * DEG / 2.0)]
    q[axis] = math.sin(angle_deg * DEG / 2.0)
    return (q[0], q[1], q[2], q[3])


def _product(a: Quaternion, b: Quaternion) -> Quaternion:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _moving_axes_quaternion(roll: float, pitch: float, yaw: float) -> Quaternion:
    """Roll, pitch, yaw about the moving X, Y', Z'' (R = Rx Ry Rz): the other reading of
    xArm decision 13 (the bridge's is fixed axes, R = Rz Ry Rx)."""
    return _product(_product(_about(0, roll), _about(1, pitch)), _about(2, yaw))


def _signed(word: int) -> int:
    return word - 0x10000 if word >= 0x8000 else word


_STATE_WRITE_NAMES = {
    STOPPED: {"stop_state", "stop"},
    PAUSED: {"pause_state", "pause"},
    0: {"start"},
}


def make_simulator(joints: int = JOINTS) -> Simulator:
    return Simulator([XArmSimDevice(joints=joints)])


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="UFactory xArm Modbus TCP simulator")
    add_tcp_arguments(parser, default_port=5021)
    parser.add_argument("--error", type=int, default=0, help="start with this error code")
    parser.add_argument(
        "--joints",
        type=int,
        choices=list(JOINT_COUNTS),
        default=JOINTS,
        help="joints of the arm (xArm 5, 6 / Lite 6, 7)",
    )
    add_ignore_argument(parser, XArmSimDevice.IGNORABLE)
    parser.add_argument(
        "--coils-as-written",
        action="store_true",
        help="C144 / C145 (pause / stop) read back what was last written, not the arm's state",
    )
    parser.add_argument(
        "--counter-low-first",
        action="store_true",
        help="the counter I34-35 low word first (xArm decision 4's other reading)",
    )
    parser.add_argument(
        "--answer-reserved",
        action="store_true",
        help="reserved rows answer 0 instead of 0x02 (xArm decision 2's other reading)",
    )
    parser.add_argument(
        "--starts-in-error",
        action="store_true",
        help="a start (H33 = 0, a task) is taken while an error shows (decision 20's other)",
    )
    parser.add_argument(
        "--safety-modes-fixed",
        action="store_true",
        help="writes to C142-143 (reduced, fence mode) acknowledged, not applied (decision 17)",
    )
    parser.add_argument(
        "--euler-moving-axes",
        action="store_true",
        help="rx/ry/rz of roll/pitch/yaw about the moving axes (xArm decision 13's other)",
    )
    args = parser.parse_args(argv)
    sim = make_simulator(args.joints)
    device = sim.device
    assert isinstance(device, XArmSimDevice)
    device.set_error(args.error)
    device.coils_as_written = bool(args.coils_as_written)
    device.counter_low_first = bool(args.counter_low_first)
    device.answer_reserved = bool(args.answer_reserved)
    device.euler_moving_axes = bool(args.euler_moving_axes)
    device.starts_in_error = bool(args.starts_in_error)
    device.safety_modes_fixed = bool(args.safety_modes_fixed)
    serve_tcp_until_signalled(sim, args, "xarm_sim")


if __name__ == "__main__":
    main()
