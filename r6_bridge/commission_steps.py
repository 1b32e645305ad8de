"""The R6's commissioning steps: the read-only checks and guided steps that the rows of
``r6_bridge/commission.py`` name (``bridge_commission r6``, docs/commissioning.md).

They use the bridge's own device logic (``R6Device``, ``RunCycleMotion``, program.py),
so a step succeeds by the bridge's rule: what the controller reads back. No ROS here.
"R6 decision N" is reading N of docs/decisions/r6.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from bridge_core.runtime.commission import Finding, Probe, Verdict
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import words_to_int
from bridge_core.wire.errors import (
    CommandRejected,
    DeviceException,
    FrameError,
    NotConfirmed,
    PollIncomplete,
)
from bridge_core.wire.registers import Register, Table, ValueType, WordOrder

from .device import SLOW_NAMES, R6Device
from .motions import CYCLE_TIME_AT_END, CYCLE_TIME_AT_START, RunCycleMotion
from .registers import (
    COIL_BANKS,
    M_BOARDS,
    MAX_AXES,
    MAX_IO_BOARDS,
    POINTS_PER_BOARD,
    R6_MAP,
    mode_name,
)

# Decision 1: what a 32/64-bit value may plausibly read on a working controller.
POSITION_PLAUSIBLE_DEG = 3600.0  # ten turns of an axis, or of a world U, V, W
WORLD_PLAUSIBLE_MM = 100_000.0  # 100 m from the base
CYCLE_PLAUSIBLE_MS = 86_400_000  # a day
WORD_ORDER_ROWS = (
    *(f"axis_position_{a}" for a in range(1, MAX_AXES + 1)),
    *(f"world_{w}" for w in ("x", "y", "z", "u", "v", "w")),
    "current_cycle_time",
    "last_cycle_time",
)
LISTED_MAX = 8  # rows named in one finding; the rest counted
# Guided steps: how long they may take, and how often they read.
CYCLE_ATTEMPTS = 2  # single cycles: a second one if the first leaves 2401 unchanged
CYCLE_LIMIT_S = 120.0  # one single cycle that has not ended by then: stopped, could not tell
RUN_BEFORE_PAUSE_S = 0.5  # decision 29's step: the program runs this long before the pause
STANDSTILL_LIMIT_S = 10.0  # a step waits this long for the program to stand (moving 0)
STANDSTILL_READ_PERIOD_S = 0.2  # between two reads of moving while it waits


@dataclass
class Controller:
    """``probe.device`` of the R6 checks: the bridge's device and the counts read."""

    device: R6Device
    axes: int
    boards: int


def controller(probe: Probe) -> Controller:
    found = probe.device
    assert isinstance(found, Controller), "setup() runs first"
    return found


def ping(io: RegisterIO) -> object:
    """One short read, timed for the reply times: the mode (2185)."""
    return io.read_registers(R6_MAP["mode"].address, 1, priority=Priority.COMMAND)


def setup(probe: Probe) -> None:
    """The controller's facts for the report (reads only)."""
    device = R6Device(probe.io)
    try:
        firmware = device.read_version()
    except (DeviceException, FrameError) as err:
        firmware = f"unavailable ({err})"
    values = device.read_named(
        "mode", "axis_count", "io_board_count", "machine_id", "alarm_code", "homed", "global_speed"
    )
    mode = int(values["mode"])
    probe.device = Controller(device, int(values["axis_count"]), int(values["io_board_count"]))
    probe.facts.update(
        {
            "firmware (rows 0-64)": firmware,
            "mode (2185)": f"{mode_name(mode)} ({mode})",
            "axis count (2267)": str(int(values["axis_count"])),
            "IO board count (2186)": str(int(values["io_board_count"])),
            "machine id (2405)": str(int(values["machine_id"])),
            "alarm code (2396)": str(int(values["alarm_code"])),
            "homed (2471)": str(int(values["homed"])),
            "global speed (20200)": f"{float(values['global_speed']):g} %",
        }
    )


