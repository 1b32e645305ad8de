"""How long this machine leaves a process, a pty link and a loopback socket waiting.

Run it beside something else (the suite, CPU burners) to see the stalls the tests meet:
a thread that sleeps 10 ms and notes how late it wakes; a byte echoed through a socat pty
pair (as the RTU tests' links are) by a child process; the same through one pty without
socat (``rawpty``: the master end here, the child on the other); a byte echoed over
loopback TCP by another child; a 4 KiB write() to a file under the temp dir. Each probe
runs in its own thread; at the end it prints, per probe, the count, median, p99 and max
wait, the waits over ``--stall-ms`` with their wall-clock times, and how much the kernel's
pressure stall information (``/proc/pressure``: CPU and IO, where the kernel has it) grew meanwhile.

    .venv/bin/python bench/stall_probe.py --seconds 300   # Ctrl-C ends it early

No ROS; loopback and pseudo-terminals only.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bridge_core.sim.pty_pair import PtyPair  # noqa: E402

SLEEP_S = 0.010  # the sleeping probe's nap
ECHO_PERIOD_S = 0.020  # one echoed byte per period on the pty and TCP probes
WRITE_PERIOD_S = 0.050  # one 4 KiB write per period
WRITE_BYTES = 4096
WRITE_FILE_BYTES = 64 * 1024 * 1024  # the written file starts over past this size

PTY_ECHO = """
import os, sys, termios, tty
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
tty.setraw(fd)
while True:
    data = os.read(fd, 64)
    if not data:
        break
    os.write(fd, data)
"""

TCP_ECHO = """
import socket, sys
server = socket.create_server(("127.0.0.1", 0))
print(server.getsockname()[1], flush=True)
conn, _ = server.accept()
conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
while True:
    data = conn.recv(64)
    if not data:
        break
    conn.sendall(data)
"""


def pressure() -> dict[str, float]:
    """Cumulative stall times (s) from /proc/pressure: 'cpu some', 'io some', 'io full'."""
    found: dict[str, float] = {}
    for resource in ("cpu", "io"):
        try:
            text = Path(f"/proc/pressure/{resource}").read_text()
        except OSError:
            continue
        for line in text.splitlines():
            kind, *fields = line.split()
            total = dict(f.split("=") for f in fields)["total"]
            found[f"{resource} {kind}"] = int(total) / 1e6
    return found


@dataclass
class Probe:
    name: str
    waits: list[float] = field(default_factory=list)
    stalls: list[tuple[float, float, dict[str, float]]] = field(default_factory=list)

    def note(
        self, wall_start: float, wait_s: float, before: dict[str, float], stall_s: float
    ) -> None:
        self.waits.append(wait_s)
        if wait_s >= stall_s:
            after = pressure()
            grown = {k: after[k] - before.get(k, after[k]) for k in after}
            self.stalls.append((wall_start, wait_s, grown))


def run_sleep(probe: Probe, stop: threading.Event, stall_s: float) -> None:
    while not stop.is_set():
        before, wall, start = pressure(), time.time(), time.monotonic()
        time.sleep(SLEEP_S)
        probe.note(wall, time.monotonic() - start - SLEEP_S, before, stall_s)


def echo_loop(probe: Probe, stop: threading.Event, stall_s: float, send, receive) -> None:  # type: ignore[no-untyped-def]
    while not stop.is_set():
        before, wall, start = pressure(), time.time(), time.monotonic()
        send(b"x")
        if receive(1) != b"x":
            raise RuntimeError(f"{probe.name}: the echo went wrong")
        probe.note(wall, time.monotonic() - start, before, stall_s)
        time.sleep(ECHO_PERIOD_S)


def fd_echo(probe: Probe, stop: threading.Event, stall_s: float, fd: int) -> threading.Thread:
    """The echo probe's thread on a pty end."""
    return threading.Thread(
        target=echo_loop,
        args=(probe, stop, stall_s, lambda b: os.write(fd, b), lambda n: os.read(fd, n)),
    )


