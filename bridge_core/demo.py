"""``bridge_demo``: the bridges against their simulators, showing live state.

Starts each device's simulator and bridge node as separate processes (as a user would
run them), then watches their topics from this process and prints a status block once
per second until Ctrl-C or ``--duration``. Everything stays on this machine: discovery is
limited to localhost and the demo uses a ROS domain of its own.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

DEFAULT_DOMAIN_ID = 42
ROOT = Path(__file__).resolve().parent.parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class DemoDevice:
    """One simulator + bridge pair and how to show its state."""

    name: str
    node_name: str
    # Both take where the device is: a TCP port, or (serial=True) the path of a pty the
    # simulator creates for the bridge's end.
    sim_args: Callable[[Any], list[str]]
    node_module: str
    node_params: Callable[[Any], dict[str, Any]]
    state_type: str  # "package/msg/Type"
    format_state: Callable[[Any], str]
    start_services: list[tuple[str, str, dict[str, Any]]] = field(default_factory=list)
    serial: bool = False
    # Nodes with a ~/state of their own, when one process runs several (MOTEC: one per
    # drive); default: just ``node_name``.
    state_nodes: list[str] = field(default_factory=list)

    @property
    def nodes(self) -> list[str]:
        return self.state_nodes or [self.node_name]


def _r6_state(state: Any) -> str:
    return (
        f"mode {state.mode_name}  alarm {state.alarm_code}  "
        f"moving {'yes' if state.moving else 'no'}  "
        f"speed {state.global_speed_percent:.1f}%  cycle {state.current_cycle_time_ms} ms"
    )


DEVICES: list[DemoDevice] = [
    DemoDevice(
        name="R6",
        node_name="r6_bridge",
        sim_args=lambda port: ["-m", "r6_bridge.sim", "--port", str(port)],
        node_module="r6_bridge.node",
        node_params=lambda port: {"port": port, "poll_rate_hz": 50.0},
        state_type="msg_defs/msg/R6State",
        format_state=_r6_state,
        start_services=[
            ("set_global_speed", "msg_defs/srv/SetValue", {"value": 80.0}),
            ("start", "std_srvs/srv/Trigger", {}),
        ],
    ),
]


def _xarm_state(state: Any) -> str:
    error = f"error {state.error_code} {state.error_text}" if state.error_code else "no error"
    outputs = "".join("1" if b else "0" for b in state.digital_outputs)
    return (
        f"state {state.state_name}  mode {state.mode}  {error}  "
        f"tcp speed {state.tcp_speed:.3f} m/s  DO {outputs}"
    )


DEVICES.append(
    DemoDevice(
        name="xArm",
        node_name="xarm_bridge",
        sim_args=lambda port: ["-m", "xarm_bridge.sim", "--port", str(port)],
        node_module="xarm_bridge.node",
        node_params=lambda port: {"port": port, "poll_rate_hz": 50.0},
        state_type="msg_defs/msg/XArmState",
        format_state=_xarm_state,
        start_services=[
            ("set_digital_output", "msg_defs/srv/SetOutput", {"board": 0, "index": 2, "on": True}),
            ("run_offline_task", "msg_defs/srv/RunOfflineTask", {"projects": [1, 2, 3, 4, 5, 6]}),
        ],
    )
)


def _stepper_state(state: Any) -> str:
    running = "".join("R" if r else "." for r in state.running)
    outputs = "".join("1" if o else "0" for o in state.outputs)
    coordinates = " ".join(f"{c:8.2f}" for c in state.coordinates)
    return f"running {running}  coordinates {coordinates}  outputs {outputs}"


DEVICES.append(
    DemoDevice(
        name="Stepper",
        node_name="stepper_bridge",
        # The manual's line: 9600 baud 8N1, replies after 35 ms (the simulator's default).
        sim_args=lambda pty: ["-m", "stepper_bridge.sim", "--pty", str(pty)],
        node_module="stepper_bridge.node",
        node_params=lambda pty: {"serial_port": str(pty), "baudrate": 9600},
        state_type="msg_defs/msg/StepperState",
        format_state=_stepper_state,
        start_services=[
            ("motor_1/forward", "std_srvs/srv/Trigger", {}),
            ("motor_3/reverse", "std_srvs/srv/Trigger", {}),
            ("set_output", "msg_defs/srv/SetOutput", {"board": 0, "index": 2, "on": True}),
        ],
        serial=True,
    )
)


def _motec_state(state: Any) -> str:
    fault = f"fault {state.fault_code} {state.fault_text}" if state.fault_code else "no fault"
    return (
        f"{state.control_mode_name} control  {'enabled' if state.enabled else 'disabled'}  "
        f"position {state.position_actual} counts  speed {state.speed_actual_rpm} rpm  {fault}"
    )


MOTEC_UNITS = (1, 2, 3)
DEVICES.append(
    DemoDevice(
        name="MOTEC",
        node_name="motec_bridge",
        sim_args=lambda pty: [
            "-m",
            "motec_bridge.sim",
            "--pty",
            str(pty),
            "--unit-ids",
            ",".join(str(u) for u in MOTEC_UNITS),
        ],
        node_module="motec_bridge.node",
        node_params=lambda pty: {
            "serial_port": str(pty),
            "baudrate": 115200,
            "unit_ids": "[" + ",".join(str(u) for u in MOTEC_UNITS) + "]",
        },
        state_type="msg_defs/msg/MotecState",
        format_state=_motec_state,
        start_services=[
            *[
                (f"motec_{u}/{service}", type_name, fields)
                for u in MOTEC_UNITS
                for service, type_name, fields in (
                    ("set_control_mode", "msg_defs/srv/SetControlMode", {"mode": 2}),
                    ("enable", "std_srvs/srv/SetBool", {"data": True}),
                    (
                        "move",
                        "msg_defs/srv/PositionMove",
                        {"position": 100.0 * u, "relative": True, "max_velocity": 5.0},
                    ),
                )
            ],
        ],
        serial=True,
        state_nodes=[f"motec_{u}" for u in MOTEC_UNITS],
    )
)


def _import(type_name: str) -> Any:
    import importlib

    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


class Monitor:
    """An rclpy node that keeps the latest message of every device topic."""

    def __init__(self, devices: Sequence[DemoDevice]) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool

        rclpy.init()
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
            ns = f"/{device.name.lower()}"
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
        end = time.monotonic() + seconds
        while time.monotonic() < end:
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

    def close(self) -> None:
        from rclpy.utilities import try_shutdown

        self.executor.shutdown()
        self.node.destroy_node()
        try_shutdown()


def render(monitor: Monitor, device: DemoDevice, rates: dict[str, float]) -> str:
    ns = f"/{device.name.lower()}"
    lines: list[str] = []
    for node in device.nodes:
        connected = monitor.latest.get(f"{ns}/{node}/connected")
        diag = next(
            (
                s
                for k, s in monitor.latest.items()
                if k.startswith("diag:") and s.name.startswith(f"{node}:")
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


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="run the bridges against their simulators")
    parser.add_argument("--duration", type=float, default=0.0, help="seconds; 0 = until Ctrl-C")
    parser.add_argument(
        "--devices",
        default=",".join(d.name for d in DEVICES),
        help="comma-separated subset, e.g. R6",
    )
    args = parser.parse_args(argv)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # everything here is local
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.setdefault("ROS_DOMAIN_ID", str(DEFAULT_DOMAIN_ID))
    wanted = {n.strip().upper() for n in args.devices.split(",") if n.strip()}
    devices = [d for d in DEVICES if d.name.upper() in wanted]
    if not devices:
        parser.error(f"no known device in {args.devices!r}")

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
    monitor: Monitor | None = None
    try:
        for device in devices:
            where: Any = logs / f"{device.name.lower()}.pty" if device.serial else _free_port()
            spawn(f"{device.name.lower()}_sim", device.sim_args(where))
            params = device.node_params(where)
            ros_args = ["--ros-args", "-r", f"__ns:=/{device.name.lower()}"]
            for key, value in params.items():
                ros_args += ["-p", f"{key}:={value}"]
            spawn(device.node_name, ["-m", device.node_module, *ros_args])
        monitor = Monitor(devices)
        for device in devices:
            for service, type_name, fields in device.start_services:
                print(
                    "  "
                    + monitor.call(
                        # with several state nodes, the service names its node itself
                        f"/{device.name.lower()}/{service}"
                        if device.state_nodes
                        else f"/{device.name.lower()}/{device.node_name}/{service}",
                        type_name,
                        fields,
                    ),
                    flush=True,
                )
        started = time.monotonic()
        last_counts = dict(monitor.counts)
        while not stop["now"] and (
            args.duration <= 0 or time.monotonic() - started < args.duration
        ):
            monitor.spin_for(1.0)
            rates = {}
            for device in devices:
                ns = f"/{device.name.lower()}"
                topic = f"{ns}/joint_states"
                rates[ns] = float(monitor.counts[topic] - last_counts.get(topic, 0))
            last_counts = dict(monitor.counts)
            print(f"--- t = {time.monotonic() - started:5.1f} s", flush=True)
            for device in devices:
                print(render(monitor, device, rates), flush=True)
            for proc in processes:
                if proc.poll() is not None:
                    raise SystemExit(f"bridge_demo: a process exited ({proc.args!r}); see {logs}")
    except KeyboardInterrupt:
        pass
    finally:
        if monitor is not None:
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


if __name__ == "__main__":
    main()
