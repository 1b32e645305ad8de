#!/usr/bin/env python3
"""Bridge benchmark: poll rate, latency and CPU per cycle, as ratios
(docs/architecture.md, "Performance: how it is measured").

One bench for the TCP bridges, ``--device r6`` (default), ``--device xarm``, or
``--device modbus`` (modbus_bridge with config/devices/xarm.yaml, against the xArm's own
simulator: the bare loop then reads the generic bridge's poll plan), against that
bridge's simulator. Prints figures and writes them to
bench/results/<device>_bench.json; asserts nothing.

    .venv/bin/python bench/bridge_bench.py [--device r6|xarm|modbus] [--duration 5] [--quick]
        [--domain-id 101] [--phases rate,latency,cpu] [--json PATH]

(bench/r6_bench.py is the same bench under its old name.) Figures (see bench/README.md):
1. rate: a bare pymodbus loop issuing the node's read plan as fast as it can, the
   device layer (<Device>.poll) likewise, and the bridge node at poll_rate_hz 1000; ratio
   node rate / bare rate (goal >= 0.8), CPU per cycle of each. The read plan is the
   device's own rate groups (``<device>.groups`` after a first poll against the
   simulator, as the node sets them): the fast group every poll, the slow group first in
   a poll once ``slow_poll_period_s`` (the node's default) has passed, as ``PollGroups``
   does. The node's polls are counted from its own diagnostics: its transactions less the
   slow group's (``slow group``: requests, period, when last read), over the fast group's
   requests; its "achieved poll rate (Hz)" is printed beside them.
2. latency: register change in the simulator -> first joint_states carrying it (node at
   100 Hz; goal p99 <= poll period + 2 ms), and a command service call (R6
   ~/set_global_speed, xArm ~/set_digital_output) -> write in the simulator's write log.
3. cpu: at 100 Hz, node CPU per poll cycle vs floor A (bare rclpy publisher of the same
   three messages, bench/floor_rclpy_publisher.py) + floor B (bare pymodbus loop paced
   at 100 Hz); ratio node / (A + B) (goal <= 1.2).

Every measured loop runs in a process of its own (CPU from time.process_time inside it,
or from /proc/<pid>/stat utime+stime from outside); the simulator runs in a separate
process except in the latency phase, which changes its registers directly. Every ROS
process gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and ROS_DOMAIN_ID=--domain-id
(default 101: the tests use 1 + pid % 100; 0-101 or 215-232, see ``DOMAIN_ID_RULE``).
Only 127.0.0.1 is used.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib
import itertools
import json
import math
import os
import platform
import random
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# Nothing ROS-related is imported at module level: the worker processes (bare pymodbus
# loop, device loop) must not pay for rclpy, and the environment must be set first.

DEFAULT_DOMAIN_ID = 101
# ROS 2's "About Domain ID" page: with the default RTPS ports (7400 + 250 x domain id + a
# few per participant) ids 102-214 fall inside Linux's ephemeral ports (32768-60999), which
# the kernel hands to any socket, so a participant may fail to bind; above 232 the port
# passes 65535. 215-232 are safe but leave room for fewer participants per machine.
DOMAIN_IDS = (range(0, 102), range(215, 233))
DOMAIN_ID_RULE = (
    "0-101 or 215-232: with ROS 2's default ports ids 102-214 land in Linux's ephemeral "
    "ports 32768-60999 and may fail to bind (ROS 2 docs, 'About Domain ID')"
)
RESULTS = ROOT / "bench" / "results"
CLK_TCK = os.sysconf("SC_CLK_TCK")
UNIT_ID = 1
AXES, IO_BOARDS = 6, 1
DEG = math.pi / 180.0
GOAL_RATE_RATIO = 0.8
GOAL_CPU_RATIO = 1.2
GOAL_LATENCY_MARGIN_MS = 2.0
LATENCY_RATE_HZ = 100.0
CPU_RATE_HZ = 100.0
MAX_RATE_HZ = 1000.0  # the node's poll_rate_hz maximum


# ====================================================================== devices


@dataclass(frozen=True)
class Profile:
    """What differs between the benchmarked bridges; the rest of the bench is shared."""

    name: str  # --device
    title: str
    package: str  # <package>.device / .sim / .node; the node's name and diagnostics prefix
    device_class: str  # in <package>.device, constructed with a DeviceChannel
    sim_args: tuple[int, ...]  # <package>.sim.make_simulator(*sim_args), the node's defaults
    joint_register: str  # simulator register (degrees) that joint_states position[0] follows
    joint_raw_max: int  # random raw values for it in +-joint_raw_max
    service: str  # ~/<service>, timed from call to register write
    service_type: str  # in msg_defs.srv
    # k, rng -> (request, table value, address) the service must write
    service_request: Callable[[int, random.Random], tuple[Any, str, int]]
    sim_package: str = ""  # whose simulator (default: package)
    node_params: tuple[str, ...] = ()  # extra -p name:=value of the node
    # channel -> the device layer (default: <package>.device.<device_class>(channel))
    make_device: Callable[[Any], Any] | None = None

    @property
    def simulator(self) -> str:
        return self.sim_package or self.package


def _r6_service(k: int, rng: random.Random) -> tuple[Any, str, int]:
    from msg_defs.srv import SetValue
    from r6_bridge.registers import R6_MAP

    request = SetValue.Request()
    request.value = 20.0 + (k % 2) * 40.0 + rng.randint(0, 100) / 10.0
    return request, "holding", R6_MAP["global_speed"].address


def _xarm_service(k: int, rng: random.Random) -> tuple[Any, str, int]:
    from msg_defs.srv import SetOutput

    request = SetOutput.Request()
    request.board, request.index, request.state = 0, rng.randint(0, 15), k % 2 == 0
    return request, "coil", request.index  # FC 05 to coil `index`


XARM_DESCRIPTION = ROOT / "config" / "devices" / "xarm.yaml"


def _modbus_device(channel: Any) -> Any:
    from modbus_bridge.description import load
    from modbus_bridge.device import DescribedDevice

    return DescribedDevice(channel, load(XARM_DESCRIPTION).device)


def _modbus_service(k: int, rng: random.Random) -> tuple[Any, str, int]:
    from msg_defs.srv import SetValue

    request = SetValue.Request()
    request.value = (k % 2) * 5.0 + rng.randint(0, 40) / 10.0  # 0-9 V
    return request, "holding", 3  # controller AO 0, FC 06 to H3


PROFILES = {
    "r6": Profile(
        name="r6",
        title="R6",
        package="r6_bridge",
        device_class="R6Device",
        sim_args=(AXES, IO_BOARDS),
        joint_register="axis_position_1",
        joint_raw_max=170_000,  # +-170 deg (x1000)
        service="set_global_speed",
        service_type="SetValue",
        service_request=_r6_service,
    ),
    "xarm": Profile(
        name="xarm",
        title="xArm",
        package="xarm_bridge",
        device_class="XArmDevice",
        sim_args=(),
        joint_register="joint_angle_1",
        joint_raw_max=1_800,  # +-180 deg (x10, signed 16-bit)
        service="set_digital_output",
        service_type="SetOutput",
        service_request=_xarm_service,
    ),
    "modbus": Profile(
        name="modbus",
        title="modbus_bridge (xArm description)",
        package="modbus_bridge",
        device_class="DescribedDevice",
        sim_args=(),
        joint_register="joint_angle_1",
        joint_raw_max=1_800,
        service="set_analog_output_0",
        service_type="SetValue",
        service_request=_modbus_service,
        sim_package="xarm_bridge",
        node_params=(f"device_file:={XARM_DESCRIPTION}",),
        make_device=_modbus_device,
    ),
}


Block = tuple[str, int, int]  # (table, address, count) of one read request


@dataclass(frozen=True)
class ReadPlan:
    """What the node reads: its device's rate groups, in the order it reads them.

    ``fast`` every poll; ``slow`` first in a poll once ``slow_period_s`` has passed since
    it was last read (``bridge_core.runtime.rate_groups.PollGroups``).
    """

    fast: tuple[Block, ...]
    slow: tuple[Block, ...]
    slow_period_s: float

    def polls(self, transactions: float, slow_reads: float) -> float:
        """Polls in which the node made ``transactions``, ``slow_reads`` of them with the
        slow group."""
        return (transactions - len(self.slow) * slow_reads) / len(self.fast)

    def describe(self) -> str:
        return (
            f"fast {len(self.fast)} requests every poll, slow {len(self.slow)} every "
            f"{self.slow_period_s:g} s"
        )

    def to_json(self) -> dict[str, Any]:
        return {"fast": self.fast, "slow": self.slow, "slow_period_s": self.slow_period_s}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ReadPlan:
        def blocks(rows: list[list[Any]]) -> tuple[Block, ...]:
            return tuple((str(t), int(a), int(c)) for t, a, c in rows)

        return cls(blocks(data["fast"]), blocks(data["slow"]), float(data["slow_period_s"]))


def make_device(profile: Profile, channel: Any) -> Any:
    """The bridge's device layer on ``channel``, built as the node builds it (defaults)."""
    if profile.make_device is not None:
        return profile.make_device(channel)
    module = importlib.import_module(f"{profile.package}.device")
    return getattr(module, profile.device_class)(channel)


