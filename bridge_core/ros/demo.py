"""``bridge_demo``: the bridges against their simulators, showing live state.

Starts each device's simulator and bridge node as separate processes (as a user would
run them), then watches their topics from this process and prints a status block once
per second until Ctrl-C or ``--duration``. Everything stays on this machine: discovery is
limited to localhost and the demo uses a ROS domain of its own.

This module knows no device. Each bridge package owns its entry, ``<bridge>/demo.py``
exporting ``DEMO = DemoDevice(...)`` (simulator arguments, node parameters, services that
set the device moving, a one-line state formatter), and declares it in the entry-point
group ``modbus_bridges.demo`` of pyproject.toml::

    [project.entry-points."modbus_bridges.demo"]
    r6 = "r6_bridge.demo:DEMO"

How the runner finds the entries (:func:`entry_specs`), first match wins:

1. a list given explicitly: ``--demo-module r6_bridge.demo`` (repeatable) or
   ``main(modules=[...])``; a spec is ``module`` (attribute ``DEMO``) or ``module:attr``;
2. in a source checkout (a pyproject.toml of this project next to ``bridge_core/``), that
   file's entry-point table, read with tomllib;
3. otherwise the installed distributions' entry points in the group (a wheel install).

Why read pyproject.toml rather than only the installed entry points: the editable install
records entry points at install time, so a checkout whose table changed since (another
git worktree sharing one venv, a pull without re-running scripts/setup.sh) would run a
stale list, or none. The table in the checkout is always the current one, and after a
clean clone plus scripts/setup.sh both sources agree. Why not scan the packages next to
``bridge_core`` for a ``demo.py``: installed, those siblings are all of site-packages,
and importing whatever ``*/demo.py`` lies there is not safe; the explicit table is one
list for both cases, and tests/core/ros/test_demo_entries.py checks that every ``<bridge>/demo.py``
in the checkout is declared in it. Entry points carry no order, so ``DemoDevice.order``
sets the order of the status blocks.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..runtime import entries
from ..wire.ports import free_port

DEFAULT_DOMAIN_ID = 42
# Ctrl-C seen: the demo ends at its monitor's next spin. Python's own SIGINT handler raises
# KeyboardInterrupt wherever the main thread is, and inside an rclpy call (a message being
# taken) pybind11 turns it into "RuntimeError: Unable to convert call argument": a
# traceback and exit 1 instead of a clean stop (seen in a CI run).
INTERRUPTED = threading.Event()
CONNECT_TIMEOUT_S = 30.0
ROOT = entries.ROOT
ENTRY_POINT_GROUP = entries.DEMO_GROUP


@dataclass
class DemoDevice:
    """One simulator + bridge pair and how to show its state.

    The pair is ``<package>.sim`` (or ``sim_module``) and ``<package>.node`` (node name =
    package), both told
    where the device is: a free TCP port (``--port`` / ``port``) or, with ``serial``, the
    path of a pty the simulator creates for the bridge's end (``--pty`` / ``serial_port``).
    """

    name: str
    package: str
    state_type: str  # "package/msg/Type"
    format_state: Callable[[Any], str]
    sim_args: list[str] = field(default_factory=list)  # besides where
    node_params: dict[str, Any] = field(default_factory=dict)  # besides where
    start_services: list[tuple[str, str, dict[str, Any]]] = field(default_factory=list)
    serial: bool = False
    # Nodes with a ~/state of their own, when one process runs several (MOTEC: one per
    # drive); default: just ``node_name``.
    state_nodes: list[str] = field(default_factory=list)
    # Where the device's block goes in the status output (lowest first).
    order: int = 100
    # The simulator's module run with ``-m`` when it is not ``<package>.sim`` (MOTEC: its
    # command line is ``sim_cli``).
    sim_module: str = ""

    @property
    def node_name(self) -> str:
        return self.package

    @property
    def namespace(self) -> str:
        """The device's ROS namespace in the demo: its name in lower case."""
        return f"/{self.name.lower()}"

    def service(self, name: str) -> str:
        """The full name of a service ``name`` of this device (with several state nodes,
        ``name`` names its node itself)."""
        if self.state_nodes:
            return f"{self.namespace}/{name}"
        return f"{self.namespace}/{self.node_name}/{name}"

    @property
    def nodes(self) -> list[str]:
        return self.state_nodes or [self.node_name]

    def simulator_command(self, where: Any) -> list[str]:
        flag = "--pty" if self.serial else "--port"
        module = self.sim_module or f"{self.package}.sim"
        return ["-m", module, flag, str(where), *self.sim_args]

    def node_command(self, where: Any) -> list[str]:
        params = {"serial_port": str(where)} if self.serial else {"port": where}
        ros_args = ["--ros-args", "-r", f"__ns:={self.namespace}"]
        for key, value in {**params, **self.node_params}.items():
            ros_args += ["-p", f"{key}:={value}"]
        return ["-m", f"{self.package}.node", *ros_args]


