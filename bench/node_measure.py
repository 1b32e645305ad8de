"""A running bridge node's poll rate and CPU per cycle, counted from its own /diagnostics
(bench/bridge_bench.py, rate and cpu phases; bench/read_rates.py); floor A's (a bare
rclpy publisher) from the messages it sends. The bench's own rclpy node
(``BenchClient``) subscribes to both.
"""

from __future__ import annotations

import itertools
import math
import re
import threading
import time
from typing import Any

from bench.bare_loops import ReadPlan
from bench.bench_processes import cycle_figures, proc_cpu_s, wait_until

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
        "rate_over_diagnostics_window_hz": tail_polls / tail_span if tail_span else math.nan,
        "diagnostics_window_s": tail_span,
        "diagnostics_rate_window_s": RATE_WINDOW_S,  # the node's "achieved poll rate" window
        "transactions": b["transactions"] - a["transactions"],
        "slow_group_reads": slow_total,
        "joint_states_received_hz": (b["joint_states"] - a["joint_states"])
        / (b["mono"] - a["mono"]),
        "diagnostics_achieved_hz": b["achieved"],
        **cycle_figures(cycles, cpu, span),
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
        **cycle_figures(cycles, c1 - c0, w1 - w0),
        "slice_rates_hz": [
            (nb - na) / (wb - wa) for (wa, _, na), (wb, _, nb) in itertools.pairwise(samples)
        ],
        "cpu_source": "/proc/<pid>/stat utime+stime; cycles = messages received",
    }