def device_plan(profile: Profile, port: int) -> ReadPlan:
    """The node's read plan: the device's rate groups after one poll of the simulator on
    ``port`` (the R6 plans by the axis and board counts it reads), with the node's default
    ``slow_poll_period_s``."""
    from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S
    from bridge_core.wire.channel import DeviceChannel
    from bridge_core.wire.transport import ModbusLink, TcpSettings

    link = ModbusLink(TcpSettings("127.0.0.1", port, 1.0))
    try:
        device = make_device(profile, DeviceChannel(link, UNIT_ID))
        device.poll()
        groups = device.groups
    finally:
        link.close()

    def blocks(requests: list[Any]) -> tuple[Block, ...]:
        return tuple((r.table.value, r.address, r.count) for r in requests)

    return ReadPlan(blocks(groups.fast), blocks(groups.slow), SLOW_POLL_PERIOD_DEFAULT_S)


# The node's diagnostics value "slow group" (bridge_core/ros/node_diagnostics.py,
# slow_group_text): "<n> request(s) every <p> s, last read <age> s ago".
SLOW_GROUP_KEY = "slow group"
SLOW_GROUP_TEXT = re.compile(
    r"(?P<requests>\d+) request\(s\) every (?P<period>[0-9.e+-]+) s, "
    r"(?:last read (?P<age>[0-9.]+) s ago|not read yet)"
)


def slow_group_status(text: str) -> tuple[int, float, float | None]:
    """(requests, period s, seconds since the last read or None) of the node's "slow
    group" value; (0, nan, None) when its slow group is empty."""
    if text.startswith("empty"):
        return 0, float("nan"), None
    match = SLOW_GROUP_TEXT.fullmatch(text)
    if match is None:
        raise ValueError(f"unexpected {SLOW_GROUP_KEY!r} diagnostics value: {text!r}")
    age = match["age"]
    return int(match["requests"]), float(match["period"]), None if age is None else float(age)


# ====================================================================== small helpers


def proc_cpu_s(pid: int) -> float:
    """utime + stime of a whole process (all threads, live and exited), in seconds."""
    text = Path(f"/proc/{pid}/stat").read_text()
    fields = text[text.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def percentile(samples: list[float], fraction: float) -> float:
    """Nearest-rank percentile (p99 of 200 samples is the 198th smallest)."""
    if not samples:
        return float("nan")
    data = sorted(samples)
    rank = max(1, math.ceil(fraction * len(data)))
    return data[rank - 1]


def median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def loadavg() -> list[float]:
    try:
        return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]
    except OSError:
        return []


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


# ====================================================================== worker processes
# ``bridge_bench.py --device D --worker bare|device --port N ...`` runs one loop and
# prints one JSON line.


