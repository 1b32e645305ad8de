#!/usr/bin/env python3
"""Device-level RTU figures on the emulated byte-timed line (docs/architecture.md,
"Performance: how it is measured").

Prints tables and writes bench/results/rtu_devices.json; asserts nothing.

    .venv/bin/python bench/rtu_devices.py [--duration 10] [--quick]
        [--parts stepper,bus,dead] [--drives 1,4,8] [--fixed-rate-hz 10]
        [--sim-tick-s 0.1] [--whole-map] [--json PATH]

Everything runs the bridges' own device layers (``StepperDevice.poll()``,
``MotecDevice.poll()``: exactly the requests a node sends per poll cycle, configuration
refresh included) through ``DeviceChannel`` on one shared ``ModbusLink``
(``TimedSerialClient``, ``PriorityLock``), against the bridges' own simulators
(``stepper_bridge.sim`` with its 35 ms reply delay, ``motec_bridge.sim`` with several
drives on one serial server), each in a process of its own on the far end of
``bench/line_relay.py`` (bytes paced at 10 bits / baud on one half-duplex timeline; the
relay holds a reply until t3.5 after the request, as a real RTU device must wait).
The simulators tick their devices' motion every 0.1 s instead of 10 ms
(``--sim-tick-s``): nothing moves here, and 100 Hz ticks of 8 drives take CPU from the
client on a 2-vCPU machine that a real drive would not (see ``SIM_TICK_S``).
Each drive gets the nodes' own poller (``bridge_core.runtime.poller.Poller``):
pacing, backoff guard and re-plan (``NodePoller``; no ROS, nothing
published), with the nodes' default channel settings. ``--whole-map``: each device reads
its whole map every poll, as before the rate groups (``read_whole_map``), for an A/B in
one tree (``bench/read_rates.py`` prints both side by side).

Parts:

- ``stepper``: one controller at 9600 and 115200 baud, polled back to back (the node's
  maximum poll rate);
- ``bus``: MOTEC drives 1, 4 and 8 on one bus at 115200, every drive polled as fast as
  possible (the node's maximum poll rate), round-robin through the PriorityLock;
- ``dead``: 4 MOTEC units at 115200, one of them (unit 4) dead (no simulator answers
  it), the others alive, at ``--fixed-rate-hz`` each and saturated; compared with the
  same units all alive (and, saturated, with the 3 live drives alone). The dead drive's
  channel uses the MOTEC node's defaults: timeout 0.1 s, 1 retry (``DeviceChannel``
  probes a device that is down once, without it), reconnect backoff 0.25 s doubling to
  5 s.

Figures:

- ``ratio``: sum of the ideal wire time of every transaction completed in the window,
  over the window (= achieved rate / wire-limit rate for the same transactions). Ideal
  transaction (8N1): (request + reply bytes) x 10 / baud, plus the device turnaround
  max(t3.5, nominal reply delay), plus t3.5 after the reply (``rtu_wire.transaction_wire_s``;
  t3.5 = 3.5 chars, fixed 1.75 ms above 19200 baud);
- ``r_dev``: the same with the turnaround the relay observed (median reply start - request
  end) instead of the nominal delay: the simulator's asyncio sleep overshoots 35 ms by
  ~1.5 ms, which is the device's doing, not the link's;
- ``gap`` / ``min``: median / shortest silence before a request (ms; t3.5 is the floor);
  ``viol/req``: requests that started inside t3.5 after the previous frame (relay
  timestamps, 20 us tolerance) / requests on the wire; the JSON also counts those more
  than 0.1 ms inside (``gross_violations``) and shows the first few; ``err``: failed
  polls of live devices;
- ``lost ms/tx``: where the window's time beyond the ideal went, per transaction: the
  client (silence before a request beyond t3.5), the device (turnaround beyond the
  nominal one), frames stretched on the wire (the relay released bytes late: the
  emulation's own); ``cpu ms/tx``: the bench process's CPU (poll threads and link);
- dead-drive tables: each live drive's polls/s over a window, and the share it keeps of
  its rate with all alive. ``steady``: between two attempts on the dead drive once its
  backoff reached the 5 s cap (whole backoff periods, so the window is unbiased);
  ``first``: the first ``--duration`` seconds after the drive went dead (backoff ramp:
  attempts after 0.25, 0.5, 1, 2, 4 s).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import multiprocessing
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Protocol

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.change_probe import answer_changes  # noqa: E402
from bench.line_relay import (  # noqa: E402
    REQUEST,
    Frame,
    LineRelay,
    request_gaps,
    silence_violations,
    transactions,
)
from bench.rtu_wire import transaction_wire_s  # noqa: E402
from bridge_core.runtime.poller import Poller  # noqa: E402
from bridge_core.wire.channel import DeviceChannel  # noqa: E402
from bridge_core.wire.planner import ReadRequest, plan_reads  # noqa: E402
from bridge_core.wire.registers import RegisterMap  # noqa: E402
from bridge_core.wire.serial_timing import silence_s  # noqa: E402
from bridge_core.wire.transport import ModbusLink, SerialSettings  # noqa: E402
from motec_bridge.device import MotecDevice  # noqa: E402
from stepper_bridge.device import StepperDevice  # noqa: E402
from stepper_bridge.registers import REPLY_DELAY_S as STEPPER_REPLY_DELAY_S  # noqa: E402
from stepper_bridge.registers import motor_register  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "rtu_devices.json"
MOTEC_BAUD = 115200
# Node defaults (bridge_core/ros/node_parameters.py parameters, motec_bridge/bus.py bus parameters;
# not imported: those modules need rclpy).
NODE_RETRIES = 1  # "retries"
NODE_RECONNECT_MAX_S = 5.0  # "reconnect_max_s"
NODE_MAX_POLL_RATE_HZ = 1000.0  # "poll_rate_hz" upper bound: polls back to back
STEPPER_TIMEOUT_S = 0.5  # BridgeNode "timeout_s"
MOTEC_TIMEOUT_S = 0.1  # motec_bridge.interface.MOTEC_DEFAULTS.timeout_s
MOTEC_DEFAULT_POLL_HZ = 10.0  # motec_bridge.interface.MOTEC_DEFAULTS.poll_rate_hz
DEAD_UNITS = 4  # units on the bus in the dead-drive cases, the last one dead
BACKOFF_CAP_ATTEMPT = 7  # the 7th attempt on a dead channel follows a capped (5 s) delay
START_TIMEOUT_S = 20.0
# A request this far inside t3.5 is no timestamp error of the relay (its calibrated
# latencies are ~10-30 us; line_relay.py tolerates 20 us); pymodbus's stock client sends
# ~0.5-1.7 ms early.
GROSS_VIOLATION_S = 100e-6


class Device(Protocol):
    def poll(self) -> object: ...

    def invalidate_config(self) -> None: ...


# ---------------------------------------------------------------- simulators and the line


def serve(
    port: str,
    baudrate: int,
    kind: str,
    units: Sequence[int],
    tick_s: float,
    ready: Any,
    stop: Any,
    control: Connection[Any, Any] | None = None,
) -> None:
    """The bridge's own simulator on ``port`` until ``stop`` is set (a process of its own).

    ``control``: values for the first unit's joint 1 (``set_joint``), each answered with
    the time it was set (``change_probe.answer_changes``)."""
    sim: Any
    if kind == "stepper":
        from stepper_bridge.sim import make_simulator as make_stepper

        sim = make_stepper(units[0], reply_delay_s=STEPPER_REPLY_DELAY_S)
    else:
        from motec_bridge.sim import make_simulator as make_motec

        sim = make_motec(units)
    sim.tick_s = tick_s
    with sim:
        sim.start_serial(port, baudrate=baudrate)
        ready.set()
        if control is None:
            stop.wait()
        else:
            device = sim.devices[units[0]]
            answer_changes(control, stop, lambda value: set_joint(device, kind, value))


def set_joint(device: Any, kind: str, value: float) -> None:
    """Joint 1 of a simulated unit at ``value`` (stepper: motor 1's coordinate, user units;
    MOTEC: the actual position, counts), as the device's own motion would leave it: its
    motion state too, so the simulator's tick keeps the register where it was set."""
    with device.lock:
        if kind == "stepper":
            device.position[1] = device.offset[1] + value
            device.set(motor_register(1, "coordinate"), value)
        else:
            device.position = value
            device.set("position_actual", int(value))
            device.set("position_setpoint", int(value))


