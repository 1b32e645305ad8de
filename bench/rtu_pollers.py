"""The RTU device benches' rig (bench/rtu_devices.py, bench/read_rates.py): a bridge's own
simulator on the far end of bench/line_relay.py's emulated byte-timed line (``line``,
``serve``), and on the near end one ``ModbusLink`` with the nodes' poll thread per
device (``polling``, ``NodePoller``: the nodes' own ``Poller`` with their default
channel settings, no ROS). ``read_whole_map``: a device reads its whole map every poll,
as before the rate groups ("today's plan").
"""

from __future__ import annotations

import contextlib
import multiprocessing
import time
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import Connection
from typing import Any, Protocol

from bench.change_probe import answer_changes
from bench.line_relay import LineRelay
from bridge_core.runtime.poller import Poller
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.planner import ReadRequest, plan_reads
from bridge_core.wire.registers import RegisterMap
from bridge_core.wire.serial_timing import silence_s
from bridge_core.wire.transport import ModbusLink, SerialSettings
from motec_bridge.device import MotecDevice
from stepper_bridge.device import StepperDevice
from stepper_bridge.registers import REPLY_DELAY_S as STEPPER_REPLY_DELAY_S
from stepper_bridge.registers import motor_register

MOTEC_BAUD = 115200
# Node defaults (bridge_core/ros/node_parameters.py parameters, motec_bridge/bus.py bus parameters;
# not imported: those modules need rclpy).
NODE_RETRIES = 1  # "retries"
NODE_RECONNECT_MAX_S = 5.0  # "reconnect_max_s"
NODE_MAX_POLL_RATE_HZ = 1000.0  # "poll_rate_hz" upper bound: polls back to back
STEPPER_TIMEOUT_S = 0.5  # BridgeNode "timeout_s"
MOTEC_TIMEOUT_S = 0.1  # motec_bridge.interface.MOTEC_DEFAULTS.timeout_s
START_TIMEOUT_S = 20.0


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