def run_worker(args: argparse.Namespace) -> None:
    profile: Profile = args.profile
    if args.worker == "bare":
        from pymodbus.client import ModbusTcpClient

        client = ModbusTcpClient("127.0.0.1", port=args.port, timeout=1.0, retries=0)
        if not client.connect():  # type: ignore[no-untyped-call]  # untyped in pymodbus
            raise SystemExit(f"bare loop: cannot connect to 127.0.0.1:{args.port}")
        read = {  # FC 01 / 02 / 03 / 04, as the node's link issues them
            "coil": (client.read_coils, True),
            "discrete_input": (client.read_discrete_inputs, True),
            "holding": (client.read_holding_registers, False),
            "input": (client.read_input_registers, False),
        }
        plan = ReadPlan.from_json(json.loads(args.plan))
        fast = [(*read[table], address, count) for table, address, count in plan.fast]
        slow = [(*read[table], address, count) for table, address, count in plan.slow]
        slow_due = -math.inf  # read in the first poll, as PollGroups does

        def cycle() -> None:
            nonlocal slow_due
            due = bool(slow) and time.monotonic() >= slow_due
            for method, bits, address, count in [*slow, *fast] if due else fast:
                reply = method(address, count=count, device_id=UNIT_ID)
                # Bit replies come padded to whole bytes.
                if reply.isError() or len(reply.bits if bits else reply.registers) < count:
                    raise RuntimeError(f"bare loop: bad reply at {address}: {reply}")
            if due:  # due again one period after this poll's reads
                slow_due = time.monotonic() + plan.slow_period_s

        close: Callable[[], None] = client.close
    else:
        from bridge_core.wire.channel import DeviceChannel
        from bridge_core.wire.transport import ModbusLink, TcpSettings

        link = ModbusLink(TcpSettings("127.0.0.1", args.port, 1.0))
        device = make_device(profile, DeviceChannel(link, UNIT_ID))
        cycle = device.poll
        close = link.close

    period = 1.0 / args.rate if args.rate > 0 else 0.0
    slices = max(1, args.slices)
    slice_s = args.duration / slices
    clock = time.perf_counter
    next_due = clock()

    def pace() -> None:
        nonlocal next_due
        if period:
            next_due += period
            delay = next_due - clock()
            if delay > 0:
                time.sleep(delay)
            else:
                next_due = clock()  # late: do not burst to catch up

    warm_end = clock() + args.warmup
    while clock() < warm_end:
        cycle()
        pace()

    def sim_cpu() -> float:
        return proc_cpu_s(args.sim_pid) if args.sim_pid else float("nan")

    samples = []  # (wall, cpu, cycles, simulator cpu) at slice boundaries
    cycles = 0
    start = clock()
    samples.append((start, time.process_time(), 0, sim_cpu()))
    for k in range(1, slices + 1):
        boundary = start + k * slice_s
        while clock() < boundary:
            cycle()
            cycles += 1
            pace()
        samples.append((clock(), time.process_time(), cycles, sim_cpu()))
    close()
    print(json.dumps({"samples": samples}), flush=True)


def loop_figures(samples: list[list[float]]) -> dict[str, Any]:
    (w0, c0, n0, s0), (w1, c1, n1, s1) = samples[0], samples[-1]
    cycles = n1 - n0
    per_slice = []
    for (wa, _, na, _), (wb, _, nb, _) in itertools.pairwise(samples):
        if wb > wa:
            per_slice.append((nb - na) / (wb - wa))
    return {
        "rate_hz": cycles / (w1 - w0),
        "cpu_us_per_cycle": 1e6 * (c1 - c0) / cycles if cycles else float("nan"),
        "cpu_percent": 100.0 * (c1 - c0) / (w1 - w0),
        "cycles": cycles,
        "window_s": w1 - w0,
        "slice_rates_hz": per_slice,
        "sim_cpu_percent": 100.0 * (s1 - s0) / (w1 - w0),
        "cpu_source": "time.process_time in the loop process",
    }


# ====================================================================== processes


class Processes:
    """Child processes this bench started; stopped by pid (SIGINT, then SIGKILL)."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.children: list[subprocess.Popen[bytes]] = []

    def start(self, name: str, argv: list[str], capture: bool = False) -> subprocess.Popen[bytes]:
        log_file = (self.log_dir / f"{name}.log").open("wb")
        proc = subprocess.Popen(
            argv,
            cwd=ROOT,
            env=dict(os.environ),
            stdout=subprocess.PIPE if capture else log_file,
            stderr=log_file,
        )
        log_file.close()
        self.children.append(proc)
        return proc

    def stop(self, proc: subprocess.Popen[bytes], timeout: float = 10.0) -> None:
        from tests.support.ros import interrupt  # imports rclpy: only where it runs

        interrupt(proc, timeout)
        if proc in self.children:
            self.children.remove(proc)

    def stop_all(self) -> None:
        for proc in list(reversed(self.children)):
            self.stop(proc, 5.0)

    @contextmanager
    def running(self, name: str, argv: list[str]) -> Iterator[subprocess.Popen[bytes]]:
        proc = self.start(name, argv)
        try:
            yield proc
        finally:
            self.stop(proc)

    def run_worker(
        self,
        profile: Profile,
        kind: str,
        port: int,
        *,
        duration: float,
        warmup: float,
        rate: float,
        slices: int,
        plan: ReadPlan,
        sim_pid: int = 0,
    ) -> dict[str, Any]:
        argv = [
            sys.executable,
            str(Path(__file__).resolve()),
            "--device",
            profile.name,
            "--worker",
            kind,
            "--port",
            str(port),
            "--duration",
            str(duration),
            "--warmup",
            str(warmup),
            "--rate",
            str(rate),
            "--slices",
            str(slices),
            "--sim-pid",
            str(sim_pid),
            "--plan",
            json.dumps(plan.to_json()),
        ]
        proc = self.start(f"worker_{profile.name}_{kind}_{int(rate)}", argv, capture=True)
        try:
            out, _ = proc.communicate(timeout=duration + warmup + 60)
        finally:
            self.stop(proc)
        if proc.returncode != 0:
            raise RuntimeError(f"worker {kind} failed (rc {proc.returncode}); see {self.log_dir}")
        return loop_figures(json.loads(out.decode().strip().splitlines()[-1])["samples"])


def start_sim_process(
    procs: Processes, profile: Profile, extra: tuple[str, ...] = ()
) -> tuple[subprocess.Popen[bytes], int]:
    name = f"{profile.name}_sim"
    port_file = Path(tempfile.mkstemp(prefix=f"{name}_port_", dir=procs.log_dir)[1])
    port_file.write_text("")
    proc = procs.start(
        name,
        [
            sys.executable,
            "-m",
            f"{profile.simulator}.sim",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--port-file",
            str(port_file),
            *extra,
        ],
    )
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        text = port_file.read_text().strip()
        if text:
            port_file.unlink()
            return proc, int(text)
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    procs.stop(proc)
    raise RuntimeError(f"{name} did not start; see {procs.log_dir / (name + '.log')}")


def node_argv(profile: Profile, port: int, rate_hz: float) -> list[str]:
    return [
        sys.executable,
        "-m",
        f"{profile.package}.node",
        "--ros-args",
        "-p",
        f"port:={port}",
        "-p",
        f"poll_rate_hz:={rate_hz}",
        *(arg for param in profile.node_params for arg in ("-p", param)),
    ]


# ====================================================================== the bench's ROS side


class BenchClient:
    """One rclpy node in the bench process, spun by a SingleThreadedExecutor thread."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name="bench-executor", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # shutting down
                return

    def close(self) -> None:
        from rclpy.utilities import try_shutdown

        self.executor.shutdown()
        self.node.destroy_node()
        try_shutdown(context=self.context)
        self._thread.join(5)


