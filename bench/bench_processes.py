"""The child processes of bench/bridge_bench.py (the simulator, the bridge nodes, the
loops, floor A), each with its log in bench/results/logs/ and stopped by its pid; a
process's CPU from /proc; the small helpers every part of the bench uses.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from bench.bridge_profiles import Profile

ROOT = Path(__file__).resolve().parents[1]
CLK_TCK = os.sysconf("SC_CLK_TCK")


def proc_cpu_s(pid: int) -> float:
    """utime + stime of a whole process (all threads, live and exited), in seconds."""
    text = Path(f"/proc/{pid}/stat").read_text()
    fields = text[text.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def loadavg() -> list[float]:
    try:
        return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]
    except OSError:
        return []


def cycle_figures(cycles: float, cpu_s: float, window_s: float) -> dict[str, float]:
    """The figures every measured loop reports over its window (the bare loops, the
    device layer, the node, the floor publisher): rate, CPU per cycle and CPU share."""
    return {
        "rate_hz": cycles / window_s,
        "cpu_us_per_cycle": 1e6 * cpu_s / cycles if cycles else float("nan"),
        "cpu_percent": 100.0 * cpu_s / window_s,
        "cycles": cycles,
        "window_s": window_s,
    }


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


def wait_until(predicate: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


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
