"""``bridge_replay BAG``: a recording of a bridge's ``~/wire`` served as a simulator.

A bag with ``msg_defs/ModbusFrame`` messages (recorded with ``record_wire`` on, by
``bridge_record`` or ``ros2 bag record``) becomes a device again: over Modbus TCP
(``--port``, ``--port-file``) or RTU on a serial port or a new pty pair (``--serial``,
``--pty``), whichever framing it was recorded with. Each request is answered with the
reply recorded to the same request (unit id and PDU: the TCP transaction id and the RTU
CRC are the framing's); of several, the nearest in sequence after the last one answered
(the recording's order, so a read after a write gets the reply recorded after that
write), else the last one recorded. What the recording says, the replay does: a recorded
timeout, link loss or frame error is no reply. A request never recorded from a unit the
recording knows gets exception 0x04 (SERVER DEVICE FAILURE: nothing was done, and the
bridge says so at once) and a line on stderr; a unit never recorded gets no reply (no
such device on the line). docs/tools.md, "Recording the wire".

Plain Python: the bag is read with ``rosbags`` (the types from the bag's own message
definitions), no rclpy.
"""

from __future__ import annotations

import argparse
import bisect
import signal
import socket
import socketserver
import struct
import sys
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from pymodbus.framer import FramerRTU
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ..wire.registers import Table
from ..wire.serial_port import open_serial
from .logs import WriteRecord, add_log_arguments
from .pty_pair import PtyPair
from .rtu_framing import BROADCAST_UNIT, CRC_SIZE, RTU_MAX_FRAME, crc_frame_size

FRAME_TYPE = "msg_defs/msg/ModbusFrame"
# msg_defs/msg/ModbusFrame's outcomes: only these had a reply the device meant.
OUTCOME_OK = 0
OUTCOME_EXCEPTION = 1
# Modbus Application Protocol V1.1b3 §7: SERVER DEVICE FAILURE, for a request the
# recording never saw from a unit it knows.
NOT_RECORDED_EXCEPTION = 0x04
EXCEPTION_FLAG = 0x80
MBAP = struct.Struct(">HHHB")  # transaction id, protocol id, length, unit id
MBAP_LEN = MBAP.size
TCP_PROTOCOL_ID = 0
MAX_PDU = 253
EXIT_BAD_INPUT = 2
SERIAL_READ_S = 0.05  # how long one read of the serial port waits (stop checks between)
RTU_FRAME_IDLE_S = 0.1  # bytes that make no frame for this long are dropped
# Function codes whose requests write (Modbus Application Protocol V1.1b3 §6).
FC_WRITE_COIL, FC_WRITE_REGISTER, FC_WRITE_COILS, FC_WRITE_REGISTERS = 0x05, 0x06, 0x0F, 0x10
FC_MASK_WRITE, FC_READ_WRITE = 0x16, 0x17
COIL_ON = 0xFF00


class BadRecording(Exception):
    """The bag cannot be served (missing, unreadable, no frames): one line for the user."""


@dataclass(frozen=True)
class Recorded:
    """One recorded reply: its place in the recording, and the reply's PDU (None: the
    device gave none, which the replay repeats)."""

    sequence: int
    reply: bytes | None


def split_adu(adu: bytes, rtu: bool) -> tuple[int, bytes] | None:
    """(unit id, PDU) of a recorded ADU, or None if it is not a whole one."""
    if rtu:
        if len(adu) < 1 + 1 + CRC_SIZE:
            return None
        return adu[0], adu[1:-CRC_SIZE]
    if len(adu) <= MBAP_LEN:
        return None
    return adu[MBAP_LEN - 1], adu[MBAP_LEN:]


