#!/usr/bin/env python3
"""An emulated byte-timed RS-485 line between two pseudo-terminals (benches and tests).

Pseudo-terminals ignore the baud rate (960 bytes "at 9600" arrive in ~0.2 ms), so RTU
timing cannot be measured on a plain pty pair. This relay sits between two pty pairs
and releases each byte one character time (``bits_per_char / baud``) after the previous
one on ONE timeline shared by both directions (RS-485 is half-duplex: a reply cannot
start while the request is still on the line). It adds no other delay: its own latency
(pty transfer plus wake-up, the smallest of those measured at start) is subtracted from
the schedule, so the receiver sees each byte about when it would finish on a real wire
(checked: within ~+0.1 ms per frame, ``--check``).

It runs in a process of its own so the process under test (client and simulator
threads sharing one GIL) cannot delay it, and records every frame of both directions
with its start and end on the emulated wire (``time.monotonic()``, the same clock in
every process) so a caller can check inter-frame silences::

    with LineRelay(9600) as line:       # line.client_path, line.device_path
        ...                             # client on client_path, device on device_path
        frames = line.frames()
    assert not silence_violations(frames, line.silence_s)

``device_turnaround_s`` optionally holds the device's reply until that long after the
request ended on the wire, for simulators that answer faster than a real RTU device
(which cannot see the end of a request before 3.5 characters of silence).

``python bench/line_relay.py --check`` compares transfer times with theory.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import ctypes
import gc
import json
import os
import pty
import select
import statistics
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from itertools import pairwise
from typing import Any

REQUEST = "request"  # bus master (client) -> device
REPLY = "reply"  # device -> bus master
BITS_PER_CHAR_8N1 = 10
# Modbus serial line spec §2.5.1.1: frames are separated by >= 3.5 characters of silence
# and a frame may not pause for more than 1.5 characters; above 19200 baud both are fixed.
SILENCE_CHARS = 3.5
INTRA_FRAME_GAP_CHARS = 1.5
FIXED_TIMING_ABOVE_BAUD = 19200
SILENCE_FIXED_S = 0.00175
INTRA_FRAME_GAP_FIXED_S = 0.00075
# The relay compensates the smallest latency it measured, so it dates a request's start
# no earlier, and a reply's end no later, than they were, give or take a few us: the
# minimum is measured with the receiver asleep in select(), and a receiver that happens
# to be awake sees a byte sooner. A request more than this inside t3.5 was inside t3.5.
TIMESTAMP_TOLERANCE_S = 20e-6
CALIBRATION_SAMPLES = 60
# The most latency the relay compensates per hop. The floor it measures is 8-20 us on an
# idle 2-core machine and 30-40 us beside two CPU burners; a calibration that starts in a
# burst of load can see no sample under 250 us, and compensating that would date frames
# early and deliver them before their wire time (a full-suite burner run did: -0.5 ms).
# So a frame is delivered at most 2 x this before its wire time, whatever the load.
MAX_LATENCY_COMPENSATION_S = 60e-6
# select() wakes up a little late even with 1 ns timer slack; the last stretch is spun.
SPIN_S = 30e-6
PR_SET_TIMERSLACK = 29
START_TIMEOUT_S = 10.0


def silence_s(baudrate: int, bits_per_char: int = BITS_PER_CHAR_8N1) -> float:
    """t3.5 on this line."""
    if baudrate > FIXED_TIMING_ABOVE_BAUD:
        return SILENCE_FIXED_S
    return SILENCE_CHARS * bits_per_char / baudrate


def intra_frame_gap_s(baudrate: int, bits_per_char: int = BITS_PER_CHAR_8N1) -> float:
    """t1.5: a longer pause on the line ends a frame."""
    if baudrate > FIXED_TIMING_ABOVE_BAUD:
        return INTRA_FRAME_GAP_FIXED_S
    return INTRA_FRAME_GAP_CHARS * bits_per_char / baudrate


@dataclass(frozen=True)
class Frame:
    """One frame on the emulated wire (times on ``time.monotonic()``)."""

    direction: str  # REQUEST or REPLY
    start: float  # first byte starts on the wire
    end: float  # last byte has finished (the receiver has it)
    size: int
    arrived: float  # raw: the relay read the first byte
    released: float  # raw: the relay wrote the last byte
    due_end: float  # end on an ideal line (``end`` is later if the relay was late)


@dataclass(frozen=True)
class Gap:
    """The silence before a request, and the frame it followed."""

    before: Frame
    request: Frame

    @property
    def silence_s(self) -> float:
        return self.request.start - self.before.end


def request_gaps(frames: Sequence[Frame]) -> list[Gap]:
    """The silence before every request that follows another frame."""
    return [Gap(a, b) for a, b in pairwise(frames) if b.direction == REQUEST]


def silence_violations(
    frames: Sequence[Frame], min_silence_s: float, tolerance_s: float = TIMESTAMP_TOLERANCE_S
) -> list[Gap]:
    """Requests that started less than ``min_silence_s`` after the previous frame ended."""
    return [g for g in request_gaps(frames) if g.silence_s < min_silence_s - tolerance_s]


def transactions(frames: Sequence[Frame]) -> list[tuple[Frame, Frame]]:
    """(request, reply) pairs in wire order."""
    return [(a, b) for a, b in pairwise(frames) if a.direction == REQUEST and b.direction == REPLY]


class LineRelay:
    """The relay process and its two pty endpoints; a context manager."""

    def __init__(
        self,
        baudrate: int,
        *,
        bits_per_char: int = BITS_PER_CHAR_8N1,
        device_turnaround_s: float = 0.0,
    ) -> None:
        self.baudrate = baudrate
        self.bits_per_char = bits_per_char
        self.char_s = bits_per_char / baudrate
        self.silence_s = silence_s(baudrate, bits_per_char)
        self.device_turnaround_s = device_turnaround_s
        self.client_path = ""
        self.device_path = ""
        self.latency_s: dict[str, float] = {}
        self._proc: subprocess.Popen[str] | None = None
        self._slaves: tuple[int, int] | None = None
        self._lock = threading.Lock()

    @property
    def paths(self) -> tuple[str, str]:
        return self.client_path, self.device_path

    def start(self) -> None:
        if self._proc is not None:
            raise RuntimeError("relay already running")
        m_client, s_client = pty.openpty()
        m_device, s_device = pty.openpty()
        for fd in (s_client, s_device):
            tty.setraw(fd)
        config = {
            "fds": [m_client, m_device, s_client, s_device],
            "char_s": self.char_s,
            "frame_gap_s": intra_frame_gap_s(self.baudrate, self.bits_per_char),
            "device_turnaround_s": self.device_turnaround_s,
        }
        self._proc = subprocess.Popen(
            [sys.executable, os.path.abspath(__file__), "--serve", json.dumps(config)],
            pass_fds=(m_client, m_device, s_client, s_device),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        # The relay owns the pty masters; the slaves stay open here so the masters never
        # see a hang-up while a client closes and reopens its port.
        os.close(m_client)
        os.close(m_device)
        self._slaves = (s_client, s_device)
        self.client_path, self.device_path = os.ttyname(s_client), os.ttyname(s_device)
        try:
            ready = self._reply_line(START_TIMEOUT_S)
        except BaseException:
            self.stop()
            raise
        self.latency_s = {k: float(v) for k, v in ready["latency_s"].items()}

    def _reply_line(self, timeout_s: float = 5.0) -> Any:
        assert self._proc is not None and self._proc.stdout is not None
        ready, _, _ = select.select([self._proc.stdout], [], [], timeout_s)
        line = self._proc.stdout.readline() if ready else ""
        if not line:
            raise RuntimeError("line relay did not answer (exited?)")
        return json.loads(line)

    def _command(self, command: str) -> Any:
        with self._lock:
            assert self._proc is not None and self._proc.stdin is not None
            self._proc.stdin.write(command + "\n")
            self._proc.stdin.flush()
            return self._reply_line()

    def frames(self) -> list[Frame]:
        """Every frame since the start (or the last ``clear``), in wire order."""
        return [Frame(**f) for f in self._command("frames")]

    def clear(self) -> None:
        """Forget the recorded frames (e.g. between benchmark cases)."""
        self._command("clear")

    def blackout(self, seconds: float) -> tuple[float, float]:
        """Cut the line both ways for ``seconds`` from now (a cable glitch): every byte
        that arrives, or was due to come out, meanwhile is lost. Returns the window
        (``time.monotonic()`` from, until) as the relay process keeps it."""
        window = self._command(f"blackout {float(seconds)!r}")
        return float(window["from"]), float(window["until"])

    def mute_replies(self, seconds: float) -> tuple[float, float]:
        """Lose every reply for ``seconds`` from now while requests still reach the device
        (a broken transmit pair or driver on the device's side): the device acts on what
        it hears, the master hears nothing. Returns the window as ``blackout`` does."""
        window = self._command(f"mute {float(seconds)!r}")
        return float(window["from"]), float(window["until"])

    def stop(self) -> None:
        proc, self._proc = self._proc, None
        if proc is not None:
            with contextlib.suppress(OSError, ValueError):
                assert proc.stdin is not None
                proc.stdin.write("quit\n")
                proc.stdin.close()
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
            if proc.stdout is not None:
                proc.stdout.close()
        if self._slaves is not None:
            for fd in self._slaves:
                with contextlib.suppress(OSError):
                    os.close(fd)
            self._slaves = None

    def __enter__(self) -> LineRelay:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------ self-check
    def measure_transfer(self, size: int, direction: str = REQUEST) -> float:
        """Seconds from writing ``size`` bytes at one end until the other end has them all."""
        assert self._slaves is not None
        src, dst = self._slaves if direction == REQUEST else self._slaves[::-1]
        data = bytes(i & 0xFF for i in range(size))
        started = time.monotonic()
        os.write(src, data)
        got = _read_exactly(dst, size, timeout_s=5 + 2 * size * self.char_s)
        finished = time.monotonic()
        if got != data:
            raise RuntimeError(f"relay garbled a frame: sent {size} bytes, got {len(got)}")
        return finished - started

    def measure_crossing(self, request_size: int, reply_size: int) -> float:
        """A reply written while the request is still on the line must wait for it.

        Seconds from writing both until the reply's last byte is in; theory:
        (request_size + reply_size) characters.
        """
        assert self._slaves is not None
        s_client, s_device = self._slaves
        started = time.monotonic()
        os.write(s_client, bytes(request_size))
        os.write(s_device, bytes(reply_size))
        got = _read_exactly(s_client, reply_size, timeout_s=5.0)
        finished = time.monotonic()
        _read_exactly(s_device, request_size, timeout_s=5.0)
        if len(got) != reply_size:
            raise RuntimeError("relay lost bytes")
        return finished - started


def _read_exactly(fd: int, size: int, timeout_s: float) -> bytes:
    buf = bytearray()
    deadline = time.monotonic() + timeout_s
    while len(buf) < size:
        ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            break
        buf += os.read(fd, size - len(buf))
    return bytes(buf)


@contextlib.contextmanager
def line_relay(baudrate: int, **kwargs: Any) -> Iterator[tuple[str, str, LineRelay]]:
    """``(client_path, device_path, relay)`` for the lifetime of the block."""
    with LineRelay(baudrate, **kwargs) as relay:
        yield relay.client_path, relay.device_path, relay


# ---------------------------------------------------------------- relay check against theory


@dataclass(frozen=True)
class TransferCheck:
    baudrate: int
    case: str  # "request", "reply" or "crossing"
    size: int  # bytes on the line
    theory_s: float
    median_s: float
    p90_s: float

    @property
    def error_s(self) -> float:
        return self.median_s - self.theory_s


def check_relay(
    baudrates: Sequence[int] = (9600, 115200),
    sizes: Sequence[int] = (8, 25, 103),
    repeats: int = 15,
    pause_s: float = 0.01,
) -> list[TransferCheck]:
    """Median transfer time of frames of known sizes vs ``size * bits / baud``."""
    results: list[TransferCheck] = []
    for baud in baudrates:
        with LineRelay(baud) as relay:
            cases: list[tuple[str, int, Any]] = []
            for size in sizes:
                cases.append((REQUEST, size, lambda n=size: relay.measure_transfer(n, REQUEST)))
                cases.append((REPLY, size, lambda n=size: relay.measure_transfer(n, REPLY)))
            cases.append(("crossing", 8 + 25, lambda: relay.measure_crossing(8, 25)))
            for case, size, measure in cases:
                measure()  # warm-up
                samples = []
                for _ in range(repeats):
                    time.sleep(pause_s)
                    samples.append(measure())
                samples.sort()
                results.append(
                    TransferCheck(
                        baud,
                        case,
                        size,
                        size * relay.char_s,
                        statistics.median(samples),
                        samples[int(0.9 * (len(samples) - 1))],
                    )
                )
    return results


def print_check(results: Sequence[TransferCheck]) -> None:
    print(
        f"{'baud':>7} {'case':>9} {'bytes':>5} {'theory ms':>10} {'median ms':>10} "
        f"{'error ms':>9} {'p90 ms':>8}"
    )
    for r in results:
        print(
            f"{r.baudrate:>7} {r.case:>9} {r.size:>5} {r.theory_s * 1e3:>10.3f} "
            f"{r.median_s * 1e3:>10.3f} {r.error_s * 1e3:>+9.3f} {r.p90_s * 1e3:>8.3f}"
        )


# ---------------------------------------------------------------- the relay process


def _calibrate(write_fd: int, read_fd: int) -> float:
    """Smallest seconds from a write on one end until a select()-woken read on the other.

    The smallest, not the median: latency under load only grows, so compensating the
    minimum keeps every timestamp on the safe side of the truth (see silence checks);
    capped, because a minimum taken in a burst of load is the load's, not the pty's.
    """
    samples = []
    for i in range(CALIBRATION_SAMPLES + 5):
        started = time.monotonic()
        os.write(write_fd, b"\x55")
        select.select([read_fd], [], [])
        os.read(read_fd, 16)
        if i >= 5:  # warm-up
            samples.append(time.monotonic() - started)
        time.sleep(0.0005)
    return min(min(samples), MAX_LATENCY_COMPENSATION_S)


def _serve(config: dict[str, Any]) -> None:
    m_client, m_device, s_client, s_device = config["fds"]
    char_s: float = config["char_s"]
    frame_gap_s: float = config["frame_gap_s"]
    turnaround_s: float = config["device_turnaround_s"]
    # No reference cycles are made here; a collection of the growing frame list would
    # stall the byte clock for milliseconds.
    gc.disable()
    with contextlib.suppress(OSError, AttributeError):
        # Precise select() timeouts for this process only (default slack is 50 us).
        ctypes.CDLL(None).prctl(PR_SET_TIMERSLACK, 1, 0, 0, 0)
    latency = {
        "client_in": _calibrate(s_client, m_client),
        "client_out": _calibrate(m_client, s_client),
        "device_in": _calibrate(s_device, m_device),
        "device_out": _calibrate(m_device, s_device),
    }
    os.close(s_client)
    os.close(s_device)
    ctrl = sys.stdin.fileno()
    print(json.dumps({"latency_s": latency}), flush=True)

    source = {m_client: REQUEST, m_device: REPLY}
    dest = {m_client: m_device, m_device: m_client}
    in_latency = {m_client: latency["client_in"], m_device: latency["device_in"]}
    out_latency = {m_client: latency["device_out"], m_device: latency["client_out"]}
    out_latency_to = {m_device: latency["device_out"], m_client: latency["client_out"]}
    clock = time.monotonic
    # One entry per byte: (release time, destination fd, byte, frame index).
    pending: collections.deque[tuple[float, int, int, int]] = collections.deque()
    frames: list[dict[str, Any]] = []
    base = 0  # frame index of frames[0] (after clear)
    line_free = 0.0
    request_end = float("-inf")
    ctrl_buf = b""
    dark_from = dark_until = float("-inf")  # a blackout: bytes in it are lost
    mute_from = mute_until = float("-inf")  # replies lost (the device hears, is not heard)

    while True:
        now = clock()
        if pending and pending[0][0] <= now:
            out: dict[int, bytearray] = {}
            done: dict[int, int] = {}
            while pending and pending[0][0] <= now:
                _, fd, byte, index = pending.popleft()
                if dark_from <= now < dark_until:
                    continue  # lost in the blackout
                out.setdefault(fd, bytearray()).append(byte)
                done[fd] = index
            for fd, data in out.items():
                # Stamped before the write: if the relay is preempted around the write,
                # the receiver still cannot have had the byte before this time.
                released = clock()
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                index = done[fd]
                if index >= base:
                    frame = frames[index - base]
                    frame["released"] = released
                    # Released late (the relay was not scheduled in time): the receiver
                    # has the byte only now, so that is when the frame ended on this line.
                    frame["end"] = max(frame["end"], released + out_latency_to[fd])
            continue
        timeout: float | None = None
        if pending:
            timeout = max(0.0, pending[0][0] - now - SPIN_S)
        ready, _, _ = select.select([m_client, m_device, ctrl], [], [], timeout)
        woke = clock()
        for fd in ready:
            if fd == ctrl:
                chunk = os.read(ctrl, 4096)
                if not chunk:
                    return
                ctrl_buf += chunk
                while b"\n" in ctrl_buf:
                    line, ctrl_buf = ctrl_buf.split(b"\n", 1)
                    command = line.decode().strip()
                    if command == "quit":
                        return
                    if command == "clear":
                        base += len(frames)
                        frames = []
                        print("{}", flush=True)
                    elif command == "frames":
                        print(json.dumps(frames), flush=True)
                    elif command.startswith("blackout "):
                        dark_from = clock()
                        dark_until = dark_from + float(command.split()[1])
                        print(json.dumps({"from": dark_from, "until": dark_until}), flush=True)
                    elif command.startswith("mute "):
                        mute_from = clock()
                        mute_until = mute_from + float(command.split()[1])
                        print(json.dumps({"from": mute_from, "until": mute_until}), flush=True)
                    else:
                        print(json.dumps({"error": f"unknown command {command!r}"}), flush=True)
                continue
            received = os.read(fd, 4096)
            arrived = woke
            if dark_from <= woke < dark_until:
                continue  # lost in the blackout
            direction = source[fd]
            if direction == REPLY and mute_from <= woke < mute_until:
                continue  # the reply is lost: the device's transmitter is cut off
            start = max(arrived - in_latency[fd], line_free)
            if direction == REPLY:
                start = max(start, request_end + turnaround_s)
            to = dest[fd]
            for byte in received:
                end = start + char_s
                last = frames[-1] if frames else None
                if (
                    last is not None
                    and last["direction"] == direction
                    and start - last["end"] <= frame_gap_s
                ):
                    last["end"] = last["due_end"] = end
                    last["size"] += 1
                else:
                    frames.append(
                        asdict(Frame(direction, start, end, 1, arrived, float("nan"), end))
                    )
                pending.append((end - out_latency[fd], to, byte, base + len(frames) - 1))
                start = end
            line_free = start
            if direction == REQUEST:
                request_end = start


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--serve", metavar="JSON", help=argparse.SUPPRESS)
    parser.add_argument("--check", action="store_true", help="compare with theory")
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args(argv)
    if args.serve:
        _serve(json.loads(args.serve))
        return 0
    if args.check:
        print_check(check_relay(repeats=args.repeats))
        return 0
    parser.print_help()
    return 2


if __name__ == "__main__":
    sys.exit(main())