class Counter:
    def __init__(self) -> None:
        self.n = 0
        self.first = threading.Event()

    def __call__(self, _msg: Any) -> None:
        self.n += 1
        self.first.set()


def wait_until(predicate: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


def measure_node(
    client: BenchClient,
    pid: int,
    *,
    package: str,
    duration: float,
    warmup: float,
    plan: ReadPlan,
    sim_pid: int = 0,
    startup_timeout: float = 60.0,
    subscribe_joint_states: bool = True,
) -> dict[str, Any]:
    """Rate and CPU per cycle of a running bridge node.

    ``subscribe_joint_states=False`` leaves the node without any joint_states subscriber,
    so a Python subscriber's own CPU (this process, on the same 2 cores) does not slow
    the simulator and the node: the bridge's capacity, comparable with the bare loop.

    Sampled in the /diagnostics callback (once a second): the node's cumulative
    transaction count and its slow group (requests, period, seconds since its last read),
    the node process's utime+stime from /proc, the number of joint_states this process
    received, and the node's own "achieved poll rate (Hz)". The node's polls between two
    samples: the transactions less the slow group's (its reads = the time between the
    two "last read" instants over its period, rounded: one each period), over the fast
    group's requests (``plan``, which must have as many slow requests as the node says);
    independent of what this subscriber keeps up with. The window runs from the first
    sample after warm-up to the first sample at least ``duration`` later (at least one
    diagnostics period).
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState

    joints = Counter()
    samples: list[dict[str, float]] = []
    lock = threading.Lock()

    def on_diag(msg: Any) -> None:
        cpu = proc_cpu_s(pid)
        sim_cpu = proc_cpu_s(sim_pid) if sim_pid else float("nan")
        for status in msg.status:
            # "/<node>: <device> Modbus bridge" (the fully qualified node name).
            if not status.name.lstrip("/").startswith(f"{package}:"):
                continue
            values = {kv.key: kv.value for kv in status.values}
            if "transactions" not in values:
                continue
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            slow_requests, slow_period, slow_age = slow_group_status(values[SLOW_GROUP_KEY])
            with lock:
                samples.append(
                    {
                        "mono": time.monotonic(),
                        "stamp": stamp,
                        "cpu": cpu,
                        "transactions": float(values["transactions"]),
                        "achieved": float(values.get("achieved poll rate (Hz)", "nan")),
                        "joint_states": joints.n,
                        "bench_cpu": time.process_time(),
                        "sim_cpu": sim_cpu,
                        "slow_requests": slow_requests,
                        "slow_period": slow_period,
                        # Wall-clock time of the slow group's last read (0.1 s resolution).
                        "slow_read": math.nan if slow_age is None else stamp - slow_age,
                    }
                )

    sub_j = (
        client.node.create_subscription(JointState, "/joint_states", joints, 10, raw=True)
        if subscribe_joint_states
        else None
    )
    sub_d = client.node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    try:
        if subscribe_joint_states and not joints.first.wait(startup_timeout):
            raise RuntimeError(f"no joint_states from {package}")
        if not subscribe_joint_states:
            wait_until(
                lambda: any(x["transactions"] > 0 for x in samples),
                startup_timeout,
                f"{package} polling",
            )
        time.sleep(warmup)
        t_start = time.monotonic()

        def window() -> list[dict[str, float]]:
            with lock:
                inside = [s for s in samples if s["mono"] >= t_start]
            if len(inside) >= 2 and inside[-1]["mono"] - inside[0]["mono"] >= duration - 0.5:
                return inside
            return []

        got = wait_until(window, duration + 15.0, f"diagnostics from {package}")
    finally:
        if sub_j is not None:
            client.node.destroy_subscription(sub_j)
        client.node.destroy_subscription(sub_d)
    a, b = got[0], got[-1]
    if b["slow_requests"] != len(plan.slow) or (
        plan.slow and b["slow_period"] != plan.slow_period_s
    ):
        raise RuntimeError(
            f"{package}'s slow group is {b['slow_requests']} request(s) every "
            f"{b['slow_period']:g} s, the bench's plan {plan.describe()}"
        )

    def slow_reads(x: dict[str, float], y: dict[str, float]) -> int:
        if not plan.slow:
            return 0
        between = y["slow_read"] - x["slow_read"]
        if math.isnan(between):
            raise RuntimeError(f"{package} had not read its slow group by the window")
        return round(between / plan.slow_period_s)

    pairs = [(x, y, slow_reads(x, y)) for x, y in itertools.pairwise(got)]
    slow_total = sum(n for _, _, n in pairs)
    cycles = plan.polls(b["transactions"] - a["transactions"], slow_total)
    span = b["stamp"] - a["stamp"]
    cpu = b["cpu"] - a["cpu"]
    slice_rates = [
        plan.polls(y["transactions"] - x["transactions"], n) / (y["stamp"] - x["stamp"])
        for x, y, n in pairs
        if y["stamp"] > x["stamp"]
    ]
    # The same count over the node's own rate window (the samples nearest its last
    # RATE_WINDOW_S), to set beside its "achieved poll rate (Hz)" of that window.
    from bridge_core.runtime.diagnostics import RATE_WINDOW_S

    k = min(range(len(got)), key=lambda i: abs(b["stamp"] - got[i]["stamp"] - RATE_WINDOW_S))
    tail = pairs[k:]
    tail_span = b["stamp"] - got[k]["stamp"]
    tail_polls = plan.polls(b["transactions"] - got[k]["transactions"], sum(n for *_, n in tail))
    return {
        "rate_hz": cycles / span,
        "rate_over_diagnostics_window_hz": tail_polls / tail_span if tail_span else math.nan,
        "diagnostics_window_s": tail_span,
        "diagnostics_rate_window_s": RATE_WINDOW_S,  # the node's "achieved poll rate" window
        "transactions": b["transactions"] - a["transactions"],
        "slow_group_reads": slow_total,
        "joint_states_received_hz": (b["joint_states"] - a["joint_states"])
        / (b["mono"] - a["mono"]),
        "diagnostics_achieved_hz": b["achieved"],
        "cpu_us_per_cycle": 1e6 * cpu / cycles if cycles else float("nan"),
        "cpu_percent": 100.0 * cpu / span,
        "cycles": cycles,
        "window_s": span,
        "slice_rates_hz": slice_rates,
        "bench_process_cpu_percent": 100.0
        * (b["bench_cpu"] - a["bench_cpu"])
        / (b["mono"] - a["mono"]),
        "sim_cpu_percent": 100.0 * (b["sim_cpu"] - a["sim_cpu"]) / (b["mono"] - a["mono"]),
        "cpu_source": "/proc/<pid>/stat utime+stime; cycles from the node's diagnostics "
        "(transactions less the slow group's, over the fast group's requests)",
    }


def measure_publisher(
    client: BenchClient,
    pid: int,
    topic: str,
    *,
    duration: float,
    warmup: float,
    startup_timeout: float = 60.0,
) -> dict[str, Any]:
    """Rate (messages received on ``topic``) and CPU per cycle of a publisher process."""
    from sensor_msgs.msg import JointState

    msgs = Counter()
    sub = client.node.create_subscription(JointState, topic, msgs, 10, raw=True)
    try:
        if not msgs.first.wait(startup_timeout):
            raise RuntimeError(f"no messages on {topic}")
        time.sleep(warmup)
        samples = []
        slices = max(1, round(duration))
        for k in range(slices + 1):
            if k:
                time.sleep(duration / slices)
            samples.append((time.monotonic(), proc_cpu_s(pid), msgs.n))
    finally:
        client.node.destroy_subscription(sub)
    (w0, c0, n0), (w1, c1, n1) = samples[0], samples[-1]
    cycles = n1 - n0
    return {
        "rate_hz": cycles / (w1 - w0),
        "cpu_us_per_cycle": 1e6 * (c1 - c0) / cycles if cycles else float("nan"),
        "cpu_percent": 100.0 * (c1 - c0) / (w1 - w0),
        "cycles": cycles,
        "window_s": w1 - w0,
        "slice_rates_hz": [
            (nb - na) / (wb - wa) for (wa, _, na), (wb, _, nb) in itertools.pairwise(samples)
        ],
        "cpu_source": "/proc/<pid>/stat utime+stime; cycles = messages received",
    }


# ====================================================================== phases


def phase_rate(
    opts: argparse.Namespace,
    procs: Processes,
    client: BenchClient,
    sim_port: int,
    sim_pid: int,
    plan: ReadPlan,
) -> dict[str, Any]:
    d, w, s, p = opts.duration, opts.warmup, opts.slices, opts.profile
    log(f"rate: bare pymodbus loop, max rate, {plan.describe()} ({d} s)")
    bare = procs.run_worker(
        p, "bare", sim_port, duration=d, warmup=w, rate=0, slices=s, plan=plan, sim_pid=sim_pid
    )
    log(f"rate: device layer {p.device_class}.poll(), max rate ({d} s)")
    device = procs.run_worker(
        p, "device", sim_port, duration=d, warmup=w, rate=0, slices=s, plan=plan, sim_pid=sim_pid
    )
    nodes: dict[str, Any] = {}
    for subscribed in (False, True):
        what = "bench subscribed" if subscribed else "no subscriber"
        log(f"rate: {p.package} node at poll_rate_hz {MAX_RATE_HZ:g}, {what} ({d} s)")
        name = f"{p.package}_1000{'_sub' if subscribed else ''}"
        with procs.running(name, node_argv(p, sim_port, MAX_RATE_HZ)) as proc:
            nodes[what] = measure_node(
                client,
                proc.pid,
                package=p.package,
                duration=d,
                warmup=w,
                plan=plan,
                sim_pid=sim_pid,
                subscribe_joint_states=subscribed,
            )
    node, node_sub = nodes["no subscriber"], nodes["bench subscribed"]
    return {
        "bare_pymodbus": bare,
        "device_loop": device,
        "node_1000": node,
        "node_1000_subscribed": node_sub,
        "ratio_node_to_bare": node["rate_hz"] / bare["rate_hz"],
        # The same ratio from the node's own "achieved poll rate (Hz)" (5 s window).
        "ratio_node_diagnostics_to_bare": node["diagnostics_achieved_hz"] / bare["rate_hz"],
        "ratio_node_subscribed_to_bare": node_sub["rate_hz"] / bare["rate_hz"],
        "ratio_device_to_bare": device["rate_hz"] / bare["rate_hz"],
        "goal_ratio_min": GOAL_RATE_RATIO,
    }


def phase_cpu(
    opts: argparse.Namespace,
    procs: Processes,
    client: BenchClient,
    sim_port: int,
    sim_pid: int,
    plan: ReadPlan,
) -> dict[str, Any]:
    d, w, s, p = opts.duration, opts.warmup, opts.slices, opts.profile
    rate = CPU_RATE_HZ
    log(f"cpu: {p.package} node at {rate:g} Hz ({d} s)")
    with procs.running(f"{p.package}_100", node_argv(p, sim_port, rate)) as proc:
        node = measure_node(
            client,
            proc.pid,
            package=p.package,
            duration=d,
            warmup=w,
            plan=plan,
            sim_pid=sim_pid,
        )
    floors: dict[str, Any] = {}
    for executor in ("single", *opts.extra_executors):
        log(f"cpu: floor A, bare rclpy publisher at {rate:g} Hz, {executor} executor ({d} s)")
        argv = [
            sys.executable,
            str(ROOT / "bench" / "floor_rclpy_publisher.py"),
            "--device",
            p.name,
            "--rate",
            str(rate),
            "--executor",
            executor,
            "--ros-args",
            "-r",
            "__ns:=/floor",
        ]
        with procs.running(f"floor_rclpy_{p.name}_{executor}", argv) as proc:
            floors[executor] = measure_publisher(
                client, proc.pid, "/floor/joint_states", duration=d, warmup=w
            )
    log(f"cpu: floor B, bare pymodbus loop paced at {rate:g} Hz ({d} s)")
    floor_b = procs.run_worker(
        p, "bare", sim_port, duration=d, warmup=w, rate=rate, slices=s, plan=plan, sim_pid=sim_pid
    )
    floor_a = floors["single"]
    floor_sum = floor_a["cpu_us_per_cycle"] + floor_b["cpu_us_per_cycle"]
    result = {
        "rate_hz": rate,
        "node": node,
        "floor_a_rclpy": floor_a,
        "floor_b_pymodbus": floor_b,
        "floor_sum_us_per_cycle": floor_sum,
        "ratio_node_to_floors": node["cpu_us_per_cycle"] / floor_sum,
        "goal_ratio_max": GOAL_CPU_RATIO,
    }
    for executor in opts.extra_executors:
        result[f"floor_a_rclpy_{executor}_executor"] = floors[executor]
    return result


def latency_stats(samples_s: list[float]) -> dict[str, Any]:
    ms = [1e3 * x for x in samples_s]
    return {
        "n": len(ms),
        "p50_ms": median(ms),
        "p99_ms": percentile(ms, 0.99),
        "max_ms": max(ms) if ms else float("nan"),
        "min_ms": min(ms) if ms else float("nan"),
    }


def phase_latency(
    opts: argparse.Namespace, procs: Processes, client: BenchClient
) -> dict[str, Any]:
    from sensor_msgs.msg import JointState

    p: Profile = opts.profile
    # The simulator's tick() keeps running: both simulators leave the joints alone while
    # idle (R6 not running, xArm sleeping), which is how they start.
    sim = importlib.import_module(f"{p.simulator}.sim").make_simulator(*p.sim_args)
    sim.round_trip_s = opts.reply_delay_ms / 1000.0  # --reply-delay-ms, as in the other phases
    sim.nagle = opts.nagle
    port = sim.start_tcp("127.0.0.1", 0)
    device = sim.device
    rng = random.Random(opts.seed)
    scale = device.map[p.joint_register].scale
    state: dict[str, Any] = {"expected": None, "t1": 0.0, "t1_wall": 0.0, "stamp": 0.0}
    arrived = threading.Event()
    first = threading.Event()

    def on_joints(msg: Any) -> None:
        now, now_wall = time.monotonic(), time.time()
        first.set()
        expected = state["expected"]
        if expected is not None and msg.position and abs(msg.position[0] - expected) < 1e-9:
            state["expected"] = None
            state["t1"], state["t1_wall"] = now, now_wall
            state["stamp"] = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            arrived.set()

    service = f"/{p.package}/{p.service}"
    srv_type = getattr(importlib.import_module("msg_defs.srv"), p.service_type)
    sub = client.node.create_subscription(JointState, "/joint_states", on_joints, 10)
    srv = client.node.create_client(srv_type, service)
    register_s: list[float] = []
    in_flight_s: list[float] = []  # poll start (header stamp) -> arrival
    write_s: list[float] = []
    response_s: list[float] = []
    missed = failed = 0
    try:
        log(
            f"latency: {p.package} at {LATENCY_RATE_HZ:g} Hz, simulator in this process, "
            f"{opts.changes} register changes"
        )
        with procs.running(f"{p.package}_latency", node_argv(p, port, LATENCY_RATE_HZ)):
            if not first.wait(60):
                raise RuntimeError(f"no joint_states from {p.package}")
            time.sleep(opts.warmup)
            last_raw = None
            for _ in range(opts.changes):
                raw = last_raw
                while raw == last_raw:
                    raw = rng.randint(-p.joint_raw_max, p.joint_raw_max)
                last_raw = raw
                value = raw / scale
                arrived.clear()
                state["expected"] = value * DEG  # what the node computes: deg * DEG
                t0 = time.monotonic()
                device.set(p.joint_register, value)
                if arrived.wait(1.0):
                    register_s.append(state["t1"] - t0)
                    in_flight_s.append(state["t1_wall"] - state["stamp"])
                else:
                    state["expected"] = None
                    missed += 1
                time.sleep(rng.uniform(0.020, 0.050))

            log(f"latency: {opts.service_calls} ~/{p.service} calls")
            wait_until(srv.service_is_ready, 30, f"service {service}")
            for k in range(opts.service_calls):
                request, table, address = p.service_request(k, rng)
                done = threading.Event()
                with device.lock:
                    seen = len(device.write_log)
                t0_wall = time.time()
                t0 = time.monotonic()
                future = srv.call_async(request)
                future.add_done_callback(lambda _f, e=done: e.set())
                if not done.wait(5.0) or not future.result().success:
                    failed += 1
                    continue
                response_s.append(time.monotonic() - t0)
                with device.lock:
                    new = [
                        r
                        for r in device.write_log[seen:]
                        if r.table.value == table and r.address == address
                    ]
                if new:
                    write_s.append(new[0].time - t0_wall)
                else:
                    failed += 1
                time.sleep(rng.uniform(0.020, 0.050))
    finally:
        client.node.destroy_subscription(sub)
        client.node.destroy_client(srv)
        sim.stop()
    period_ms = 1e3 / LATENCY_RATE_HZ
    reg = latency_stats(register_s)
    reg["missed"] = missed
    return {
        "poll_rate_hz": LATENCY_RATE_HZ,
        "joint_register": p.joint_register,
        "service": service,
        "register_to_joint_states": reg,
        # The part after the poll started (JointState stamp = wall time of a read in the
        # poll: R6 the last block's, xArm the first's): the rest of the poll, decode,
        # publish, delivery to this process.
        "poll_start_to_joint_states": latency_stats(in_flight_s),
        "goal_p99_max_ms": period_ms + GOAL_LATENCY_MARGIN_MS,
        "service_call_to_register_write": {**latency_stats(write_s), "failed": failed},
        "service_call_to_response": latency_stats(response_s),
    }


# ====================================================================== report


def fmt(value: Any, digits: int = 1) -> str:
    if isinstance(value, float):
        return "n/a" if math.isnan(value) else f"{value:.{digits}f}"
    return str(value)


def print_table(results: dict[str, Any]) -> None:
    meta = results["meta"]
    p = PROFILES[meta["device"]]
    print()
    print(
        f"{p.title} bench {meta['date']}  {meta['machine']}  duration {meta['duration_s']} s/phase"
        f"  load {meta['loadavg_before']} -> {meta['loadavg_after']}"
    )
    if "read_plan" in meta:
        plan = ReadPlan.from_json(meta["read_plan"])
        print(
            f"read plan of the node and the bare loops (the device's rate groups): "
            f"{plan.describe()}"
        )
    rows: list[tuple[str, str, str, str, str]] = []
    if "rate" in results:
        r = results["rate"]
        for key, label in (
            ("bare_pymodbus", "1a bare pymodbus loop, max"),
            ("device_loop", f"1  {p.device_class}.poll() loop, max (context)"),
            ("node_1000", f"1b {p.package}, poll_rate_hz 1000, no subscriber"),
            ("node_1000_subscribed", f"   {p.package}, 1000 Hz, bench subscribed (context)"),
        ):
            m = r[key]
            rows.append(
                (
                    label,
                    fmt(m["rate_hz"]),
                    fmt(m["cpu_us_per_cycle"], 0),
                    fmt(m["cpu_percent"]),
                    fmt(m["sim_cpu_percent"], 0),
                )
            )
        m = r["node_1000"]
        rows.append(
            (
                f"   1b counted, last {fmt(m['diagnostics_window_s'])} s / node's diagnostics "
                f"({m['diagnostics_rate_window_s']:g} s)",
                f"{fmt(m['rate_over_diagnostics_window_hz'])} / "
                f"{fmt(m['diagnostics_achieved_hz'])}",
                "",
                "",
                "",
            )
        )
        n = r["node_1000_subscribed"]
        rows.append(
            (
                "   subscribed: joint_states received / diag achieved",
                f"{fmt(n['joint_states_received_hz'])} / {fmt(n['diagnostics_achieved_hz'])}",
                "",
                "",
                "",
            )
        )
    if "cpu" in results:
        c = results["cpu"]
        rows.append(
            (
                f"3  {p.package} at 100 Hz",
                fmt(c["node"]["rate_hz"]),
                fmt(c["node"]["cpu_us_per_cycle"], 0),
                fmt(c["node"]["cpu_percent"]),
                fmt(c["node"]["sim_cpu_percent"], 0),
            )
        )
        rows.append(
            (
                "3  floor A: rclpy publisher, 100 Hz",
                fmt(c["floor_a_rclpy"]["rate_hz"]),
                fmt(c["floor_a_rclpy"]["cpu_us_per_cycle"], 0),
                fmt(c["floor_a_rclpy"]["cpu_percent"]),
                "",
            )
        )
        for key, m in c.items():
            if key.startswith("floor_a_rclpy_") and isinstance(m, dict):
                name = key.removeprefix("floor_a_rclpy_").removesuffix("_executor")
                rows.append(
                    (
                        f"   floor A with {name} executor (context)",
                        fmt(m["rate_hz"]),
                        fmt(m["cpu_us_per_cycle"], 0),
                        fmt(m["cpu_percent"]),
                        "",
                    )
                )
        rows.append(
            (
                "3  floor B: pymodbus loop paced 100 Hz",
                fmt(c["floor_b_pymodbus"]["rate_hz"]),
                fmt(c["floor_b_pymodbus"]["cpu_us_per_cycle"], 0),
                fmt(c["floor_b_pymodbus"]["cpu_percent"]),
                fmt(c["floor_b_pymodbus"]["sim_cpu_percent"], 0),
            )
        )
    if rows:
        width = max(len(r[0]) for r in rows)
        head = ("cycles/s", "CPU us/cycle", "CPU %core", "sim %core")
        print(f"{'loop':<{width}}  {head[0]:>14}  {head[1]:>12}  {head[2]:>9}  {head[3]:>9}")
        for label, rate, cpu, pct, sim in rows:
            print(f"{label:<{width}}  {rate:>14}  {cpu:>12}  {pct:>9}  {sim:>9}")
        print()
    figures: list[tuple[str, str, str, str]] = []  # figure, value, goal, note

    def verdict(ok: bool) -> str:
        return "met" if ok else "MISSED"

    if "rate" in results:
        r = results["rate"]
        ratio, goal = r["ratio_node_to_bare"], r["goal_ratio_min"]
        figures.append(
            (
                "1  rate node(1000 Hz) / bare pymodbus",
                f"{ratio:.2f}",
                f">= {goal} {verdict(ratio >= goal)}",
                f"from the node's diagnostics (achieved poll rate) "
                f"{r['ratio_node_diagnostics_to_bare']:.2f}; device loop / bare "
                f"{r['ratio_device_to_bare']:.2f}; with the bench subscribed to "
                f"joint_states {r['ratio_node_subscribed_to_bare']:.2f}",
            )
        )
    if "latency" in results:
        lat = results["latency"]
        reg, fl = lat["register_to_joint_states"], lat["poll_start_to_joint_states"]
        goal = lat["goal_p99_max_ms"]
        figures.append(
            (
                "2  register -> joint_states p50/p99/max ms",
                f"{fmt(reg['p50_ms'])}/{fmt(reg['p99_ms'])}/{fmt(reg['max_ms'])}",
                f"p99 <= {goal:g} {verdict(reg['p99_ms'] <= goal)}",
                f"n {reg['n']}, missed {reg['missed']}; poll start -> msg "
                f"p50/p99 {fmt(fl['p50_ms'])}/{fmt(fl['p99_ms'])}",
            )
        )
        sw, sr = lat["service_call_to_register_write"], lat["service_call_to_response"]
        figures.append(
            (
                "2  service call -> register write p50/p99 ms",
                f"{fmt(sw['p50_ms'], 2)}/{fmt(sw['p99_ms'], 2)}",
                "",
                f"n {sw['n']}, failed {sw['failed']}; call -> response "
                f"p50/p99 {fmt(sr['p50_ms'], 2)}/{fmt(sr['p99_ms'], 2)}",
            )
        )
    if "cpu" in results:
        c = results["cpu"]
        ratio, goal = c["ratio_node_to_floors"], c["goal_ratio_max"]
        figures.append(
            (
                "3  CPU/cycle node / (floor A + floor B)",
                f"{ratio:.2f}",
                f"<= {goal} {verdict(ratio <= goal)}",
                f"{fmt(c['node']['cpu_us_per_cycle'], 0)} / "
                f"({fmt(c['floor_a_rclpy']['cpu_us_per_cycle'], 0)} + "
                f"{fmt(c['floor_b_pymodbus']['cpu_us_per_cycle'], 0)}) us",
            )
        )
    if figures:
        fw = max(len(f[0]) for f in figures)
        vw = max(len(f[1]) for f in figures)
        gw = max(len(f[2]) for f in figures)
        print(f"{'figure':<{fw}}  {'value':>{vw}}  {'goal':<{gw}}  note")
        for name, value, goal_text, note in figures:
            print(f"{name:<{fw}}  {value:>{vw}}  {goal_text:<{gw}}  {note}")
    print()


# ====================================================================== main


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description="Bridge benchmark (prints figures)")
    parser.add_argument(
        "--device", choices=sorted(PROFILES), default="r6", help="bridge to measure (default r6)"
    )
    parser.add_argument("--duration", type=float, default=5.0, help="measured seconds per phase")
    parser.add_argument(
        "--warmup",
        type=float,
        default=None,
        help="discarded seconds before each measurement (default 1, quick 0.3)",
    )
    parser.add_argument("--quick", action="store_true", help="~1 s phases, fewer latency samples")
    parser.add_argument(
        "--domain-id",
        type=int,
        default=DEFAULT_DOMAIN_ID,
        help=f"ROS_DOMAIN_ID for the bench and its nodes (default {DEFAULT_DOMAIN_ID})",
    )
    parser.add_argument(
        "--phases", default="rate,latency,cpu", help="comma-separated subset of rate,latency,cpu"
    )
    parser.add_argument("--changes", type=int, default=None, help="register changes (default 200)")
    parser.add_argument(
        "--service-calls", type=int, default=None, help="service calls (default 100)"
    )
    parser.add_argument(
        "--extra-executors",
        default="multi,events",
        help="also measure floor A with these executors (comma list of multi,events; '' for none)",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--reply-delay-ms",
        type=float,
        default=0.0,
        help="the simulator's simulated round trip (bench/pipelining.py)",
    )
    parser.add_argument(
        "--max-in-flight", type=int, default=1, help="the node's max_in_flight (default 1)"
    )
    parser.add_argument(
        "--nagle",
        action="store_true",
        help="the simulator leaves Nagle on for its replies (its --nagle personality)",
    )
    parser.add_argument(
        "--json", type=Path, default=None, help="default bench/results/<device>_bench.json"
    )
    # worker mode (internal)
    parser.add_argument("--worker", choices=("bare", "device"), help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--rate", type=float, default=0.0, help=argparse.SUPPRESS)
    parser.add_argument("--slices", type=int, default=5, help=argparse.SUPPRESS)
    parser.add_argument("--sim-pid", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--plan", default="", help=argparse.SUPPRESS)  # ReadPlan as JSON
    opts = parser.parse_args(argv)
    opts.profile = PROFILES[opts.device]
    opts.sim_extra = ("--reply-delay-ms", str(opts.reply_delay_ms)) if opts.reply_delay_ms else ()
    if opts.nagle:
        opts.sim_extra = (*opts.sim_extra, "--nagle")
    if opts.max_in_flight != 1:
        opts.profile = dataclasses.replace(
            opts.profile,
            node_params=(*opts.profile.node_params, f"max_in_flight:={opts.max_in_flight}"),
        )
    opts.json = opts.json or RESULTS / f"{opts.device}_bench.json"
    if opts.quick:
        if "--duration" not in (argv if argv is not None else sys.argv):
            opts.duration = 1.0
        opts.changes = opts.changes or 40
        opts.service_calls = opts.service_calls or 20
        opts.warmup = 0.3 if opts.warmup is None else opts.warmup
    opts.changes = opts.changes or 200
    opts.service_calls = opts.service_calls or 100
    opts.warmup = 1.0 if opts.warmup is None else opts.warmup
    opts.extra_executors = [e for e in opts.extra_executors.split(",") if e]
    if not any(opts.domain_id in ids for ids in DOMAIN_IDS):
        parser.error(f"--domain-id {opts.domain_id}: use {DOMAIN_ID_RULE}")
    return opts


def isolate_ros(domain_id: int) -> None:
    """ROS discovery on this machine, in ``domain_id``: before rclpy is imported anywhere;
    inherited by every child process (bench/read_rates.py calls it too)."""
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.setdefault("PYTHONUNBUFFERED", "1")


def main(argv: list[str] | None = None) -> None:
    opts = parse_args(argv)
    if opts.worker:
        run_worker(opts)
        return
    isolate_ros(opts.domain_id)
    phases = [p.strip() for p in opts.phases.split(",") if p.strip()]
    unknown = set(phases) - {"rate", "latency", "cpu"}
    if unknown:
        raise SystemExit(f"unknown phases {sorted(unknown)}")

    import pymodbus

    RESULTS.mkdir(parents=True, exist_ok=True)
    log_dir = RESULTS / "logs"
    log_dir.mkdir(exist_ok=True)
    results: dict[str, Any] = {
        "meta": {
            "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "machine": f"{platform.node()} {os.cpu_count()} CPU {platform.machine()}",
            "python": platform.python_version(),
            "pymodbus": pymodbus.__version__,
            "duration_s": opts.duration,
            "warmup_s": opts.warmup,
            "quick": opts.quick,
            "ros_domain_id": opts.domain_id,
            "device": opts.device,
            "loadavg_before": loadavg(),
        }
    }
    log(
        f"{opts.device} bench: domain {opts.domain_id}, {opts.duration} s per phase, "
        f"phases {','.join(phases)}; logs in {log_dir}"
    )
    procs = Processes(log_dir)
    client = BenchClient(f"{opts.device}_bench")
    started = time.monotonic()
    try:
        if "rate" in phases or "cpu" in phases:
            sim_proc, sim_port = start_sim_process(procs, opts.profile, opts.sim_extra)
            try:
                plan = device_plan(opts.profile, sim_port)
                results["meta"]["read_plan"] = plan.to_json()
                log(f"read plan (the device's rate groups): {plan.describe()}")
                args = (opts, procs, client, sim_port, sim_proc.pid, plan)
                if "rate" in phases:
                    results["rate"] = phase_rate(*args)
                if "cpu" in phases:
                    results["cpu"] = phase_cpu(*args)
            finally:
                procs.stop(sim_proc)
        if "latency" in phases:
            results["latency"] = phase_latency(opts, procs, client)
    finally:
        procs.stop_all()
        with suppress(Exception):
            client.close()
    results["meta"]["loadavg_after"] = loadavg()
    results["meta"]["elapsed_s"] = round(time.monotonic() - started, 1)
    print_table(results)
    opts.json.parent.mkdir(parents=True, exist_ok=True)
    opts.json.write_text(json.dumps(results, indent=2) + "\n")
    log(f"wrote {opts.json}")


if __name__ == "__main__":
    main()