@dataclass
class Recording:
    """The frames of one link, indexed by request (unit id, PDU)."""

    replies: dict[tuple[int, bytes], list[Recorded]] = field(default_factory=dict)
    units: set[int] = field(default_factory=set)
    frames: int = 0
    first_time: float = 0.0
    last_time: float = 0.0
    rtu: bool = False
    not_recorded: int = 0
    _cursor: int = 0
    _sequences: dict[tuple[int, bytes], list[int]] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def add(
        self,
        sequence: int,
        rtu: bool,
        request: bytes,
        reply: bytes,
        outcome: int,
        sent_s: float,
    ) -> None:
        asked = split_adu(request, rtu)
        if asked is None:  # never sent (the link was down): nothing to answer
            return
        answered = split_adu(reply, rtu) if outcome in (OUTCOME_OK, OUTCOME_EXCEPTION) else None
        key = (asked[0], asked[1])
        self.replies.setdefault(key, []).append(
            Recorded(sequence, answered[1] if answered else None)
        )
        self.units.add(asked[0])
        self.rtu = rtu
        self.frames += 1
        self.first_time = min(self.first_time or sent_s, sent_s)
        self.last_time = max(self.last_time, sent_s)

    def seal(self) -> None:
        """Order each request's replies by sequence (a bag holds them in arrival order)."""
        for key, recorded in self.replies.items():
            recorded.sort(key=lambda r: r.sequence)
            self._sequences[key] = [r.sequence for r in recorded]

    def answer(self, unit_id: int, pdu: bytes) -> bytes | None:
        """The reply PDU to send (None: none)."""
        if unit_id not in self.units:
            return None  # no such device on the line
        key = (unit_id, pdu)
        with self._lock:
            recorded = self.replies.get(key)
            if not recorded:
                self.not_recorded += 1
                print(
                    f"bridge_replay: not recorded: unit {unit_id} request {pdu.hex()}: "
                    f"exception 0x{NOT_RECORDED_EXCEPTION:02X}",
                    file=sys.stderr,
                    flush=True,
                )
                return bytes([(pdu[0] if pdu else 0) | EXCEPTION_FLAG, NOT_RECORDED_EXCEPTION])
            index = bisect.bisect_right(self._sequences[key], self._cursor)
            chosen = recorded[min(index, len(recorded) - 1)]
            self._cursor = chosen.sequence
            return chosen.reply

    def summary(self) -> str:
        units = ", ".join(str(u) for u in sorted(self.units))
        span = self.last_time - self.first_time
        start = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.first_time))
        framing = "RTU" if self.rtu else "TCP"
        return (
            f"{self.frames} {framing} frames of unit(s) {units}, {span:.1f} s from {start}, "
            f"{len(self.replies)} distinct requests"
        )


def _frame_topics(connections: Sequence[Any], topic: str | None) -> list[Any]:
    chosen = [c for c in connections if c.msgtype == FRAME_TYPE]
    if topic is not None:
        chosen = [c for c in chosen if c.topic == topic]
    if not chosen:
        what = f"topic {topic}" if topic else f"topic of type {FRAME_TYPE}"
        raise BadRecording(f"no {what} (record a bridge's ~/wire: record_wire)")
    topics = sorted({c.topic for c in chosen})
    if len(topics) > 1:
        raise BadRecording(f"frames of several links ({', '.join(topics)}): pick one with --topic")
    return chosen


def load(bag: Path, topic: str | None = None) -> Recording:
    """The recording of ``~/wire`` in ``bag`` (a rosbag2 directory)."""

    if not bag.exists():
        raise BadRecording(f"{bag}: no such bag")
    recording = Recording()
    try:
        with Reader(bag) as reader:
            try:
                connections = _frame_topics(reader.connections, topic)
            except BadRecording as err:
                raise BadRecording(f"{bag}: {err}") from None
            store = get_typestore(Stores.ROS2_JAZZY)
            definition = connections[0].msgdef
            if FRAME_TYPE not in store.fielddefs:
                if not definition.data:
                    raise BadRecording(f"the bag holds no definition of {FRAME_TYPE}")
                store.register(get_types_from_msg(definition.data, FRAME_TYPE))
            for connection, _, raw in reader.messages(connections=connections):
                msg: Any = store.deserialize_cdr(raw, connection.msgtype)
                recording.add(
                    int(msg.sequence),
                    bool(msg.rtu),
                    bytes(msg.request),
                    bytes(msg.reply),
                    int(msg.outcome),
                    msg.sent.sec + msg.sent.nanosec * 1e-9,
                )
    except BadRecording:
        raise
    except Exception as err:  # rosbags' errors, a truncated file, a foreign type ...
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]  # one line
        raise BadRecording(f"{bag}: cannot read the bag: {first}") from err
    if not recording.frames:
        raise BadRecording(f"{bag}: the recording holds no request that went out")
    recording.seal()
    return recording


