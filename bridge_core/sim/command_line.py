"""The simulators' shared command line: their options (where to serve, logs, network,
personality) and the loop that serves until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
import signal
import threading
from collections.abc import Callable
from pathlib import Path

from .logs import add_log_arguments, open_logs
from .personality import DelayRange, add_delay_argument, chosen_ignore
from .pty_pair import PtyPair
from .serving import Simulator, SimulatorStartError


def serve_until_signalled(sim: Simulator, banner: str, port_file: Path | None = None) -> None:
    """The simulators' command-line loop: announce, wait for SIGINT/SIGTERM, stop.

    ``banner`` is printed (flushed) once the server listens: tests wait for that line;
    ``port_file`` receives the bound TCP port (useful with ``--port 0``).
    """
    if port_file is not None:
        port_file.write_text(str(sim.port))
    print(banner, flush=True)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    done.wait()
    sim.stop()


def add_network_arguments(
    parser: argparse.ArgumentParser, delay_default_ms: float | None = 0.0
) -> None:
    """The TCP simulators' network options (``tcp_serving``, ``personality``)."""
    add_delay_argument(
        parser,
        delay_default_ms,
        "simulated network round trip (half each way); pipelined requests overlap, their "
        "order is kept",
    )
    parser.add_argument(
        "--one-request-at-a-time",
        action="store_true",
        help="drop a request that arrives while one is unanswered (a device that does not "
        "pipeline)",
    )
    parser.add_argument(
        "--nagle", action="store_true", help="leave Nagle's algorithm on for the replies"
    )


def apply_ignore(sim: Simulator, args: argparse.Namespace) -> None:
    """``--ignore`` of a simulator's command line, on every unit (names checked by argparse)."""
    names = chosen_ignore(args)
    if names:
        sim.ignore(names)


def personality_text(sim: Simulator, args: argparse.Namespace) -> str:
    """What the banner says of the personality switches in force ('' when none)."""
    parts = []
    if getattr(args, "ignore", None):
        parts.append(f"ignores {','.join(sorted(args.ignore))}")
    if getattr(args, "nagle", False):
        parts.append("Nagle on")
    return f" ({'; '.join(parts)})" if parts else ""


def add_tcp_arguments(parser: argparse.ArgumentParser, default_port: int) -> None:
    """The TCP simulators' options: where to listen, the logs, the port file, the network."""
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=default_port, help="0 picks a free port")
    add_network_arguments(parser)
    add_log_arguments(parser)
    parser.add_argument("--port-file", type=Path, help="write the bound port here once listening")


def serve_tcp_until_signalled(sim: Simulator, args: argparse.Namespace, name: str) -> None:
    """Attach the logs, listen on ``args.host:args.port`` and serve until SIGINT/SIGTERM."""
    open_logs(args, sim)
    delay: DelayRange | None = getattr(args, "reply_delay_ms", None)
    if delay is not None:
        sim.set_round_trip(delay.low_s, delay.high_s)
    sim.one_request_at_a_time = bool(getattr(args, "one_request_at_a_time", False))
    sim.nagle = bool(getattr(args, "nagle", False))
    apply_ignore(sim, args)
    try:
        port = sim.start_tcp(args.host, args.port)
    except SimulatorStartError as err:
        raise SystemExit(
            f"{name}: cannot listen on {args.host}:{args.port}: {err.__cause__}"
        ) from None
    serve_until_signalled(
        sim, f"{name} listening on {args.host}:{port}{personality_text(sim, args)}", args.port_file
    )


def add_serial_arguments(
    parser: argparse.ArgumentParser, default_baudrate: int, example: str
) -> None:
    """The serial simulators' line options: where to serve (a port, or a new pty pair)."""
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--serial", help="serve on this serial port or pty path")
    where.add_argument(
        "--pty",
        type=Path,
        help=f"create a socat pty pair and link the bridge's end here (e.g. {example})",
    )
    parser.add_argument("--baudrate", type=int, default=default_baudrate)
    parser.add_argument("--parity", default="N", choices=("N", "E", "O"))
    parser.add_argument("--stopbits", type=int, default=1, choices=(1, 2))
    add_log_arguments(parser)


def serve_serial_until_signalled(
    sim: Simulator, args: argparse.Namespace, banner: Callable[[str], str]
) -> None:
    """Serve on ``args.serial`` or a new pty pair (``args.pty``) until SIGINT/SIGTERM.

    ``banner(where)`` is the line printed once listening; the logs (``--write-log``,
    ``--read-log``) are attached first, and the pty pair and logs are closed after.
    """
    logs = open_logs(args, sim)
    delay: DelayRange | None = getattr(args, "reply_delay_ms", None)
    if delay is not None:
        sim.set_reply_delay(delay.low_s, delay.high_s)
    apply_ignore(sim, args)
    pair = PtyPair(args.pty) if args.pty else None
    try:
        port = str(pair.device_end) if pair else args.serial
        try:
            sim.start_serial(port, args.baudrate, args.parity, args.stopbits)
        except SimulatorStartError as err:
            raise SystemExit(f"cannot serve on {port}: {err.__cause__}") from None
        where = str(args.pty) if pair else args.serial
        serve_until_signalled(sim, banner(where) + personality_text(sim, args))
    finally:
        sim.stop()
        if pair is not None:
            pair.close()
        for log in logs:
            log.close()