def run_writes(probe: Probe, stop: threading.Event, stall_s: float, path: Path) -> None:
    block = os.urandom(WRITE_BYTES)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    written = 0
    try:
        while not stop.is_set():
            if written >= WRITE_FILE_BYTES:
                os.ftruncate(fd, 0)
                os.lseek(fd, 0, os.SEEK_SET)
                written = 0
            before, wall, start = pressure(), time.time(), time.monotonic()
            written += os.write(fd, block)
            probe.note(wall, time.monotonic() - start, before, stall_s)
            time.sleep(WRITE_PERIOD_S)
    finally:
        os.close(fd)


def report(probes: list[Probe], stall_s: float) -> None:
    for probe in probes:
        waits = sorted(probe.waits) or [0.0]
        p99 = waits[min(len(waits) - 1, int(0.99 * len(waits)))]
        print(
            f"{probe.name:6} n={len(probe.waits):6}"
            f"  median {statistics.median(waits) * 1e3:7.2f} ms"
            f"  p99 {p99 * 1e3:8.2f} ms  max {waits[-1] * 1e3:8.1f} ms"
            f"  waits >= {stall_s * 1e3:.0f} ms: {len(probe.stalls)}"
        )
    stalls = sorted(
        (wall, probe.name, wait, grown) for probe in probes for wall, wait, grown in probe.stalls
    )
    for wall, name, wait, grown in stalls:
        stamp = time.strftime("%H:%M:%S", time.gmtime(wall)) + f".{int(wall % 1 * 1000):03d}"
        pressures = ", ".join(f"{k} +{v:.2f} s" for k, v in grown.items())
        print(f"  {stamp} UTC  {name:6} {wait * 1e3:8.1f} ms  ({pressures})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument(
        "--stall-ms", type=float, default=200.0, help="list waits at least this long"
    )
    args = parser.parse_args()
    stall_s = args.stall_ms / 1e3
    stop = threading.Event()
    children: list[subprocess.Popen[bytes]] = []
    with tempfile.TemporaryDirectory(prefix="stall_probe_") as tmp:
        pair = PtyPair(Path(tmp) / "link")
        try:
            children.append(
                subprocess.Popen([sys.executable, "-c", PTY_ECHO, str(pair.device_end)])
            )
            master_fd, slave_fd = os.openpty()
            children.append(
                subprocess.Popen([sys.executable, "-c", PTY_ECHO, os.ttyname(slave_fd)])
            )
            os.close(slave_fd)
            tcp_child = subprocess.Popen([sys.executable, "-c", TCP_ECHO], stdout=subprocess.PIPE)
            children.append(tcp_child)
            assert tcp_child.stdout is not None
            port = int(tcp_child.stdout.readline())
            sock = socket.create_connection(("127.0.0.1", port))
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            link_fd = os.open(pair.link, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(link_fd)
            probes = [Probe("sleep"), Probe("pty"), Probe("rawpty"), Probe("tcp"), Probe("write")]
            threads = [
                threading.Thread(target=run_sleep, args=(probes[0], stop, stall_s)),
                fd_echo(probes[1], stop, stall_s, link_fd),
                fd_echo(probes[2], stop, stall_s, master_fd),
                threading.Thread(
                    target=echo_loop, args=(probes[3], stop, stall_s, sock.sendall, sock.recv)
                ),
                threading.Thread(
                    target=run_writes, args=(probes[4], stop, stall_s, Path(tmp) / "written")
                ),
            ]
            for thread in threads:
                thread.daemon = True
                thread.start()
            print(
                f"stall_probe: {args.seconds:.0f} s from "
                f"{time.strftime('%H:%M:%S', time.gmtime())} UTC",
                flush=True,
            )
            with contextlib.suppress(KeyboardInterrupt):
                stop.wait(args.seconds)
            stop.set()
            for thread in threads:
                thread.join(5.0)
            report(probes, stall_s)
        finally:
            for child in children:
                child.kill()
                child.wait()
            pair.close()


if __name__ == "__main__":
    main()
