"""xArm outputs: the controller's digital and analog outputs, the tool's digital outputs
and the user coils, as checked writes (no ROS).

Only the channels the manual calls valid are written (xArm decision 3); several coils go
out as one FC 0F write per run of consecutive addresses (xArm decision 9). "xArm decision
N" is reading N of docs/decisions/xarm.md.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from bridge_core.runtime.checks import check_count, check_index
from bridge_core.wire.channel import RegisterIO
from bridge_core.wire.codec import encode
from bridge_core.wire.errors import CommandRejected, LinkError

from .registers import (
    FIRST_TOOL_DIGITAL,
    WRITABLE_ANALOG_OUTPUTS,
    WRITABLE_DIGITAL_OUTPUTS,
    WRITABLE_TOOL_DIGITAL_OUTPUTS,
    XARM_MAP,
)


def set_digital_output(io: RegisterIO, index: int, on: bool) -> None:
    """Controller DO 0-15 (FC 05 to coil ``index``)."""
    _check_channel("digital output", index, WRITABLE_DIGITAL_OUTPUTS)
    io.write_coil(index, bool(on))


def set_tool_digital_output(io: RegisterIO, index: int, on: bool) -> None:
    """Tool DO 0-1 (FC 05 to coil 32 + ``index``)."""
    _check_channel("tool digital output", index, WRITABLE_TOOL_DIGITAL_OUTPUTS)
    io.write_coil(FIRST_TOOL_DIGITAL + index, bool(on))


def write_digital_outputs(io: RegisterIO, first: int, values: Sequence[bool]) -> None:
    """Consecutive controller DOs in one FC 0F write."""
    if not values:
        raise CommandRejected("no output values given")
    for k in range(first, first + len(values)):
        _check_channel("digital output", k, WRITABLE_DIGITAL_OUTPUTS)
    io.write_coils(first, [bool(v) for v in values])


def set_digital_outputs(io: RegisterIO, indexes: Sequence[int], states: Sequence[bool]) -> str:
    """Controller DOs ``indexes[k]`` to ``states[k]`` (DO 0-15, any order, each once):
    each run of consecutive indexes in one FC 0F write to its coils, lowest first; no
    other output is touched. Returns what was written (e.g. "DO 2-3 on off, DO 9 on").

    Coils, not the FC 0x16 mask write of H0: the manual defines coil addressing
    exactly, the bit order of the DO word only by "每1位表示1路IO" (xArm
    decision 9)."""
    changes = _changes(
        "digital output",
        indexes,
        states,
        lambda index: _check_channel("digital output", index, WRITABLE_DIGITAL_OUTPUTS),
        len(WRITABLE_DIGITAL_OUTPUTS),
    )
    return write_runs(io, "DO", changes)


def set_user_coils(
    io: RegisterIO, coils: range, addresses: Sequence[int], states: Sequence[bool]
) -> str:
    """User coils (C256-511, "用户自定义使用") within the configured range, written like
    ``set_digital_outputs``: a run of consecutive addresses per FC 0F write."""
    if not coils:
        raise CommandRejected(
            "no user coils configured (set user_coil_count, and user_coil_first, at start-up)"
        )
    changes = _changes(
        "user coil",
        addresses,
        states,
        lambda address: check_index("user coil", address, coils),
        len(coils),
    )
    return write_runs(io, "C", changes)


def change_digital_outputs(io: RegisterIO, changes: Mapping[int, bool]) -> None:
    """Several controller DOs in one FC 0x16 mask write to H0, the others kept; bit n
    of H0 is DO n (xArm decision 9). Device layer only: ROS writes coils."""
    if not changes:
        raise CommandRejected("no output changes given")
    and_mask, or_mask = 0xFFFF, 0
    for index, on in changes.items():
        _check_channel("digital output", index, WRITABLE_DIGITAL_OUTPUTS)
        and_mask &= ~(1 << index) & 0xFFFF
        if on:
            or_mask |= 1 << index
    io.mask_write_register(XARM_MAP["controller_do_word_0"].address, and_mask, or_mask)


def write_runs(io: RegisterIO, label: str, changes: Mapping[int, bool]) -> str:
    """One FC 0F write per run of consecutive coil addresses, lowest first. A write that
    fails after others went through says which did (writes are never retried)."""
    done: list[str] = []
    for first, values in _runs(changes):
        try:
            io.write_coils(first, values)
        except LinkError as err:
            if done:
                err.args = (
                    f"{err.args[0] if err.args else err}; written before it: {', '.join(done)}",
                )
            raise
        done.append(_describe_run(label, first, values))
    return ", ".join(done)


def set_analog_output(io: RegisterIO, channel: int, volts: float) -> None:
    """Controller AO 0-1 in volts (x1000, signed 16-bit, FC 06)."""
    _check_channel("analog output", channel, WRITABLE_ANALOG_OUTPUTS)
    reg = XARM_MAP[f"controller_ao_{channel}"]
    io.write_register(reg.address, encode(reg, float(volts))[0])


def set_analog_outputs(io: RegisterIO, volts: Sequence[float]) -> None:
    """Controller AO 0.. in one FC 10 write."""
    if not volts:
        raise CommandRejected("no analog values given")
    words: list[int] = []
    for channel, value in enumerate(volts):
        _check_channel("analog output", channel, WRITABLE_ANALOG_OUTPUTS)
        words += encode(XARM_MAP[f"controller_ao_{channel}"], float(value))
    io.write_registers(XARM_MAP["controller_ao_0"].address, words)


def _changes(
    what: str,
    indexes: Sequence[int],
    states: Sequence[bool],
    check: Callable[[int], object],
    most: int,
) -> dict[int, bool]:
    """``indexes[k]`` -> ``states[k]``, checked: at most ``most`` (each index once), as
    many states as indexes, at least one, each passing ``check``. An oversized request
    is refused by its size, before any index is looked at."""
    check_count("indexes", len(indexes), most)
    if len(indexes) != len(states):
        raise CommandRejected(f"{len(indexes)} indexes but {len(states)} states: give one each")
    if not indexes:
        raise CommandRejected("no outputs given")
    changes: dict[int, bool] = {}
    for index, state in zip(indexes, states, strict=True):
        check(index)
        if index in changes:
            raise CommandRejected(f"{what} {index} given twice")
        changes[index] = bool(state)
    return changes


def _runs(changes: Mapping[int, bool]) -> list[tuple[int, list[bool]]]:
    """Runs of consecutive addresses: [(first address, values)], lowest first."""
    runs: list[tuple[int, list[bool]]] = []
    for address in sorted(changes):
        if runs and runs[-1][0] + len(runs[-1][1]) == address:
            runs[-1][1].append(changes[address])
        else:
            runs.append((address, [changes[address]]))
    return runs


def _describe_run(label: str, first: int, values: Sequence[bool]) -> str:
    where = f"{label} {first}" if len(values) == 1 else f"{label} {first}-{first + len(values) - 1}"
    return f"{where} {' '.join('on' if v else 'off' for v in values)}"


def _check_channel(what: str, index: int, valid: range) -> None:
    """Only the channels the manual calls valid (xArm decision 3)."""
    try:
        check_index(what, index, valid)
    except CommandRejected as err:
        raise CommandRejected(f"{err}: the manual names only these as valid") from None