def requests_per_poll(probe: Probe) -> int:
    """The requests of one poll that reads no slow group (R6 decision 28)."""
    found = controller(probe)
    plan = found.device.poll_plan(found.axes, found.boards)
    return sum(1 for request in plan if not request.names <= SLOW_NAMES)


def _index(name: str, prefix: str) -> int | None:
    return int(name[len(prefix) :]) if name.startswith(prefix) else None


def refusal_reason(reg: Register, probe: Probe) -> str | None:
    """Why the controller refuses ``reg`` by the bridge's readings, or None."""
    found = controller(probe)
    axis = _index(reg.name, "axis_position_")
    if axis is not None and axis > found.axes:
        return f"axis {axis} past the axis count {found.axes} (decision 8)"
    for prefix in ("io_board_input_", "io_board_output_"):
        board = _index(reg.name, prefix)
        if board is not None and board >= found.boards:
            return f"IO board {board} past the board count {found.boards} (decision 8)"
    coil = _index(reg.name, "y_output_")
    if reg.table is Table.COIL and coil is not None and coil // POINTS_PER_BOARD >= found.boards:
        board = coil // POINTS_PER_BOARD
        return f"IO board {board} past the board count {found.boards} (decisions 8, 19)"
    if reg.name.startswith(("m_board_", "m_output_")):
        return "M board values not offered: the handheld network-port version (decision 21)"
    if reg.name.startswith(("eu_board_", "eu_output_")):
        return "no EU board fitted (decision 21)"
    return None


def _listed(names: list[str]) -> str:
    shown = ", ".join(names[:LISTED_MAX])
    return shown + (f" and {len(names) - LISTED_MAX} more" if len(names) > LISTED_MAX else "")


# ---------------------------------------------------------------- read-only checks
def _plausible(name: str, value: float) -> bool:
    if name.endswith("cycle_time"):
        return 0 <= value <= CYCLE_PLAUSIBLE_MS
    if name in ("world_x", "world_y", "world_z"):
        return abs(value) <= WORLD_PLAUSIBLE_MM
    return abs(value) <= POSITION_PLAUSIBLE_DEG


def word_order(probe: Probe) -> Finding:
    """Decision 1: every nonzero 32/64-bit value the scan read, decoded both ways."""
    assert probe.rows is not None
    seen: list[str] = []
    high_ok = low_ok = 0
    for name in WORD_ORDER_ROWS:
        words = probe.rows.answered.get(name)
        if not words or not any(words):
            continue
        reg = R6_MAP[name]
        signed = reg.value_type is ValueType.I32
        high = words_to_int(words, signed, WordOrder.HIGH_FIRST) / reg.scale
        low = words_to_int(words, signed, WordOrder.LOW_FIRST) / reg.scale
        high_ok += _plausible(name, high)
        low_ok += _plausible(name, low)
        seen.append(f"{name} {high:g} (low word first: {low:g})")
    read = f"read {len(seen)} nonzero values: {_listed(seen)}"
    if not seen:
        return Finding(
            Verdict.UNCLEAR,
            "every 32/64-bit value read 0: move the arm off its origin or run a cycle, "
            "then run this again",
        )
    if high_ok == len(seen) and low_ok < len(seen):
        return Finding(Verdict.CONFIRMED, f"high word first is plausible, low is not; {read}")
    if low_ok == len(seen) and high_ok < len(seen):
        return Finding(
            Verdict.CONTRADICTED,
            "only low word first gives plausible values: every position, pose and cycle "
            f"time the bridge publishes would be wrong; do not run it, tell us; {read}",
        )
    return Finding(Verdict.UNCLEAR, f"the values settle neither order; {read}")