# The simulators advance their devices' motion every tick (default 10 ms). The devices
# stand still here, and at 100 Hz the ticks of 8 drives cost ~16 % of a core that a real
# drive would not take from the host; measured: the 8-drive bus ratio went from 0.95-0.96
# to 0.98 with 0.1 s ticks (``--sim-tick-s 0.01`` for the simulators' default).
SIM_TICK_S = 0.1


@contextlib.contextmanager
def line(
    baudrate: int,
    kind: str,
    sim_units: Sequence[int],
    sim_tick_s: float = SIM_TICK_S,
    control: Connection[Any, Any] | None = None,
) -> Iterator[LineRelay]:
    """The relay with the simulator of ``sim_units`` on its device end (``control``: see
    ``serve``)."""
    mp = multiprocessing.get_context("spawn")
    ready, stop = mp.Event(), mp.Event()
    t35 = silence_s(baudrate)
    with LineRelay(baudrate, device_turnaround_s=t35) as relay:
        proc = mp.Process(
            target=serve,
            args=(
                relay.device_path,
                baudrate,
                kind,
                list(sim_units),
                sim_tick_s,
                ready,
                stop,
                control,
            ),
        )
        proc.start()
        try:
            if not ready.wait(START_TIMEOUT_S):
                raise RuntimeError(f"{kind} simulator did not start")
            yield relay
        finally:
            stop.set()
            proc.join(10)
            if proc.is_alive():
                proc.kill()
                proc.join(5)


