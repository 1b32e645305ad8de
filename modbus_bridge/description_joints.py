"""The joints of a description file: which registers give a joint's position, velocity and
effort, the factor to SI (REP 103) from each register's unit, and how ``modbus_sim``
moves the joint. Register does not know joints: these rules are the description's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from bridge_core.runtime.units import DEG, MM, RPM_TO_RAD_S
from bridge_core.wire.codec import CodecError, encode, to_raw
from bridge_core.wire.registers import Register, RegisterMap, ValueType

from .description_commands import allowed_values, not_allowed, writable
from .description_schema import DeviceFileSpec, JointSimSpec, JointSpec, JointValueSpec
from .description_yaml import Checker, Loc

# Register units a joint value may have, as (SI unit, factor to it). REP 103: positions in
# rad or m, velocities in rad/s or m/s, efforts in N·m or N.
UNITS_TO_SI: dict[str, tuple[str, float]] = {
    "rad": ("rad", 1.0),
    "mrad": ("rad", 1e-3),
    "deg": ("rad", DEG),
    "rev": ("rad", 2.0 * math.pi),
    "m": ("m", 1.0),
    "mm": ("m", MM),
    "um": ("m", 1e-6),
    "rad/s": ("rad/s", 1.0),
    "deg/s": ("rad/s", DEG),
    "rpm": ("rad/s", RPM_TO_RAD_S),
    # A drive's frequency: one revolution per cycle, or ``per_revolution`` cycles (Hz) per
    # revolution (e.g. a motor's pole pairs); the factor is 2 pi / per_revolution.
    "Hz": ("rad/s", 2.0 * math.pi),
    "m/s": ("m/s", 1.0),
    "mm/s": ("m/s", MM),
    "N.m": ("N.m", 1.0),
    "mN.m": ("N.m", 1e-3),
    "N": ("N", 1.0),
    "kN": ("N", 1e3),
}
SI_UNITS = {
    ("revolute", "position"): "rad",
    ("revolute", "velocity"): "rad/s",
    ("revolute", "effort"): "N.m",
    ("prismatic", "position"): "m",
    ("prismatic", "velocity"): "m/s",
    ("prismatic", "effort"): "N",
}


@dataclass(frozen=True)
class JointSource:
    """A register and the factor that turns its engineering value into SI."""

    register: str
    to_si: float


# A follower's rules: the values while running / stopped, or the joint's motion times a
# factor (in the sim command register's unit).
FOLLOW_RULES = ("running", "velocity", "speed", "command")
# A joint runs, for a follower's ``running``, while its velocity is above this (SI units/s)
# or its command counts (its run register holds a run value; no run register: non-zero).
RUNNING_MIN_SI = 1e-3


@dataclass(frozen=True)
class Follow:
    """A monitor register the simulator sets from the joint's motion: ``rule`` is
    ``running`` (``running`` / ``stopped`` values) or ``velocity`` / ``speed`` /
    ``command`` (times ``factor``, in the sim command register's unit)."""

    register: str
    rule: Literal["running", "velocity", "speed", "command"]
    factor: float = 1.0
    running: float = 1.0
    stopped: float = 0.0


@dataclass(frozen=True)
class JointMotion:
    """The simulator's rule for a joint: ``command`` (to SI by ``to_si``) is a velocity or
    a target position; a target is approached at ``speed`` (SI/s; None: at once); a
    velocity follows its command with ``time_constant_s`` (None: at once), and only while
    ``run_register`` holds one of ``run_values``."""

    command: str
    to_si: float
    mode: Literal["velocity", "position"]
    speed: float | None
    time_constant_s: float | None = None
    run_register: str | None = None
    run_values: tuple[float, ...] = ()
    follows: tuple[Follow, ...] = ()


@dataclass(frozen=True)
class JointCommand:
    """What ``~/joint_commands`` writes for a joint: a writable register per kind it
    takes, each with the factor from its engineering value to SI (a command in SI is
    written as value / ``to_si``, the joint_states conversion backwards)."""

    position: JointSource | None
    velocity: JointSource | None


@dataclass(frozen=True)
class Joint:
    name: str
    position: JointSource | None  # None: a velocity-only joint (NaN in joint_states)
    velocity: JointSource | None
    effort: JointSource | None
    motion: JointMotion | None = None
    command: JointCommand | None = None


def _joint_source(
    register_map: RegisterMap,
    joint: JointSpec,
    what: Literal["position", "velocity", "effort"],
    spec: JointValueSpec,
    check: Checker,
    at: Loc,
    *,
    command: bool = False,
) -> JointSource | None:
    """A joint's register for ``what`` and its factor to SI; ``command``: a register
    ``~/joint_commands`` writes (writable), else one ``joint_states`` reads (readable)."""
    if spec.register_name not in register_map:
        check.add((*at, what, "register"), f"no register named {spec.register_name!r}")
        return None
    if spec.factor == 0:
        check.add((*at, what, "factor"), "0 would make every value 0 (allowed: non-zero)")
        return None
    register = register_map[spec.register_name]
    usable = register.access.writable if command else register.access.readable
    if not usable or register.value_type in (ValueType.BOOL, ValueType.STRING):
        needs = "writable number (access W or RW" if command else "readable number (access R or RW"
        check.add(
            (*at, what, "register"),
            f"{spec.register_name} is not a {needs}, a numeric type)",
        )
        return None
    wanted = SI_UNITS[(joint.kind, what)]
    unit = UNITS_TO_SI.get(register.unit)
    if unit is None or unit[0] != wanted:
        allowed = ", ".join(u for u, (si, _) in UNITS_TO_SI.items() if si == wanted)
        check.add(
            (*at, what, "register"),
            f"{spec.register_name}'s unit {register.unit!r} is not a {joint.kind} {what} "
            f"(REP 103 {wanted}; allowed units: {allowed})",
        )
        return None
    per_revolution = _per_revolution(register, spec.per_revolution, check, (*at, what))
    if per_revolution is None:
        return None
    return JointSource(spec.register_name, unit[1] * spec.factor / per_revolution)


def _per_revolution(
    register: Register, given: float | None, check: Checker, at: Loc
) -> float | None:
    """A Hz register's cycles per revolution (default 1); only a Hz register has one."""
    if given is not None and register.unit != "Hz":
        check.add(
            (*at, "per_revolution"),
            f"{register.name}'s unit is {register.unit!r}: per_revolution is for a Hz register",
        )
        return None
    return 1.0 if given is None else given


def build_joints(
    spec: DeviceFileSpec, register_map: RegisterMap, check: Checker
) -> tuple[Joint, ...]:
    joints: list[Joint] = []
    names: set[str] = set()
    for index, joint in enumerate(spec.joints):
        at: Loc = ("joints", index)
        if joint.name in names:
            check.add((*at, "name"), f"joint {joint.name!r} given twice (names are unique)")
        names.add(joint.name)
        if joint.position is None and joint.velocity is None:
            check.add(at, f"joint {joint.name!r} needs a position or a velocity register")
            continue
        position = velocity = effort = None
        if joint.position is not None:
            position = _joint_source(register_map, joint, "position", joint.position, check, at)
        if joint.velocity is not None:
            velocity = _joint_source(register_map, joint, "velocity", joint.velocity, check, at)
        if joint.effort is not None:
            effort = _joint_source(register_map, joint, "effort", joint.effort, check, at)
        motion = None
        if joint.sim is not None:
            motion = _joint_motion(
                register_map, joint, joint.sim, allowed_values(spec), check, (*at, "sim")
            )
        command = None
        if joint.command is not None:
            command = _joint_command(
                register_map, joint, allowed_values(spec), check, (*at, "command")
            )
        if not check.problems:
            joints.append(Joint(joint.name, position, velocity, effort, motion, command))
    return tuple(joints)


def _joint_command(
    register_map: RegisterMap,
    joint: JointSpec,
    allowed: dict[str, tuple[float, ...]],
    check: Checker,
    at: Loc,
) -> JointCommand | None:
    """A joint's ``command``: its registers writable numbers in the joint's SI kind; a
    position command needs the joint's position register (its stop holds the joint where
    that register reads), a velocity command a register that takes 0 (its stop)."""
    spec = joint.command
    assert spec is not None
    if spec.position is None and spec.velocity is None:
        check.add(at, "give position, velocity or both (the registers joint_commands writes)")
        return None
    position = velocity = None
    if spec.position is not None:
        if joint.position is None:
            check.add(
                (*at, "position"),
                "a position command needs the joint's position register (its stop holds the "
                "joint where it stands)",
            )
            return None
        position = _joint_source(
            register_map, joint, "position", spec.position, check, at, command=True
        )
    if spec.velocity is not None:
        velocity = _joint_source(
            register_map, joint, "velocity", spec.velocity, check, at, command=True
        )
        if velocity is not None:
            register = register_map[velocity.register]
            try:
                to_raw(register, 0.0)
            except CodecError as err:
                check.add((*at, "velocity", "register"), f"its stop, 0, cannot be written: {err}")
                return None
            if register.name in allowed and 0.0 not in allowed[register.name]:
                check.add(
                    (*at, "velocity", "register"),
                    f"its stop, 0, is not one of {register.name}'s values",
                )
                return None
    if check.problems:
        return None
    return JointCommand(position, velocity)


def _joint_motion(
    register_map: RegisterMap,
    joint: JointSpec,
    sim: JointSimSpec,
    allowed: dict[str, tuple[float, ...]],
    check: Checker,
    at: Loc,
) -> JointMotion | None:
    if joint.position is None and sim.mode == "position":
        check.add((*at, "mode"), "a joint without a position register moves by velocity")
        return None
    register = writable(register_map, sim.command, check, at, field="command")
    if register is None:
        return None
    wanted = SI_UNITS[(joint.kind, sim.mode)]
    unit = UNITS_TO_SI.get(register.unit)
    if unit is None or unit[0] != wanted:
        units = ", ".join(u for u, (si, _) in UNITS_TO_SI.items() if si == wanted)
        check.add(
            (*at, "command"),
            f"{sim.command}'s unit {register.unit!r} is not a {joint.kind} {sim.mode} "
            f"({wanted}; allowed units: {units})",
        )
        return None
    if sim.speed is not None and sim.mode == "velocity":
        check.add((*at, "speed"), "speed is for mode position (a velocity command sets it)")
        return None
    if sim.mode == "position" and (sim.time_constant_s is not None or sim.run_register):
        check.add(at, "time_constant_s and run_register are for mode velocity")
        return None
    per_revolution = _per_revolution(register, sim.per_revolution, check, at)
    if per_revolution is None:
        return None
    if (sim.run_register is None) != (sim.run_values is None):
        check.add(at, "give run_register and run_values together")
        return None
    if sim.run_register is not None:
        if sim.run_register not in register_map:
            check.add((*at, "run_register"), f"no register named {sim.run_register!r}")
            return None
        if not _run_values_fit(register_map[sim.run_register], sim, allowed, check, at):
            return None
    follows = _follows(register_map, joint, sim, check, at)
    if follows is None:
        return None
    return JointMotion(
        sim.command,
        unit[1] / per_revolution,
        sim.mode,
        sim.speed,
        sim.time_constant_s,
        sim.run_register,
        tuple(sim.run_values or ()),
        follows,
    )


def _run_values_fit(
    register: Register,
    sim: JointSimSpec,
    allowed: dict[str, tuple[float, ...]],
    check: Checker,
    at: Loc,
) -> bool:
    """Each run value is one the run register can hold and is allowed to be written (one
    of its ``values``): else the joint could never run."""
    choices = allowed.get(register.name)
    for k, value in enumerate(sim.run_values or ()):
        try:
            raw = to_raw(register, value)
        except CodecError as err:
            check.add((*at, "run_values", k), f"{register.name} cannot hold it: {err}")
            return False
        if choices is not None and raw not in {to_raw(register, c) for c in choices}:
            check.add((*at, "run_values", k), not_allowed(register.name, value, choices))
            return False
    return True


def _follows(
    register_map: RegisterMap, joint: JointSpec, sim: JointSimSpec, check: Checker, at: Loc
) -> tuple[Follow, ...] | None:
    """``sim.follows``: monitor registers (readable numbers the bridge never writes, not
    moved by the joint already), each with exactly one rule whose values fit it."""
    driven = {sim.command, sim.run_register}
    for source in (joint.position, joint.velocity, joint.effort):
        if source is not None:
            driven.add(source.register_name)
    built: list[Follow] = []
    for name, rule in (sim.follows or {}).items():
        where: Loc = (*at, "follows", name)
        if name not in register_map:
            check.add(where, f"no register named {name!r}")
            return None
        register = register_map[name]
        if name in driven:
            check.add(where, f"{name} is the joint's own (the simulator moves it already)")
            return None
        if register.access.writable or register.value_type in (ValueType.BOOL, ValueType.STRING):
            check.add(
                where,
                f"{name} is not a read-only number (a follower is a monitor the device sets; "
                "the simulator would overwrite what the bridge writes)",
            )
            return None
        given = [key for key in FOLLOW_RULES if getattr(rule, key) is not None]
        if rule.stopped is not None and "running" not in given:
            given.append("running")
        if len(given) != 1:
            check.add(
                where,
                "give one rule: running (with stopped, default 0), velocity, speed or command",
            )
            return None
        kind = given[0]
        if kind == "running":
            running = 1.0 if rule.running is None else rule.running
            stopped = 0.0 if rule.stopped is None else rule.stopped
            for key, value in (("running", running), ("stopped", stopped)):
                try:
                    encode(register, value)
                except CodecError as err:
                    check.add((*where, key), f"{name} cannot hold it: {err}")
                    return None
            built.append(Follow(name, "running", running=running, stopped=stopped))
        else:
            factor = getattr(rule, kind)
            built.append(Follow(name, kind, factor=factor))  # type: ignore[arg-type]
    return tuple(built)