def counts(probe: Probe) -> Finding:
    """Decision 8: the rows of the axes and boards in use answer, the rows past refuse."""
    assert probe.rows is not None
    found = controller(probe)
    if not (0 <= found.axes <= MAX_AXES and 0 <= found.boards <= MAX_IO_BOARDS):
        return Finding(
            Verdict.CONTRADICTED,
            f"axis count {found.axes} / IO board count {found.boards} outside the manual's "
            f"0-{MAX_AXES} / 0-{MAX_IO_BOARDS}",
        )
    in_use = [f"axis_position_{a}" for a in range(1, found.axes + 1)]
    past = [f"axis_position_{a}" for a in range(found.axes + 1, MAX_AXES + 1)]
    for kind in ("input", "output"):
        in_use += [f"io_board_{kind}_{b}" for b in range(found.boards)]
        past += [f"io_board_{kind}_{b}" for b in range(found.boards, MAX_IO_BOARDS)]
    refused = probe.rows.refused_names()
    counted = f"axis count {found.axes}, IO board count {found.boards}"
    if bad := [name for name in in_use if name in refused]:
        return Finding(
            Verdict.CONTRADICTED,
            f"{counted}, but rows in use refused: {_listed(bad)}: every poll would fail",
        )
    if answered := [name for name in past if name not in refused]:
        return Finding(
            Verdict.CONTRADICTED,
            f"{counted}; rows past the counts answered: {_listed(answered)} (harmless: the "
            "bridge reads only the rows in use)",
        )
    if not past:
        return Finding(Verdict.UNCLEAR, f"{counted}: nothing past the counts to read")
    return Finding(
        Verdict.CONFIRMED,
        f"{counted}: the {len(in_use)} rows in use answered, the {len(past)} past them refused",
    )


def map_gaps() -> list[int]:
    """The first address of every gap between the holding rows of the map (the rows the
    host does not offer, decision 11, among them)."""
    rows = sorted((r for r in R6_MAP if r.table is Table.HOLDING), key=lambda r: r.address)
    gaps: list[int] = []
    end = 0
    for reg in rows:
        if reg.address > end:
            gaps.append(end)
        end = max(end, reg.end)
    return gaps


def undefined_rows(probe: Probe) -> Finding:
    """Decision 11: one register of every gap read alone; the controller refuses each."""
    answered: list[str] = []
    gaps = map_gaps()
    for address in gaps:
        try:
            probe.io.read_registers(address, 1, priority=Priority.COMMAND)
        except DeviceException:
            continue
        answered.append(str(address))
    if answered:
        return Finding(
            Verdict.CONTRADICTED,
            f"{len(answered)} of {len(gaps)} registers outside the map answered: "
            f"{_listed(answered)} (harmless: the bridge never reads across them)",
        )
    return Finding(
        Verdict.CONFIRMED,
        f"the first register of each of the {len(gaps)} gaps of the map refused",
    )


def m_boards(probe: Probe) -> Finding:
    """Decision 21: whether the controller offers the M boards' values (``m_boards``)."""
    assert probe.rows is not None
    names = [f"m_board_{kind}_{b}" for kind in ("input", "output") for b in range(M_BOARDS)]
    names += [f"m_output_{c}" for c in range(COIL_BANKS[1][2])]
    refused = probe.rows.refused_names()
    bad = [name for name in names if name in refused]
    if not bad:
        return Finding(
            Verdict.CONFIRMED,
            f"the M boards' {len(names)} rows and coils answered: the bridge may poll and "
            "switch them",
            {"m_boards": True},
        )
    if len(bad) == len(names):
        return Finding(
            Verdict.CONFIRMED,
            "the M boards' rows and coils refused (the handheld network-port version): "
            "leave them off",
            {"m_boards": False},
        )
    return Finding(
        Verdict.UNCLEAR, f"some M board rows refused: {_listed(bad)}; left off", {"m_boards": False}
    )


# ---------------------------------------------------------------- guided steps
def pause(probe: Probe) -> str:
    """The stop of the guided steps: pause (20001), as a run_cycle goal's end (decision 23:
    the step is kept), confirmed by the bridge's rule (decision 29)."""
    try:
        return controller(probe).device.halt("pause")
    except NotConfirmed as err:
        return f"not confirmed: {err}: stop the program on the pendant"