# ---------------------------------------------------------------- writes, for --write-log


def write_record(unit_id: int, pdu: bytes) -> WriteRecord | None:
    """The write a request PDU asks for, as the simulators log it (None: not a write)."""
    if len(pdu) < 5:
        return None
    code = pdu[0]
    address = int.from_bytes(pdu[1:3], "big")
    values: tuple[int, ...]
    table = Table.HOLDING
    if code == FC_WRITE_COIL:
        table, values = Table.COIL, (int(int.from_bytes(pdu[3:5], "big") == COIL_ON),)
    elif code == FC_WRITE_REGISTER:
        values = (int.from_bytes(pdu[3:5], "big"),)
    elif code == FC_WRITE_COILS:
        count = int.from_bytes(pdu[3:5], "big")
        packed = pdu[6:]
        table = Table.COIL
        values = tuple((packed[i // 8] >> (i % 8)) & 1 for i in range(min(count, 8 * len(packed))))
    elif code == FC_WRITE_REGISTERS:
        values = _registers(pdu[6:])
    elif code == FC_MASK_WRITE and len(pdu) >= 7:
        values = (int.from_bytes(pdu[3:5], "big"), int.from_bytes(pdu[5:7], "big"))
    elif code == FC_READ_WRITE and len(pdu) >= 10:
        address = int.from_bytes(pdu[5:7], "big")
        values = _registers(pdu[10:])
    else:
        return None
    return WriteRecord(time.time(), unit_id, code, table, address, values)


def _registers(data: bytes) -> tuple[int, ...]:
    return tuple(int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data) - 1, 2))


@dataclass
class Replayer:
    """Answers requests from a ``Recording`` and logs the writes it answered."""

    recording: Recording
    write_log: IO[str] | None = None
    _log_lock: threading.Lock = field(default_factory=threading.Lock)

    def reply(self, unit_id: int, pdu: bytes) -> bytes | None:
        reply = self.recording.answer(unit_id, pdu)
        if reply and not reply[0] & EXCEPTION_FLAG and self.write_log is not None:
            record = write_record(unit_id, pdu)
            if record is not None:
                with self._log_lock:
                    self.write_log.write(record.to_json() + "\n")
                    self.write_log.flush()
        return reply


# ---------------------------------------------------------------- Modbus TCP


class _TcpHandler(socketserver.BaseRequestHandler):
    server: _TcpServer

    def handle(self) -> None:
        sock: socket.socket = self.request
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        stream = sock.makefile("rb")
        while True:
            header = stream.read(MBAP_LEN)
            if len(header) < MBAP_LEN:
                return
            tid, protocol, length, unit_id = MBAP.unpack(header)
            if protocol != TCP_PROTOCOL_ID or not 2 <= length <= MAX_PDU + 1:
                return  # not Modbus TCP: the connection goes, as a device's would
            pdu = stream.read(length - 1)
            if len(pdu) < length - 1:
                return
            reply = self.server.replayer.reply(unit_id, pdu)
            if reply is not None:
                sock.sendall(MBAP.pack(tid, TCP_PROTOCOL_ID, len(reply) + 1, unit_id) + reply)


class _TcpServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, address: tuple[str, int], replayer: Replayer) -> None:
        self.replayer = replayer
        super().__init__(address, _TcpHandler)


class TcpReplay:
    """The replay listening on TCP (``port`` the bound one)."""

    def __init__(self, replayer: Replayer, host: str = "127.0.0.1", port: int = 0) -> None:
        self._server = _TcpServer((host, port), replayer)
        self.port = int(self._server.server_address[1])
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._server.shutdown()
        self._server.server_close()


# ---------------------------------------------------------------- Modbus RTU