# ---------------------------------------------------------------- the nodes' poll threads


class NodePoller:
    """One device's poll thread: the nodes' own ``bridge_core.runtime.poller.Poller`` (pacing,
    backoff guard, ``invalidate_config`` before the first poll after (re)connecting),
    with the poll wrapped to record when each attempt started and each success ended.
    ``observer``, when set, is told of every snapshot and the time its poll returned."""

    def __init__(self, name: str, channel: DeviceChannel, device: Device, rate_hz: float) -> None:
        self.name = name
        self.channel = channel
        self.device = device
        self.attempts: list[float] = []  # poll starts (monotonic)
        self.completed: list[float] = []  # successful poll ends
        self.observer: Callable[[object, float], None] | None = None
        self.poller: Poller[object] = Poller(
            channel,
            self._poll,
            lambda _snapshot: None,
            rate_hz=rate_hz,
            link_up=device.invalidate_config,
            replan=device.invalidate_config,
            name=name,
        )

    def _poll(self) -> object:
        self.attempts.append(time.monotonic())
        snapshot = self.device.poll()
        done = time.monotonic()
        self.completed.append(done)
        if self.observer is not None:
            self.observer(snapshot, done)
        return snapshot

    @property
    def failures(self) -> int:
        return self.poller.failures

    def start(self) -> None:
        self.poller.start()

    def stop(self) -> None:
        self.poller.stop(join_s=0.0)

    def join(self) -> None:
        self.poller.stop()

    def rate_in(self, start: float, end: float) -> float:
        return sum(start < t <= end for t in self.completed) / (end - start)


def whole_map_plan(
    register_map: RegisterMap, fast: Sequence[ReadRequest], slow: Sequence[ReadRequest]
) -> list[ReadRequest]:
    """The plan before rate groups: every register of both groups planned as one, read
    every poll; the block holding the fast plan's first registers first (the stepper's
    running flags, as its status plan was ordered then). For the stepper and MOTEC this is
    the status plan of the tree before the rate groups (dc8e5b1's parent): the same
    registers, planned by the same planner."""
    names = sorted({name for request in (*fast, *slow) for name in request.names})
    plan = plan_reads(register_map, register_map.select(names))
    lead = fast[0].names if fast else frozenset()
    return sorted(plan, key=lambda request: not request.names & lead)


def read_whole_map(device: StepperDevice | MotecDevice) -> None:
    """Bench only: ``device`` reads its whole map every poll ("today's plan", for an A/B
    against the rate groups in one tree). Its ``PollGroups`` get the merged plan as the fast
    group and an empty slow group, through their public ``set_plans``: the same requests a
    poll made before rate groups; nothing in the bridges changes."""
    groups = device.groups
    groups.set_plans(whole_map_plan(device.register_map, groups.fast, groups.slow), [])