def entry_specs(root: Path = ROOT) -> list[str]:
    """The ``module:attr`` of every declared demo entry (see the module docstring)."""
    return entries.entry_specs(ENTRY_POINT_GROUP, root)


def load_devices(specs: Iterable[str]) -> list[DemoDevice]:
    """Import each ``module`` (attribute ``DEMO``) or ``module:attr``; in ``order``."""
    devices: dict[str, DemoDevice] = {}
    for spec in specs:
        module, _, attr = spec.strip().partition(":")
        device = getattr(importlib.import_module(module), attr or "DEMO")
        if not isinstance(device, DemoDevice):
            raise TypeError(f"{spec}: {type(device).__name__}, not a DemoDevice")
        if device.name.upper() in devices:
            raise ValueError(f"{spec}: a second demo entry named {device.name!r}")
        devices[device.name.upper()] = device
    return sorted(devices.values(), key=lambda d: d.order)  # stable: ties keep their order


def _import(type_name: str) -> Any:
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


class Monitor:
    """An rclpy node that keeps the latest message of every device topic."""

    def __init__(self, devices: Sequence[DemoDevice]) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool

        # No rclpy signal handler: Ctrl-C is the KeyboardInterrupt main() ends on (rclpy's
        # own would shut the context down under a spin: a traceback, exit 1); main()'s
        # handler only sets INTERRUPTED, which spin_for turns into that exception.
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.rclpy = rclpy
        self.node = rclpy.create_node("bridge_demo_monitor")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.latest: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.positions: dict[str, dict[str, float]] = {}
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        for device in devices:
            ns = device.namespace
            self._watch(JointState, f"{ns}/joint_states")
            for node in device.nodes:
                self._watch(_import(device.state_type), f"{ns}/{node}/state")
                self._watch(Bool, f"{ns}/{node}/connected", latched)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._diagnostics, 10)

    def _watch(self, msg_type: Any, topic: str, qos: Any = 10) -> None:
        self.counts[topic] = 0

        def store(msg: Any) -> None:
            self.latest[topic] = msg
            self.counts[topic] += 1
            if topic.endswith("/joint_states"):  # several nodes may share the topic
                positions = self.positions.setdefault(topic, {})
                positions.update(zip(msg.name, msg.position, strict=False))

        self.node.create_subscription(msg_type, topic, store, qos)

    def _diagnostics(self, array: Any) -> None:
        for status in array.status:
            self.latest[f"diag:{status.hardware_id}"] = status

    def spin_for(self, seconds: float) -> None:
        """Spin ``seconds``; KeyboardInterrupt here, between two spins, after a Ctrl-C."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if INTERRUPTED.is_set():
                raise KeyboardInterrupt
            self.executor.spin_once(timeout_sec=max(0.0, min(0.05, end - time.monotonic())))

    def call(
        self, service: str, type_name: str, fields: dict[str, Any], timeout: float = 10.0
    ) -> str:
        srv = _import(type_name)
        client = self.node.create_client(srv, service)
        try:
            end = time.monotonic() + timeout
            while not client.service_is_ready():
                if time.monotonic() > end:
                    return f"{service}: not available"
                self.spin_for(0.05)
            request = srv.Request()
            for key, value in fields.items():
                setattr(request, key, value)
            future = client.call_async(request)
            while not future.done():
                if time.monotonic() > end:
                    return f"{service}: no reply"
                self.spin_for(0.05)
            reply = future.result()
            return f"{service}: {reply.message}"
        finally:
            self.node.destroy_client(client)

    def wait_connected(self, devices: Sequence[DemoDevice], timeout: float) -> list[str]:
        """Spin until every node says ``~/connected`` true; the nodes that did not."""
        topics = [
            f"{device.namespace}/{node}/connected" for device in devices for node in device.nodes
        ]
        end = time.monotonic() + timeout

        def waiting() -> list[str]:
            return [t for t in topics if not getattr(self.latest.get(t), "data", False)]

        while waiting() and time.monotonic() < end:
            self.spin_for(0.1)
        return waiting()

    def close(self) -> None:
        from rclpy.utilities import try_shutdown

        self.executor.shutdown()
        self.node.destroy_node()
        try_shutdown()


def render(monitor: Monitor, device: DemoDevice, rates: dict[str, float]) -> str:
    ns = device.namespace
    lines: list[str] = []
    for node in device.nodes:
        connected = monitor.latest.get(f"{ns}/{node}/connected")
        diag = next(
            (
                s
                for k, s in monitor.latest.items()
                if k.startswith("diag:") and s.name.startswith(f"{ns}/{node}: ")
            ),
            None,
        )
        link = "connected" if connected is not None and connected.data else "DISCONNECTED"
        level = (
            {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}.get(diag.level[0], "?") if diag else "-"
        )
        label = device.name if len(device.nodes) == 1 else f"{device.name} {node}"
        lines.append(f"[{label}] {link}  diagnostics {level}{': ' + diag.message if diag else ''}")
        state = monitor.latest.get(f"{ns}/{node}/state")
        if state is not None:
            lines.append("   " + device.format_state(state))
    lines[0] += f"  joint_states {rates.get(ns, 0.0):.1f} Hz"
    positions = monitor.positions.get(f"{ns}/joint_states", {})
    if positions:
        joints = "  ".join(f"{n} {math.degrees(p):8.2f}" for n, p in sorted(positions.items()))
        lines.insert(1, f"   joints (deg): {joints}")
    return "\n".join(lines)


def _chosen_devices(
    argv: Sequence[str] | None, modules: Sequence[str] | None
) -> tuple[argparse.Namespace, list[DemoDevice]]:
    """The command line and the devices it picks (a usage error exits, as argparse does)."""
    parser = argparse.ArgumentParser(description="run the bridges against their simulators")
    parser.add_argument("--duration", type=float, default=0.0, help="seconds; 0 = until Ctrl-C")
    parser.add_argument(
        "--devices", default="", help="comma-separated subset, e.g. R6,MOTEC (default: all)"
    )
    parser.add_argument(
        "--demo-module",
        action="append",
        default=[],
        metavar="MODULE[:ATTR]",
        help="a demo entry to use instead of the declared ones (repeatable), e.g. r6_bridge.demo",
    )
    args = parser.parse_args(argv)
    specs = [*(modules or ()), *args.demo_module] or entry_specs()
    try:
        known = load_devices(specs)
    except (ImportError, AttributeError, TypeError, ValueError) as exc:
        parser.error(f"cannot load the demo entries: {exc}")
    if not known:
        parser.error(f"no demo entries declared (entry-point group {ENTRY_POINT_GROUP!r})")
    wanted = {n.strip().upper() for n in args.devices.split(",") if n.strip()}
    devices = [d for d in known if not wanted or d.name.upper() in wanted]
    unknown = wanted - {d.name.upper() for d in known}
    if unknown or not devices:
        names = ", ".join(d.name for d in known)
        parser.error(f"no known device in {args.devices!r} (known: {names})")
    return args, devices


def _call_start_services(monitor: Monitor, devices: Sequence[DemoDevice]) -> None:
    """Once the devices are connected (or the wait ran out), the services that set them moving."""
    # The start services need a connected device: on a busy machine the simulators
    # and bridges take a while to come up, and a service called earlier is refused.
    for topic in monitor.wait_connected(devices, CONNECT_TIMEOUT_S):
        print(f"  {topic}: not connected after {CONNECT_TIMEOUT_S:.0f} s", flush=True)
    for device in devices:
        for service, type_name, fields in device.start_services:
            print(
                "  "
                + monitor.call(
                    device.service(service),
                    type_name,
                    fields,
                ),
                flush=True,
            )


def _show_until_stopped(
    monitor: Monitor,
    devices: Sequence[DemoDevice],
    processes: Sequence[subprocess.Popen[bytes]],
    duration_s: float,
    stop: dict[str, bool],
    logs: Path,
) -> None:
    """Each second the devices' state on the console, until ``duration_s`` (0: never),
    a SIGTERM (``stop``), or a process that exited (SystemExit)."""
    started = time.monotonic()
    last_counts = dict(monitor.counts)
    while not stop["now"] and (duration_s <= 0 or time.monotonic() - started < duration_s):
        monitor.spin_for(1.0)
        rates = {}
        for device in devices:
            ns = device.namespace
            topic = f"{ns}/joint_states"
            rates[ns] = float(monitor.counts[topic] - last_counts.get(topic, 0))
        last_counts = dict(monitor.counts)
        print(f"--- t = {time.monotonic() - started:5.1f} s", flush=True)
        for device in devices:
            print(render(monitor, device, rates), flush=True)
        for proc in processes:
            if proc.poll() is not None:
                raise SystemExit(f"bridge_demo: a process exited ({proc.args!r}); see {logs}")


def _shut_down(monitor: Monitor | None, processes: Sequence[subprocess.Popen[bytes]]) -> None:
    """The monitor closed, then every process asked to stop (SIGINT), newest first."""
    # A second Ctrl-C must not cut the clean-up short (the bridges' own stops run in
    # their processes, which got the terminal's SIGINT too): it is bounded anyway.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if monitor is not None:
        with contextlib.suppress(Exception):  # its context may be gone already
            monitor.close()
    for proc in reversed(processes):
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc in reversed(processes):
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
    print("bridge_demo: stopped", flush=True)


def main(argv: Sequence[str] | None = None, modules: Sequence[str] | None = None) -> None:
    """Run the demo; ``modules``: the demo entries to use instead of the declared ones."""
    args, devices = _chosen_devices(argv, modules)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # everything here is local
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.setdefault("ROS_DOMAIN_ID", str(DEFAULT_DOMAIN_ID))

    from rclpy.executors import ExternalShutdownException

    processes: list[subprocess.Popen[bytes]] = []
    logs = Path(tempfile.mkdtemp(prefix="bridge_demo_"))
    print(f"bridge_demo: ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, logs in {logs}", flush=True)

    def spawn(name: str, command: list[str]) -> None:
        log = (logs / f"{name}.log").open("wb")
        processes.append(
            subprocess.Popen(
                [sys.executable, *command], cwd=ROOT, stdout=log, stderr=subprocess.STDOUT
            )
        )

    stop = {"now": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(now=True))
    signal.signal(signal.SIGINT, lambda *_: INTERRUPTED.set())
    monitor: Monitor | None = None
    try:
        for device in devices:
            where: Any = logs / f"{device.name.lower()}.pty" if device.serial else free_port()
            spawn(f"{device.name.lower()}_sim", device.simulator_command(where))
            spawn(device.node_name, device.node_command(where))
        monitor = Monitor(devices)
        _call_start_services(monitor, devices)
        _show_until_stopped(monitor, devices, processes, args.duration, stop, logs)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        _shut_down(monitor, processes)


if __name__ == "__main__":
    # Run as ``python -m bridge_core.ros.demo`` this file is ``__main__``, while the entries
    # build their DemoDevice from ``bridge_core.ros.demo``: run that module's main so both
    # sides share one DemoDevice class.
    from bridge_core.ros.demo import main as _main

    _main()