def rtu_adu(unit_id: int, pdu: bytes) -> bytes:
    body = bytes([unit_id]) + pdu
    return body + FramerRTU.compute_CRC(body).to_bytes(2, "big")


class SerialReplay:
    """The replay answering on a serial port (or a pty's device end)."""

    def __init__(
        self, replayer: Replayer, port: str, baudrate: int, parity: str, stopbits: int
    ) -> None:
        self._replayer = replayer
        self._serial = open_serial(
            port, baudrate=baudrate, parity=parity, stopbits=stopbits, timeout=SERIAL_READ_S
        )
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        buffer = b""
        heard = time.monotonic()
        while not self._stopping.is_set():
            data = self._serial.read(RTU_MAX_FRAME)
            now = time.monotonic()
            if not data:
                if buffer and now - heard > RTU_FRAME_IDLE_S:
                    buffer = b""  # no frame in it: a slave waits for the next one
                continue
            buffer, heard = buffer + data, now
            while (size := crc_frame_size(buffer)) and size <= len(buffer):
                frame, buffer = buffer[:size], buffer[size:]
                unit_id, pdu = frame[0], frame[1:-CRC_SIZE]
                reply = self._replayer.reply(unit_id, pdu)
                if reply is not None and unit_id != BROADCAST_UNIT:
                    self._serial.write(rtu_adu(unit_id, reply))

    def stop(self) -> None:
        self._stopping.set()
        self._thread.join(1.0)
        self._serial.close()


# ---------------------------------------------------------------- command line


def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="bridge_replay",
        description="serve a bag's recorded ~/wire (msg_defs/ModbusFrame) as a Modbus device",
    )
    parser.add_argument("bag", type=Path, help="rosbag2 directory recorded with record_wire on")
    parser.add_argument("--topic", help="the ~/wire topic to serve, if the bag holds several")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=502, help="TCP port; 0 picks a free one")
    parser.add_argument("--port-file", type=Path, help="write the bound port here once listening")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--serial", help="serve RTU on this serial port or pty path")
    where.add_argument(
        "--pty", type=Path, help="serve RTU on a new socat pty pair, the bridge's end linked here"
    )
    parser.add_argument("--baudrate", type=int, default=9600)
    parser.add_argument("--parity", default="N", choices=("N", "E", "O"))
    parser.add_argument("--stopbits", type=int, default=1, choices=(1, 2))
    add_log_arguments(parser)
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> None:
    args = parse(argv)
    try:
        recording = load(args.bag, args.topic)
    except BadRecording as err:
        print(f"bridge_replay: {err}", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT) from None
    write_log = args.write_log.open("a") if args.write_log else None
    replayer = Replayer(recording, write_log)
    served: TcpReplay | SerialReplay
    pair: PtyPair | None = None
    try:
        if args.serial or args.pty:
            pair = PtyPair(args.pty) if args.pty else None
            port = str(pair.device_end) if pair else args.serial
            served = SerialReplay(replayer, port, args.baudrate, args.parity, args.stopbits)
            where = f"on {args.pty or args.serial} ({args.baudrate} 8{args.parity}{args.stopbits})"
        else:
            served = TcpReplay(replayer, args.host, args.port)
            where = f"listening on {args.host}:{served.port}"
    except (OSError, RuntimeError) as err:
        if pair is not None:
            pair.close()
        print(f"bridge_replay: cannot serve: {err}", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT) from None
    if args.port_file is not None and isinstance(served, TcpReplay):
        args.port_file.write_text(str(served.port))
    print(f"bridge_replay: {recording.summary()}; {where}", flush=True)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    try:
        done.wait()
    finally:
        served.stop()
        if pair is not None:
            pair.close()
        if write_log is not None:
            write_log.close()


def frames_of(items: Iterable[tuple[int, bool, bytes, bytes, int, float]]) -> Recording:
    """A recording from plain tuples (sequence, rtu, request, reply, outcome, sent time):
    for tests and for a fixture written without a bag."""
    recording = Recording()
    for item in items:
        recording.add(*item)
    recording.seal()
    return recording


if __name__ == "__main__":
    main()