def make_pollers(
    link: ModbusLink, kind: str, units: Sequence[int], rate_hz: float, whole_map: bool = False
) -> list[NodePoller]:
    pollers = []
    for unit in units:
        channel = DeviceChannel(
            link, unit, retries=NODE_RETRIES, reconnect_max_s=NODE_RECONNECT_MAX_S
        )
        device: StepperDevice | MotecDevice = (
            StepperDevice(channel) if kind == "stepper" else MotecDevice(channel)
        )
        if whole_map:
            read_whole_map(device)
        pollers.append(NodePoller(f"{kind}_{unit}", channel, device, rate_hz))
    return pollers


@contextlib.contextmanager
def polling(
    relay: LineRelay,
    kind: str,
    units: Sequence[int],
    rate_hz: float,
    timeout_s: float,
    whole_map: bool = False,
) -> Iterator[list[NodePoller]]:
    """Poll threads for ``units`` on one link to the relay's client end, stopped on exit."""
    link = ModbusLink(SerialSettings(relay.client_path, relay.baudrate, timeout_s=timeout_s))
    pollers = make_pollers(link, kind, units, rate_hz, whole_map)
    for p in pollers:
        p.start()
    try:
        yield pollers
    finally:
        for p in pollers:
            p.stop()
        for p in pollers:
            p.join()
        link.close()