def _stands(probe: Probe, device: R6Device) -> str | None:
    """None once the program stands, else why the step does not start."""
    deadline = time.monotonic() + STANDSTILL_LIMIT_S
    while device.read_named("moving")["moving"]:
        if time.monotonic() > deadline or probe.wait(STANDSTILL_READ_PERIOD_S):
            return "the program runs: stop it on the pendant first"
    return None


def _one_cycle(probe: Probe, device: R6Device) -> tuple[RunCycleMotion, str] | Finding:
    """One single cycle (20002) followed as a run_cycle goal: the motion and its end."""
    motion = RunCycleMotion(device, device.poll(), single_cycle=True)
    motion.start()
    started = time.monotonic()
    period = 1.0 / float(probe.values.get("poll_rate_hz", 50.0))
    while True:
        if probe.wait(period):
            return Finding(Verdict.UNCLEAR, "stopped by the operator before the cycle ended")
        if time.monotonic() - started > CYCLE_LIMIT_S:
            return Finding(Verdict.UNCLEAR, f"the cycle did not end within {CYCLE_LIMIT_S:g} s")
        try:
            snapshot = device.poll()
        except PollIncomplete:
            continue
        verdict = motion.judge(snapshot, time.monotonic() - started)
        if verdict is not None:
            return motion, verdict.message


def cycle_time_2401(probe: Probe) -> Finding:
    """Decision 23: single cycles, each followed by ``RunCycleMotion``'s verdict; which way
    this controller writes 2401 is what that verdict learnt."""
    device = controller(probe).device
    if (busy := _stands(probe, device)) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    said: list[str] = []
    for attempt in range(1, CYCLE_ATTEMPTS + 1):
        try:
            ran = _one_cycle(probe, device)
        except CommandRejected as err:
            return Finding(
                Verdict.NOT_RUN, f"refused by the bridge's checks, the step started nothing: {err}"
            )
        if isinstance(ran, Finding):
            return ran
        motion, message = ran
        said.append(f"cycle {attempt}: {message}")
        if device.cycle_time_written_at == CYCLE_TIME_AT_END:
            return Finding(
                Verdict.CONFIRMED, f"2401 kept its value while the cycle ran; {'; '.join(said)}"
            )
        if device.cycle_time_written_at == CYCLE_TIME_AT_START:
            return Finding(
                Verdict.CONTRADICTED,
                "2401 changed while the cycle ran: this controller writes it at a cycle's "
                "start, so run_cycle can never prove a single cycle on it (every goal ends "
                f"STOPPED); watch the arm instead; {'; '.join(said)}",
            )
        if not motion.seen_running:
            break
        probe.say(f"  {said[-1]}; 2401 did not change: one more single cycle")
    return Finding(Verdict.UNCLEAR, "; ".join(said))


def stop_shows_in_2470(probe: Probe) -> Finding:
    """Decision 29: start (20003, checked and read back), run, pause (20001) read back."""
    device = controller(probe).device
    if (busy := _stands(probe, device)) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    try:
        started = device.run_program("start")
    except CommandRejected as err:
        return Finding(
            Verdict.NOT_RUN, f"refused by the bridge's checks, the step started nothing: {err}"
        )
    except NotConfirmed as err:
        return Finding(Verdict.UNCLEAR, f"the program did not start: {err}")
    if probe.wait(RUN_BEFORE_PAUSE_S):
        return Finding(Verdict.UNCLEAR, f"stopped by the operator before the pause ({started})")
    try:
        paused = device.halt("pause")
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"{err}: this controller takes longer than HALT_CONFIRM_S to show a stop, or "
            "2470 does not follow the motion; tell us the time the arm takes to stand",
        )
    return Finding(Verdict.CONFIRMED, f"start: {started}; pause: {paused}")