def wait_until(condition: Callable[[], bool], timeout_s: float, step_s: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(step_s)
    return True


# ---------------------------------------------------------------- wire accounting


def wire_figures(
    frames: Sequence[Frame], baudrate: int, nominal_delay_s: float, start: float, end: float
) -> dict[str, Any]:
    """Transactions wholly inside [start, end] vs their ideal wire time; line checks."""
    t35 = silence_s(baudrate)
    pairs = [(q, r) for q, r in transactions(frames) if q.start >= start and r.end <= end]
    turnaround = statistics.median(r.start - q.end for q, r in pairs) if pairs else 0.0
    window = end - start
    nominal = sum(transaction_wire_s(baudrate, q.size, r.size, nominal_delay_s) for q, r in pairs)
    observed = sum(transaction_wire_s(baudrate, q.size, r.size, turnaround) for q, r in pairs)
    gaps = [g.silence_s for g in request_gaps(frames)]
    # Where the window's time beyond the ideal went, per transaction (ms): the client's
    # silence before a request beyond t3.5, the device's turnaround beyond the nominal
    # one, frames stretched on the wire (relay late).
    in_window = [g for g in request_gaps(frames) if g.before.end >= start and g.request.end <= end]
    char_s = 10 / baudrate
    n = max(1, len(pairs))
    lost = {
        "client": sum(max(0.0, g.silence_s - t35) for g in in_window) / n,
        "device": sum(r.start - q.end - max(t35, nominal_delay_s) for q, r in pairs) / n,
        "frames": sum(f.end - f.start - f.size * char_s for qr in pairs for f in qr) / n,
    }
    return {
        "window_s": window,
        "transactions": len(pairs),
        "ratio": nominal / window,
        "ratio_dev": observed / window,
        "lost_ms_per_transaction": {k: v * 1e3 for k, v in lost.items()},
        "device_turnaround_ms": turnaround * 1e3,
        "mean_gap_ms": statistics.fmean(gaps) * 1e3 if gaps else None,
        "median_gap_ms": statistics.median(gaps) * 1e3 if gaps else None,
        "min_gap_ms": min(gaps) * 1e3 if gaps else None,
        "requests_on_wire": sum(f.direction == REQUEST for f in frames),
        "violations": len(violations := silence_violations(frames, t35)),
        "gross_violations": len(silence_violations(frames, t35, GROSS_VIOLATION_S)),
        "violation_examples": [
            {
                "silence_ms": g.silence_s * 1e3,
                "before": asdict(g.before),
                "request": asdict(g.request),
            }
            for g in violations[:5]
        ],
        "t35_ms": t35 * 1e3,
    }


def saturated_run(
    baudrate: int,
    kind: str,
    units: Sequence[int],
    duration_s: float,
    warmup_s: float,
    nominal_delay_s: float,
    timeout_s: float,
    sim_tick_s: float = SIM_TICK_S,
    *,
    whole_map: bool = False,
    control: Connection[Any, Any] | None = None,
    during: Callable[[list[NodePoller]], contextlib.AbstractContextManager[object]] | None = None,
) -> dict[str, Any]:
    """Every unit polled back to back; the window runs from the first poll completed
    after the warm-up to the last one before its end, so whole polls are counted.

    ``whole_map``: every unit reads its whole map every poll (``read_whole_map``);
    ``control``: the simulator's (``serve``); ``during(pollers)``: a context entered for
    the measured window (e.g. a ``change_probe.ChangeProbe`` changing registers)."""
    with (
        line(baudrate, kind, units, sim_tick_s, control) as relay,
        polling(relay, kind, units, NODE_MAX_POLL_RATE_HZ, timeout_s, whole_map) as pollers,
    ):
        if not wait_until(lambda: all(p.completed for p in pollers), START_TIMEOUT_S):
            raise RuntimeError(f"{kind}: not every unit answered")
        time.sleep(warmup_s)
        with during(pollers) if during is not None else contextlib.nullcontext():
            relay.clear()
            t0, cpu0 = time.monotonic(), time.process_time()
            time.sleep(duration_s)
            t1, cpu1 = time.monotonic(), time.process_time()
        frames = relay.frames()
    ends = sorted(t for p in pollers for t in p.completed if t0 <= t <= t1)
    start, end = ends[0], ends[-1]
    polls = [sum(start < t <= end for t in p.completed) for p in pollers]
    wire = wire_figures(frames, baudrate, nominal_delay_s, start, end)
    rate = sum(polls) / (end - start)
    return {
        "kind": kind,
        "baudrate": baudrate,
        "units": len(units),
        "reply_delay_ms": nominal_delay_s * 1e3,
        "polls": sum(polls),
        "polls_per_s": rate,
        "per_unit_min": min(polls) / (end - start),
        "per_unit_max": max(polls) / (end - start),
        "wire_polls_per_s": rate / wire["ratio"],
        "wire_polls_per_s_dev": rate / wire["ratio_dev"],
        "errors": sum(p.failures for p in pollers),
        **wire,
        # The bench process (poll threads, link) only: simulator and relay run elsewhere.
        "client_cpu_ms_per_transaction": (cpu1 - cpu0) * 1e3 / max(1, wire["transactions"]),
        "client_cpu_ms_per_poll": (cpu1 - cpu0) * 1e3 / max(1, len(ends)),
        "whole_map": whole_map,
        "relay_latency_us": {k: v * 1e6 for k, v in relay.latency_s.items()},
    }


# ---------------------------------------------------------------- dead drive


def dead_run(
    rate_hz: float,
    duration_s: float,
    periods: int,
    dead: bool,
    live_only: bool = False,
    sim_tick_s: float = SIM_TICK_S,
) -> dict[str, Any]:
    """Units 1..DEAD_UNITS polled at ``rate_hz`` each; the last unit dead if ``dead``.

    ``live_only``: only the live units exist (no dead unit polled either).
    """
    all_units = list(range(1, DEAD_UNITS + 1))
    live = all_units[:-1] if dead or live_only else all_units
    polled = live if live_only else all_units
    with (
        line(MOTEC_BAUD, "motec", live, sim_tick_s) as relay,
        polling(relay, "motec", polled, rate_hz, MOTEC_TIMEOUT_S) as pollers,
    ):
        t_start = time.monotonic()
        live_pollers = [p for p in pollers if p.channel.unit_id in live]
        dead_poller = next((p for p in pollers if p.channel.unit_id not in live), None)
        if dead_poller is not None:
            # Until the backoff is capped and `periods` whole 5 s periods have followed.
            last = BACKOFF_CAP_ATTEMPT + periods
            done = wait_until(
                lambda: (
                    len(dead_poller.attempts) >= last and time.monotonic() - t_start >= duration_s
                ),
                60 + periods * (NODE_RECONNECT_MAX_S + 1) + duration_s,
            )
            if not done:
                raise RuntimeError("the dead drive's attempts did not come as expected")
            attempts = dead_poller.attempts
            windows = {
                "first": (attempts[0], attempts[0] + duration_s),
                "steady": (attempts[BACKOFF_CAP_ATTEMPT - 1], attempts[last - 1]),
            }
        else:
            time.sleep(1.0 + duration_s)  # 1 s warm-up
            t1 = time.monotonic()
            windows = {"steady": (t1 - duration_s, t1), "first": (t1 - duration_s, t1)}
        frames = relay.frames()
    rates = {name: [p.rate_in(a, b) for p in live_pollers] for name, (a, b) in windows.items()}
    a, b = windows["steady"]
    return {
        "rate_hz": rate_hz,
        "units_polled": len(polled),
        "live": len(live),
        "dead": dead,
        "windows_s": {k: w[1] - w[0] for k, w in windows.items()},
        "live_rates": rates,
        "dead_attempts": len(dead_poller.attempts) if dead_poller else 0,
        "dead_timeouts": dead_poller.channel.stats.timeouts if dead_poller else 0,
        "errors": sum(p.failures for p in live_pollers),
        "bus_ratio_steady": wire_figures(frames, MOTEC_BAUD, 0.0, a, b)["ratio"],
        "violations": len(silence_violations(frames, silence_s(MOTEC_BAUD))),
        "requests_on_wire": sum(f.direction == REQUEST for f in frames),
    }


def dead_cases(
    rate_hz: float, duration_s: float, periods: int, sim_tick_s: float = SIM_TICK_S
) -> dict[str, Any]:
    def measure(rate: float, **kwargs: bool) -> dict[str, Any]:
        return dead_run(rate, duration_s, periods, sim_tick_s=sim_tick_s, **kwargs)

    fixed_alive = measure(rate_hz, dead=False)
    fixed_dead = measure(rate_hz, dead=True)
    sat_alive = measure(NODE_MAX_POLL_RATE_HZ, dead=False)
    sat_live_only = measure(NODE_MAX_POLL_RATE_HZ, dead=False, live_only=True)
    sat_dead = measure(NODE_MAX_POLL_RATE_HZ, dead=True)
    out: dict[str, Any] = {"runs": [fixed_alive, fixed_dead, sat_alive, sat_live_only, sat_dead]}
    rows = []
    for label, ref, run in (
        (f"{rate_hz:g} Hz, 1 dead vs 4 alive", fixed_alive, fixed_dead),
        ("max, 1 dead vs 4 alive", sat_alive, sat_dead),
        ("max, 1 dead vs 3 alone", sat_live_only, sat_dead),
    ):
        # Per live unit: its rate with the dead unit / the same unit's rate in ``ref``.
        ref_rates = ref["live_rates"]["steady"][: len(run["live_rates"]["steady"])]
        row: dict[str, Any] = {"case": label, "ref_rate": statistics.median(ref_rates)}
        for window in ("steady", "first"):
            rates = run["live_rates"][window]
            kept = [r / q for r, q in zip(rates, ref_rates, strict=True)]
            row[window] = {
                "rate": statistics.median(rates),
                "kept_median": statistics.median(kept),
                "kept_min": min(kept),
            }
        row["violations"] = run["violations"] + ref["violations"]
        row["requests_on_wire"] = run["requests_on_wire"] + ref["requests_on_wire"]
        row["errors"] = run["errors"] + ref["errors"]
        row["dead_attempts"] = run["dead_attempts"]
        row["steady_window_s"] = run["windows_s"]["steady"]
        rows.append(row)
    out["rows"] = rows
    return out


# ---------------------------------------------------------------- tables


def print_saturated(rows: Sequence[dict[str, Any]], header: bool = True) -> None:
    head = (
        f"{'device':<7} {'baud':>6} {'units':>5} {'polls':>5} {'polls/s':>8} {'unit min':>8} "
        f"{'wire/s':>7} {'ratio':>6} {'wire/s d':>8} {'r_dev':>6} {'turn':>6} {'gap':>5} "
        f"{'min':>5} "
        f"{'viol/req':>10} {'err':>3} {'lost ms/tx: client dev frames':>30} {'cpu ms/tx':>9}"
    )
    if header:
        print(head)
        print("-" * len(head))
    for r in rows:
        lost = r["lost_ms_per_transaction"]
        print(
            f"{r['kind']:<7} {r['baudrate']:>6} {r['units']:>5} {r['polls']:>5} "
            f"{r['polls_per_s']:>8.2f} {r['per_unit_min']:>8.2f} {r['wire_polls_per_s']:>7.2f} "
            f"{r['ratio']:>6.3f} {r['wire_polls_per_s_dev']:>8.2f} {r['ratio_dev']:>6.3f} "
            f"{r['device_turnaround_ms']:>6.2f} {r['median_gap_ms']:>5.2f} {r['min_gap_ms']:>5.3f} "
            f"{r['violations']:>4}/{r['requests_on_wire']:<5} {r['errors']:>3} "
            f"{lost['client']:>17.3f} {lost['device']:>6.3f} {lost['frames']:>6.3f} "
            f"{r['client_cpu_ms_per_transaction']:>9.3f}",
            flush=True,
        )


def print_dead(rows: Sequence[dict[str, Any]]) -> None:
    head = (
        f"{'case':<24} {'ref/s':>6} {'steady/s':>8} {'kept':>6} {'min':>6} "
        f"{'first/s':>7} {'kept':>6} {'min':>6} {'window':>6} {'viol/req':>11} {'err':>3}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        s, f = r["steady"], r["first"]
        print(
            f"{r['case']:<24} {r['ref_rate']:>6.2f} {s['rate']:>8.2f} {s['kept_median']:>6.3f} "
            f"{s['kept_min']:>6.3f} {f['rate']:>7.2f} {f['kept_median']:>6.3f} "
            f"{f['kept_min']:>6.3f} {r['steady_window_s']:>6.1f} "
            f"{r['violations']:>4}/{r['requests_on_wire']:<6} {r['errors']:>3}",
            flush=True,
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=10.0, help="measured s per case")
    parser.add_argument("--quick", action="store_true", help="2 s windows, 1 backoff period")
    parser.add_argument("--parts", default="stepper,bus,dead")
    parser.add_argument(
        "--fixed-rate-hz",
        type=float,
        default=MOTEC_DEFAULT_POLL_HZ,
        help="per-drive poll rate of the fixed-rate dead-drive case (node default 10)",
    )
    parser.add_argument("--drives", default="1,4,8", help="bus part: drive counts")
    parser.add_argument(
        "--sim-tick-s",
        type=float,
        default=SIM_TICK_S,
        help="simulators' motion tick (their default: 0.01)",
    )
    parser.add_argument(
        "--whole-map",
        action="store_true",
        help="stepper and bus parts: read the whole map every poll (the plan before rate "
        "groups; read_whole_map)",
    )
    parser.add_argument("--json", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    duration = 2.0 if args.quick else args.duration
    warmup = 0.5 if args.quick else 1.0
    periods = 1 if args.quick else 2
    parts = set(args.parts.split(","))
    tick = args.sim_tick_s
    started = time.monotonic()
    result: dict[str, Any] = {
        "when": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": platform.platform(),
        "duration_s": duration,
        "sim_tick_s": args.sim_tick_s,
        "whole_map": args.whole_map,
    }
    plan = "the whole map every poll" if args.whole_map else "rate groups"
    if "stepper" in parts:
        print(f"stepper: StepperDevice.poll() back to back, 35 ms reply delay, {plan}")
        rows = []
        for baud in (9600, 115200):
            rows.append(
                saturated_run(
                    baud,
                    "stepper",
                    [1],
                    duration,
                    warmup,
                    STEPPER_REPLY_DELAY_S,
                    STEPPER_TIMEOUT_S,
                    tick,
                    whole_map=args.whole_map,
                )
            )
            print_saturated(rows[-1:], header=len(rows) == 1)
        result["stepper"] = rows
        print()
    if "bus" in parts:
        print(
            f"MOTEC bus at {MOTEC_BAUD}: every drive's MotecDevice.poll() as fast as "
            f"possible, {plan}"
        )
        rows = []
        for n in (int(x) for x in args.drives.split(",") if x):
            rows.append(
                saturated_run(
                    MOTEC_BAUD,
                    "motec",
                    range(1, n + 1),
                    duration,
                    warmup,
                    0.0,
                    MOTEC_TIMEOUT_S,
                    tick,
                    whole_map=args.whole_map,
                )
            )
            print_saturated(rows[-1:], header=len(rows) == 1)
        result["bus"] = rows
        print()
    if "dead" in parts:
        print(
            f"MOTEC, {DEAD_UNITS} units at {MOTEC_BAUD}, unit {DEAD_UNITS} dead "
            f"(timeout {MOTEC_TIMEOUT_S} s, probed once, backoff to "
            f"{NODE_RECONNECT_MAX_S:g} s): live drives' polls/s"
        )
        dead = dead_cases(args.fixed_rate_hz, duration, periods, tick)
        print_dead(dead["rows"])
        result["dead"] = dead
        print()
    result["run_s"] = time.monotonic() - started
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    print(f"wrote {args.json} ({result['run_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
